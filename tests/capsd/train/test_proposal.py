"""`capsd train proposal`: a close proposal network added, the rest kept bit for bit."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import pytest
import torch

from capsd.errors import CapsdError
from capsd.services.sonar_detect.cnn import DEFAULT_WEIGHTS
from capsd.services.sonar_detect.polar_net import load, save
from capsd.train.near_refiner import NearRefinerConfig, train_near_refiner
from capsd.train.proposal import ProposalConfig, train_proposal

# Two short runs, one epoch, short calibrations: the steps, not the figures.
TINY = ProposalConfig(
    close_share=0.5,
    workers=1,
    threads=1,
    runs=2,
    duration_s=2.0,
    epochs=1,
    calibration_duration_s=0.3,
    near_calibration_duration_s=0.3,
    evaluate="none",
)


def test_a_close_proposal_network_is_added_the_rest_kept_deterministic(tmp_path: Path) -> None:
    shipped_meta = json.loads(DEFAULT_WEIGHTS.with_suffix(".json").read_text())
    nets = []
    for name in ("a", "b"):
        meta = train_proposal(DEFAULT_WEIGHTS, tmp_path / name, TINY)
        assert meta["proposal"]["runs"] == 2
        assert meta["proposal"]["frames"] > 0
        assert meta["proposal"]["train_config"]["close_share"] == 0.5
        assert meta["train_config"] == shipped_meta["train_config"]  # the main networks' own
        assert meta["calibration"]["logit_offset"] >= 0.0
        assert meta["near_refiner"]["calibration"]["near_logit_offset"] >= 0.0
        assert json.loads((tmp_path / name / "polar_net.json").read_text()) == meta
        nets.append(load(tmp_path / name / "polar_net.pt"))
    first, second = (n.state_dict() for n in nets)
    assert all(torch.equal(first[k], second[k]) for k in first)
    shipped = load(DEFAULT_WEIGHTS).state_dict()
    kept = [k for k in shipped if "logit_offset" not in k and not k.startswith("close_")]
    assert any(k.startswith("proposal.") for k in kept)
    assert all(torch.equal(first[k], shipped[k]) for k in kept)
    net = nets[0]
    assert net.close_proposal is not None
    assert float(net.close_max_range_m) == TINY.close_max_range_m
    close = net.close_proposal.state_dict()
    assert any(not torch.equal(close[k], net.proposal.state_dict()[k]) for k in close)


def test_the_main_network_trained_again_narrower_the_close_one_kept(tmp_path: Path) -> None:
    main = dataclasses.replace(
        TINY, network="main", width=8, close_share=None, rack_heights="drawn"
    )
    meta = train_proposal(DEFAULT_WEIGHTS, tmp_path / "main", main)
    shipped_meta = json.loads(DEFAULT_WEIGHTS.with_suffix(".json").read_text())
    assert meta["proposal"] == shipped_meta["proposal"]  # the close network's record
    # The weights' own runs: no close runs unless asked; the racks as asked.
    assert meta["main_proposal"]["train_config"]["close_share"] == 0.0
    assert meta["main_proposal"]["train_config"]["rack_heights"] == "drawn"
    assert meta["train_config"].get("rack_heights", "preset") == "preset"  # the refiners'
    net = load(tmp_path / "main" / "polar_net.pt")
    assert net.proposal.width == 8
    shipped = load(DEFAULT_WEIGHTS)
    assert shipped.close_proposal is not None
    assert net.close_proposal is not None
    assert net.close_proposal.width == shipped.close_proposal.width
    trained, kept = net.state_dict(), shipped.state_dict()
    same = [k for k in kept if "logit_offset" not in k and not k.startswith("proposal.")]
    assert any(k.startswith("close_proposal.") for k in same)
    assert all(torch.equal(trained[k], kept[k]) for k in same)
    # The other training commands take narrow weights: the near refiner's mines with its
    # main proposal network.
    near = NearRefinerConfig(
        near_runs=1, edge_runs=1, other_runs=1, duration_s=2.0, workers=1, threads=1,
        epochs=1, calibration_duration_s=0.3, evaluate="none",
    )  # fmt: skip
    train_near_refiner(tmp_path / "main" / "polar_net.pt", tmp_path / "near", near)
    refined = load(tmp_path / "near" / "polar_net.pt")
    assert refined.close_proposal is not None
    assert (refined.proposal.width, refined.close_proposal.width) == (8, 32)
    with pytest.raises(CapsdError, match="width 4: 8 to 64 channels"):
        train_proposal(DEFAULT_WEIGHTS, tmp_path / "odd", dataclasses.replace(main, width=4))


def test_a_teacher_s_heat_changes_what_the_narrow_network_learns(tmp_path: Path) -> None:
    nets = {}
    for targets in ("labels", "labels_and_teacher"):
        config = dataclasses.replace(TINY, network="main", width=8, targets=targets)
        meta = train_proposal(DEFAULT_WEIGHTS, tmp_path / targets, config)
        assert meta["main_proposal"]["config"]["targets"] == targets
        nets[targets] = load(tmp_path / targets / "polar_net.pt").proposal.state_dict()
    plain, taught = nets["labels"], nets["labels_and_teacher"]
    assert any(not torch.equal(plain[k], taught[k]) for k in plain if k.endswith("weight"))


def test_no_close_network_to_learn_from_is_refused(tmp_path: Path) -> None:
    net = load(DEFAULT_WEIGHTS)
    net.close_proposal = None
    save(net, tmp_path / "polar_net.pt", meta={})
    shutil.copy(DEFAULT_WEIGHTS.with_suffix(".json"), tmp_path / "polar_net.json")
    config = dataclasses.replace(TINY, targets="labels_and_teacher")
    with pytest.raises(CapsdError, match="no close proposal network to learn from"):
        train_proposal(tmp_path / "polar_net.pt", tmp_path / "out", config)
    assert not (tmp_path / "out").exists()


def test_weights_without_their_training_record_are_refused(tmp_path: Path) -> None:
    bare = tmp_path / "bare" / "polar_net.pt"
    bare.parent.mkdir()
    shutil.copy(DEFAULT_WEIGHTS, bare)
    with pytest.raises(CapsdError, match="no train_config"):
        train_proposal(bare, tmp_path / "out", TINY)


@pytest.mark.parametrize(
    ("config", "message"),
    [
        (ProposalConfig(close_share=1.5), r"close share 1\.5"),
        (ProposalConfig(close_max_range_m=6.0), r"close max range 6\.0 m"),
    ],
)
def test_settings_out_of_range_are_refused(
    tmp_path: Path, config: ProposalConfig, message: str
) -> None:
    with pytest.raises(CapsdError, match=message):
        train_proposal(DEFAULT_WEIGHTS, tmp_path / "out", config)
