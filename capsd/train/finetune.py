"""`capsd train detector --finetune LABELS`: adapt the shipped weights to a site's own frames.

The labelled pings of a first dive (`capsd label`) become training samples exactly as the
simulator's do (the grid with the ROV's centre, crops around it with a proposal's offsets,
crops of the brightest places and of the network's own wrong peaks as negatives). A few
simulated runs of the training variety are mixed in, so the network keeps what it knew; then
a few epochs of both networks at a lower learning rate, from the shipped weights. The
operating point is set again on the site's own frames (`recalibrate_on_labels`): anything
confident away from the label in a labelled frame is a false alarm. Minutes on 2 cores.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from capsd.errors import CapsdError
from capsd.payloads import SonarLabel
from capsd.services.sonar_detect.polar_input import BeamTable
from capsd.services.sonar_detect.polar_net import PolarNet, load, near_refined, save
from capsd.sonar_geometry import fan_distance_m
from capsd.train.data import Samples, plan_runs, render, samples_of_ping
from capsd.train.detector import (
    TrainConfig,
    _train_proposal,
    _train_refine,
    operating_offset,
)
from capsd.train.labelling import LabelledPing, frames_of, read_labels

# A BlueROV2's echo: about 0.4 m deep in range, 0.5 m across (for the extent targets).
ECHO_RANGE_EXTENT_M = 0.4
ECHO_CROSS_EXTENT_M = 0.5


@dataclass(frozen=True)
class FinetuneConfig:
    seed: int = 0
    proposal_epochs: int = 3
    refine_epochs: int = 3
    lr: float = 5e-4
    replay_runs: int = 8  # simulated runs of the training variety mixed in
    replay_duration_s: float = 20.0
    workers: int = 2
    threads: int = 2


def _label_of(stamp_ns: int, ping_id: int, range_m: float, azimuth_rad: float) -> SonarLabel:
    half_cross = ECHO_CROSS_EXTENT_M / 2 / max(range_m, 0.5)
    return SonarLabel(
        stamp_ns=stamp_ns,
        seq=0,
        ping_id=ping_id,
        visible=True,
        range_m=range_m,
        azimuth_rad=azimuth_rad,
        elevation_rad=0.0,
        range_min_m=max(range_m - ECHO_RANGE_EXTENT_M / 2, 0.0),
        range_max_m=range_m + ECHO_RANGE_EXTENT_M / 2,
        azimuth_min_rad=azimuth_rad - half_cross,
        azimuth_max_rad=azimuth_rad + half_cross,
        rov_position_m=(0.0, 0.0, 0.0),
    )


# On the labelled frames, anything confident further than this from the label is a false alarm.
FALSE_ALARM_M = 0.8
MAX_SITE_FALSE_ALARMS_PER_FRAME = 0.005


def recalibrate_on_labels(net: PolarNet, labels: list[LabelledPing]) -> dict[str, float]:
    """The operating point on the site's own frames (the logit offset).

    The labels say where the ROV is, so a
    confident candidate anywhere else in a labelled frame is a false alarm. The logit offset
    becomes the lowest that keeps those at most MAX_SITE_FALSE_ALARMS_PER_FRAME (never lower
    than the shipped one: fine-tuning only ever makes the detector more cautious here).
    """
    from capsd.services.sonar_detect.cnn import NETWORK_ALONE, Candidate, CnnDetector

    shipped = float(net.logit_offset)
    net.logit_offset.zero_()
    detector = CnnDetector(NETWORK_ALONE, net=net)
    false_logits: list[float] = []
    frames = 0
    # Candidates the near refiner scores keep its own operating point (train.near_refiner);
    # fine-tuning adapts the main refiner only.
    for frame, label in frames_of(labels):
        frames += 1
        where = Candidate(label.range_m, label.azimuth_rad)
        half_fov_rad = BeamTable(frame.azimuths_rad).half_fov_rad
        for d in detector.detect(frame):
            near = near_refined(
                net, range_m=d.range_m, azimuth_rad=d.azimuth_rad, half_fov_rad=half_fov_rad
            )
            if not near and fan_distance_m(d, where) > FALSE_ALARM_M:
                c = min(max(d.confidence, 1e-12), 1 - 1e-12)
                false_logits.append(math.log(c / (1 - c)))
    site = operating_offset(false_logits, frames, MAX_SITE_FALSE_ALARMS_PER_FRAME)
    offset = max(shipped, site)
    net.logit_offset.fill_(offset)
    return {"shipped_offset": round(shipped, 4), "site_offset": round(site, 4), "offset": offset}


def finetune(
    weights: Path, labels_dir: Path, out_dir: Path, config: FinetuneConfig
) -> dict[str, Any]:
    """Fine-tune `weights` on the labels in `labels_dir`; write polar_net.pt/.json to out_dir."""
    started = time.monotonic()
    torch.manual_seed(config.seed)
    torch.set_num_threads(config.threads)
    gen = torch.Generator().manual_seed(config.seed)
    net = load(weights)
    labels = read_labels(labels_dir)
    if not labels:
        raise CapsdError(f"{labels_dir}: no labelled pings left to fine-tune on")
    rng = np.random.default_rng(config.seed)
    samples = Samples()
    for frame, label in frames_of(labels):
        ping = _label_of(frame.stamp_ns, frame.ping_id, label.range_m, label.azimuth_rad)
        samples.extend(samples_of_ping(frame, ping, rng, proposal=net.proposal, inputs=net.inputs))
    site_crops = len(samples.crops)
    plans = plan_runs(
        runs=config.replay_runs,
        seed=config.seed + 1000,
        duration_s=config.replay_duration_s,
        sonar_hz=2.0,
    )
    samples.extend(render(plans, workers=config.workers, inputs=net.inputs))
    train_config = TrainConfig(
        seed=config.seed,
        threads=config.threads,
        proposal_epochs=config.proposal_epochs,
        proposal_lr=config.lr,
        refine_epochs=config.refine_epochs,
        refine_lr=config.lr,
    )
    proposal_losses = _train_proposal(net, samples, train_config, gen)
    refine_losses = _train_refine(net, samples, train_config, gen, label="fine-tuning refiner")
    operating_point = recalibrate_on_labels(net, labels)
    out_dir.mkdir(parents=True, exist_ok=True)
    meta: dict[str, Any] = {
        "finetuned_from": str(weights),
        "labels": str(labels_dir),
        "finetune_config": asdict(config),
        "samples": {
            "labelled_pings": len(labels),
            "site_crops": site_crops,
            "replay_crops": len(samples.crops) - site_crops,
        },
        "loss": {
            "proposal_last": float(np.mean(proposal_losses[-20:])),
            "refine_last": float(np.mean(refine_losses[-20:])),
        },
        "operating_point": operating_point,
        "seconds": round(time.monotonic() - started, 1),
        "torch": str(torch.__version__),
    }
    out = out_dir / "polar_net.pt"
    save(net, out, meta=meta)
    (out_dir / "polar_net.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")
    print(f"fine-tuned weights: {out} ({meta['seconds']:.0f} s)")
    return meta
