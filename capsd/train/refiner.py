"""`capsd train refiner`: more hard-example rounds for trained weights' main refiner, the rest kept.

What the detector loses on looks it was not trained on is mostly the ROV over clutter (the
racks, the floor): on the bench's held-out look at 8-14 m, 48 % of the refiner's scores at
the true ROV over clutter reach 0.5 against 89 % in clear water (session 61, by hand). The
refiner's hard-example rounds (stage 4 of `capsd train detector`) are what teaches it those
pings: fresh runs seen through the weights' own proposal network, every crop trained again and
the ones it gets wrong or only just right repeated. `capsd train detector` runs one round to
keep its 29 minutes; this runs `rounds` more on fresh plans (seeds after the weights' own
rounds, with the weights' stored `train_config`: its runs, look variety, far share), keeps
both proposal networks and the near refiner, sets the main operating point again on the
validation runs and writes the weights. Deterministic for a seed. About 6 minutes a round
and 5 for the operating point on 2 cores.
"""

from __future__ import annotations

import dataclasses
import io
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Literal

import torch

from capsd.errors import CapsdError
from capsd.services.sonar_detect.polar_net import load
from capsd.train.detector import (
    TrainConfig,
    _mean,
    calibrate,
    hard_round,
    save_evaluated,
    stored_meta,
    stored_train_config,
)

MAX_ROUNDS = 8


@dataclass(frozen=True)
class RefinerConfig:
    rounds: int = 2
    # The rounds' run plans are drawn from the weights' training seed + 2 + their own hard
    # rounds + `seed_offset` + k: after every plan the weights were trained on (offset 0).
    seed_offset: int = 0
    workers: int = 2
    threads: int = 2
    # None: as the weights' own train_config (tests make them small).
    runs: int | None = None  # per round
    duration_s: float | None = None
    epochs: int | None = None
    calibration_duration_s: float = TrainConfig.calibration_duration_s
    # "none" leaves the held-out evaluation to `capsd bench detect`.
    evaluate: Literal["heldout", "none"] = "heldout"
    eval_duration_s: float = TrainConfig.eval_duration_s


def train_refiner(weights: Path, out_dir: Path, config: RefinerConfig) -> dict[str, Any]:
    """`weights` with `config.rounds` more hard-example rounds of the main refiner; to `out_dir`."""
    if not 1 <= config.rounds <= MAX_ROUNDS:
        raise CapsdError(f"train refiner: rounds {config.rounds}: 1 to {MAX_ROUNDS}")
    if config.seed_offset < 0:
        raise CapsdError(f"train refiner: seed offset {config.seed_offset}: 0 or more")
    started = time.monotonic()
    net = load(weights)
    meta = stored_meta(weights)
    base = stored_train_config(weights, meta)
    if base.inputs != net.inputs:
        raise CapsdError(f"{weights}: its networks read {net.inputs}, its train_config says not")
    train_config = dataclasses.replace(
        base,
        workers=config.workers,
        threads=config.threads,
        hard_runs=base.hard_runs if config.runs is None else config.runs,
        duration_s=base.duration_s if config.duration_s is None else config.duration_s,
        hard_epochs=base.hard_epochs if config.epochs is None else config.epochs,
        calibration_duration_s=config.calibration_duration_s,
        device="cpu",
    )
    before = meta.get("refiner_rounds", {}).get("rounds", [])
    first_seed = base.seed + 2 + base.hard_rounds + len(before) + config.seed_offset
    torch.manual_seed(first_seed)
    torch.set_num_threads(config.threads)
    gen = torch.Generator().manual_seed(first_seed)
    buffer = io.BytesIO()
    torch.save({k: v.cpu() for k, v in net.proposal.state_dict().items()}, buffer)
    rounds: list[dict[str, Any]] = list(before)
    for k in range(config.rounds):
        plan_seed = first_seed + k
        losses, (hard, crops) = hard_round(
            net,
            train_config,
            gen,
            proposal_state=buffer.getvalue(),
            plan_seed=plan_seed,
            label=f"round {k + 1} of {config.rounds}",
        )
        rounds.append(
            {
                "plan_seed": plan_seed,
                "runs": train_config.hard_runs,
                "hard_examples": hard,
                "fresh_crops": crops,
                "loss_first_last": [_mean(losses[:50]), _mean(losses[-50:])],
            }
        )
    meta["refiner_rounds"] = {
        "trained_by": "capsd train refiner",
        "from_weights": str(weights),
        "config": asdict(config),
        "rounds": rounds,
        "seconds_render_and_train": round(time.monotonic() - started, 1),
    }
    meta.pop("evaluation", None)  # of the weights before
    out_dir.mkdir(parents=True, exist_ok=True)
    meta["calibration"] = calibrate(net, duration_s=train_config.calibration_duration_s)
    path = save_evaluated(
        net, out_dir, meta, evaluate=config.evaluate, eval_duration_s=config.eval_duration_s
    )
    print(f"weights: {path}; total {time.monotonic() - started:.0f} s")
    return meta
