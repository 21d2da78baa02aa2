"""`capsd train proposal`: a proposal network trained again for trained weights, the rest kept.

The proposal network (stage 2 of `capsd train detector`) decides which places of a frame the
refiners ever see. A ROV 1.2-2 m from a sonar 30 deg down, in the middle of the aperture, got
0.02-0.09 of heat where the refiners, shown a crop there, called it ROV at 0.6-0.99: it was
never proposed (the pitch calibration's near profile in the pond, session 58; the nfp tank
too, session 59, by hand), because the training runs put almost no ROV there. This trains a
proposal network from scratch as `capsd train detector` does, on the runs the weights were
trained on (their stored `train_config`) with a `close_share` of them made close runs
(capsd.train.data's close runs), and adds it as the weights' close proposal network: it gives
the heat of the rows nearer than `close_max_range_m` (polar_net). Trained so, a network used
everywhere found the far ROVs of the bench's held-out look less often (14-20 m 60.4 -> 41.1 %,
session 59), so the main one keeps the rest of the frame; the refiners, the near refiner and
the range table are kept too. Then both operating points are set again on the validation runs
(other proposals reach the refiners). Deterministic for a seed. About 17 minutes on 2 cores.

`network: main` trains the main proposal network again the same way, on the weights' own runs
(no close runs unless `close_share` says so), and keeps the close one: with fewer channels
(`width`) it costs less on every whole-frame search (session 60: 4.0 -> 1.5 ms at 16 of 32)
and found fewer ROVs on the bench's held-out look (81.5 -> 79.1 %), so the shipped is 32 wide.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Literal

import torch

from capsd.errors import CapsdError
from capsd.services.sonar_detect.polar_net import (
    PROPOSAL_WIDTH,
    PROPOSAL_WIDTHS,
    PolarNet,
    ProposalNet,
    load,
)
from capsd.simulator.world import RackHeights
from capsd.train.data import render
from capsd.train.detector import (
    TrainConfig,
    _mean,
    _train_proposal,
    calibrate,
    save_evaluated,
    stored_meta,
    stored_train_config,
)
from capsd.train.near_refiner import NearRefinerConfig, calibrate_near

# Up to where the close proposal network may take over: beyond, the main one saw plenty of ROVs.
MAX_CLOSE_RANGE_M = 4.0
CLOSE_SHARE = 0.25  # the share of runs drawn close for the close network (session 59)


@dataclass(frozen=True)
class ProposalConfig:
    seed: int = 0
    network: Literal["close", "main"] = "close"  # which one is trained again
    # The share of close runs; None: CLOSE_SHARE for the close network, the weights' own for
    # the main one.
    close_share: float | None = None
    close_max_range_m: float = 2.5  # the close network's rows (kept as stored for main)
    width: int = PROPOSAL_WIDTH  # its channels (fewer cost less on every whole-frame search)
    # labels_and_teacher: the network it replaces (the weights' own) gives its heat as a soft
    # target beside the labels (distillation: a narrow network learns from the wide one).
    targets: Literal["labels", "labels_and_teacher"] = "labels"
    # The runs' racks and skips (world.RackHeights); None: as the weights' own train_config.
    rack_heights: RackHeights | None = None
    workers: int = 2
    threads: int = 2
    # None: as the weights' own train_config (tests make them small).
    runs: int | None = None
    duration_s: float | None = None
    epochs: int | None = None
    calibration_duration_s: float = TrainConfig.calibration_duration_s
    near_calibration_duration_s: float = NearRefinerConfig.calibration_duration_s
    # "none" leaves the held-out evaluation to `capsd bench detect` (the weights' json then
    # has none: the one of the weights before is dropped).
    evaluate: Literal["heldout", "none"] = "heldout"
    eval_duration_s: float = TrainConfig.eval_duration_s


def train_proposal(weights: Path, out_dir: Path, config: ProposalConfig) -> dict[str, Any]:
    """`weights` with a proposal network trained again (`config.network`); into `out_dir`."""
    if config.close_share is not None and not 0.0 <= config.close_share <= 1.0:
        raise CapsdError(f"train proposal: close share {config.close_share}: between 0 and 1")
    if not 0.5 <= config.close_max_range_m <= MAX_CLOSE_RANGE_M:
        raise CapsdError(
            f"train proposal: close max range {config.close_max_range_m} m: "
            f"0.5 to {MAX_CLOSE_RANGE_M}"
        )
    low, high = PROPOSAL_WIDTHS
    if not low <= config.width <= high:
        raise CapsdError(f"train proposal: width {config.width}: {low} to {high} channels")
    started = time.monotonic()
    net = load(weights)
    teacher = None
    if config.targets == "labels_and_teacher":
        teacher = net.proposal if config.network == "main" else net.close_proposal
        if teacher is None:
            raise CapsdError(f"{weights}: no close proposal network to learn from")
    meta = stored_meta(weights)
    base = stored_train_config(weights, meta)
    train_config = dataclasses.replace(
        base,
        seed=config.seed,
        workers=config.workers,
        threads=config.threads,
        close_share=(
            config.close_share
            if config.close_share is not None
            else CLOSE_SHARE
            if config.network == "close"
            else base.close_share
        ),
        runs=base.runs if config.runs is None else config.runs,
        duration_s=base.duration_s if config.duration_s is None else config.duration_s,
        proposal_epochs=base.proposal_epochs if config.epochs is None else config.epochs,
        calibration_duration_s=config.calibration_duration_s,
        rack_heights=base.rack_heights if config.rack_heights is None else config.rack_heights,
    )
    if train_config.inputs != net.inputs:
        raise CapsdError(f"{weights}: its networks read {net.inputs}, its train_config says not")
    torch.manual_seed(config.seed)
    torch.set_num_threads(config.threads)
    gen = torch.Generator().manual_seed(config.seed)
    plans = train_config.plans(runs=train_config.runs, seed=train_config.seed)
    samples = render(plans, workers=config.workers, inputs=net.inputs)
    samples.crops.clear()  # the refiners are kept: only the grids train
    samples.crop_targets.clear()
    samples.crop_ranges_m.clear()
    close = sum(plan.standoff_m is not None and plan.rov_mode == "profile" for plan in plans)
    print(
        f"{len(samples.grids)} frames ({int(sum(t[0] for t in samples.grid_targets))} with the "
        f"ROV) from {len(plans)} runs ({close} of them the ROV profiling close)"
    )
    trainee = PolarNet(inputs=net.inputs)  # from scratch, as train detector
    if config.width != PROPOSAL_WIDTH:
        trainee.proposal = ProposalNet(config.width, channels=2 + net.inputs.extra_planes)
    losses = _train_proposal(trainee, samples, train_config, gen, teacher=teacher)
    if config.network == "close":
        net.close_proposal = trainee.proposal
        net.close_max_range_m.fill_(config.close_max_range_m)
    else:
        net.proposal = trainee.proposal
    trained_s = time.monotonic() - started
    meta["proposal" if config.network == "close" else "main_proposal"] = {
        "trained_by": "capsd train proposal",
        "from_weights": str(weights),
        "config": asdict(config),
        "runs": len(plans),
        "frames": len(samples.grids),
        "loss_first_last": [_mean(losses[:50]), _mean(losses[-50:])],
        "seconds_render_and_train": round(trained_s, 1),
        # What this network was trained with; `train_config` stays the refiners'.
        "train_config": asdict(train_config),
    }
    meta.pop("evaluation", None)  # of the weights before; `capsd bench detect` measures these
    out_dir.mkdir(parents=True, exist_ok=True)
    meta["calibration"] = calibrate(net, duration_s=train_config.calibration_duration_s)
    if net.near_refine is not None:
        near_meta = dict(meta.get("near_refiner", {}))
        near_meta["calibration"] = calibrate_near(
            net, duration_s=config.near_calibration_duration_s
        )
        meta["near_refiner"] = near_meta
    path = save_evaluated(
        net, out_dir, meta, evaluate=config.evaluate, eval_duration_s=config.eval_duration_s
    )
    print(f"weights: {path}; total {time.monotonic() - started:.0f} s")
    return meta
