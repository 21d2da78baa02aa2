"""`capsd train near-refiner`: the main network kept, a near refiner added, deterministic."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from capsd.errors import CapsdError
from capsd.services.sonar_detect.cnn import DEFAULT_WEIGHTS
from capsd.services.sonar_detect.polar_net import PolarNet, load, save
from capsd.train.near_refiner import (
    NearRefinerConfig,
    recalibrate_near_refiner,
    train_near_refiner,
)

# A run of each kind, one epoch: the steps, not the figures.
TINY = NearRefinerConfig(
    near_runs=1,
    edge_runs=1,
    other_runs=1,
    duration_s=2.0,
    workers=1,
    threads=1,
    epochs=1,
    calibration_duration_s=0.3,
    evaluate="none",
)


def test_a_near_refiner_is_added_beside_the_main_network_and_deterministic(
    tmp_path: Path,
) -> None:
    config = TINY
    nets = []
    for name in ("a", "b"):
        meta = train_near_refiner(DEFAULT_WEIGHTS, tmp_path / name, config)
        assert meta["near_refiner"]["crops"] > 0
        assert meta["near_refiner"]["calibration"]["near_logit_offset"] >= 0.0
        assert "train_config" in meta  # the main network's own record is kept
        nets.append(load(tmp_path / name / "polar_net.pt"))
    main = load(DEFAULT_WEIGHTS)
    first, second = (n.state_dict() for n in nets)
    assert all(torch.equal(first[k], second[k]) for k in first)
    net = nets[0]
    assert net.near_refine is not None
    assert float(net.near_max_range_m) == config.max_range_m
    # The main network is the input's, bit for bit; the near refiner started from its
    # refiner and moved.
    shipped = main.state_dict()
    assert all(torch.equal(first[k], shipped[k]) for k in shipped if not k.startswith("near_"))
    near = net.near_refine.state_dict()
    assert any(not torch.equal(near[k], main.refine.state_dict()[k]) for k in near)


def test_calibrate_only_keeps_the_near_refiner_and_moves_where_it_takes_over(
    tmp_path: Path,
) -> None:
    config = TINY
    train_near_refiner(DEFAULT_WEIGHTS, tmp_path / "trained", config)
    trained = load(tmp_path / "trained" / "polar_net.pt")
    assert float(trained.near_edge_max_range_m) == config.edge_max_range_m
    assert float(trained.near_edge_within_rad) == pytest.approx(math.radians(20.0))
    narrower = replace(config, max_range_m=1.0, edge_within_deg=0.0)
    meta = recalibrate_near_refiner(
        tmp_path / "trained" / "polar_net.pt", tmp_path / "again", narrower
    )
    assert meta["near_refiner"]["takes_over"]["max_range_m"] == 1.0
    assert meta["near_refiner"]["calibration"]["near_logit_offset"] >= 0.0
    again = load(tmp_path / "again" / "polar_net.pt")
    assert float(again.near_max_range_m) == 1.0
    assert float(again.near_edge_within_rad) == 0.0
    before, after = trained.state_dict(), again.state_dict()
    assert all(torch.equal(before[k], after[k]) for k in before if "refine." in k)
    # Weights without a near refiner: named, nothing written.
    save(PolarNet(), tmp_path / "plain.pt", meta={})
    with pytest.raises(CapsdError, match="no near refiner"):
        recalibrate_near_refiner(tmp_path / "plain.pt", tmp_path / "none", narrower)
    assert not (tmp_path / "none").exists()
