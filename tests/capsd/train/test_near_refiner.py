"""`capsd train near-refiner`: the main network kept, a near refiner added, deterministic."""

from __future__ import annotations

from pathlib import Path

import torch

from capsd.services.sonar_detect.cnn import DEFAULT_WEIGHTS
from capsd.services.sonar_detect.polar_net import load
from capsd.train.near_refiner import NearRefinerConfig, train_near_refiner


def test_a_near_refiner_is_added_beside_the_main_network_and_deterministic(
    tmp_path: Path,
) -> None:
    config = NearRefinerConfig(
        near_runs=1,
        other_runs=1,
        duration_s=2.0,
        workers=1,
        threads=1,
        epochs=1,
        calibration_duration_s=0.3,
        evaluate="none",
    )
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
