"""`capsd train refiner`: more hard-example rounds for the main refiner, the rest kept."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import pytest
import torch

from capsd.errors import CapsdError
from capsd.services.sonar_detect.cnn import DEFAULT_WEIGHTS
from capsd.services.sonar_detect.polar_net import load
from capsd.train.refiner import RefinerConfig, train_refiner

# Two short runs a round, one epoch, a short calibration: the steps, not the figures.
TINY = RefinerConfig(
    rounds=2,
    workers=1,
    threads=1,
    runs=2,
    duration_s=2.0,
    epochs=1,
    calibration_duration_s=0.3,
    evaluate="none",
)


def test_the_main_refiner_trains_on_the_rest_kept_deterministic(tmp_path: Path) -> None:
    shipped_meta = json.loads(DEFAULT_WEIGHTS.with_suffix(".json").read_text())
    trained = shipped_meta["train_config"]
    first_seed = trained["seed"] + 2 + trained["hard_rounds"]
    nets = []
    for name in ("a", "b"):
        meta = train_refiner(DEFAULT_WEIGHTS, tmp_path / name, TINY)
        rounds = meta["refiner_rounds"]["rounds"]
        assert [r["plan_seed"] for r in rounds] == [first_seed, first_seed + 1]
        assert all(r["runs"] == 2 and 0 <= r["hard_examples"] <= r["fresh_crops"] for r in rounds)
        assert meta["train_config"] == trained  # what the networks were first trained with
        assert meta["calibration"]["logit_offset"] >= 0.0
        assert json.loads((tmp_path / name / "polar_net.json").read_text()) == meta
        nets.append(load(tmp_path / name / "polar_net.pt").state_dict())
    first, second = nets
    assert all(torch.equal(first[k], second[k]) for k in first)
    shipped = load(DEFAULT_WEIGHTS).state_dict()
    kept = [k for k in shipped if "logit_offset" not in k and not k.startswith("refine.")]
    assert {k.split(".")[0] for k in kept} >= {"proposal", "close_proposal", "near_refine"}
    assert all(torch.equal(first[k], shipped[k]) for k in kept)
    changed = [k for k in shipped if k.startswith("refine.") and k.endswith("weight")]
    assert changed
    assert any(not torch.equal(first[k], shipped[k]) for k in changed)
    # Once more on its own output: the next rounds plan runs the first did not.
    meta = train_refiner(
        tmp_path / "a" / "polar_net.pt", tmp_path / "c", dataclasses.replace(TINY, rounds=1)
    )
    seeds = [r["plan_seed"] for r in meta["refiner_rounds"]["rounds"]]
    assert seeds == [first_seed, first_seed + 1, first_seed + 2]


def test_weights_without_their_training_record_are_refused(tmp_path: Path) -> None:
    bare = tmp_path / "bare" / "polar_net.pt"
    bare.parent.mkdir()
    shutil.copy(DEFAULT_WEIGHTS, bare)
    with pytest.raises(CapsdError, match="no train_config"):
        train_refiner(bare, tmp_path / "out", TINY)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("config", "message"),
    [
        (dataclasses.replace(TINY, rounds=0), "rounds 0: 1 to 8"),
        (dataclasses.replace(TINY, rounds=9), "rounds 9: 1 to 8"),
        (dataclasses.replace(TINY, seed_offset=-1), "seed offset -1"),
    ],
)
def test_settings_out_of_range_are_refused(
    tmp_path: Path, config: RefinerConfig, message: str
) -> None:
    with pytest.raises(CapsdError, match=message):
        train_refiner(DEFAULT_WEIGHTS, tmp_path / "out", config)
