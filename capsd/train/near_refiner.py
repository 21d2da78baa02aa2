"""`capsd train near-refiner`: a second refiner for ROVs nearer than about 1.5 m.

Near the sonar a metric crop (polar_input.crop: 2 cm steps) spans most of the fan, the ROV
seen steeply from above fills up to a third of it, and the main refiner, trained on ROVs
mostly 1.5-20 m off with the sonar 8-30 deg down, doubts it: centred on the truth it called
28 % of the ROVs 0.5-1.5 m off a sonar 60 deg down "ROV" (`capsd bench detect --runs near`'s
runs, by hand, session 55). Training the whole network with near runs took the far bands
down with it (session 48: held out 8-14 m 20.5 -> 6.2 %), so the near ROV gets a refiner of
its own, started from the main one and fine-tuned on crops centred nearer than CROP_WITHIN_M:
near runs (the mockup, the ASV following 0.3-1.0 m off, the sonar 45-75 deg down and turned
up to 70 deg: capsd.train.data's near runs) and training-like runs (their near crops: the
apex's ring-down, the floor, clutter under a shallower sonar). The detector sends it the
candidates nearer than `max_range_m` (cnn.CnnDetector); candidates further off never meet it.
Its operating point is its own: the lowest logit offset leaving at most
MAX_NEAR_FALSE_ALARMS_PER_FRAME false alarms nearer than `max_range_m` on validation runs (the
main network's and near ones, seeds of their own). Deterministic for a seed.
"""

from __future__ import annotations

import copy
import io
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Literal

import torch

from capsd.bench.detect import Run
from capsd.errors import CapsdError
from capsd.services.sonar_detect.polar_input import DEFAULT_INPUTS
from capsd.services.sonar_detect.polar_net import PolarNet, load, save
from capsd.train.data import plan_runs, render
from capsd.train.detector import (
    VALIDATION_RUNS,
    TrainConfig,
    _mean,
    _train_refine,
    operating_offset,
    stored_meta,
    validation_logits,
)

# Crops centred nearer than this train the near refiner (a margin over `max_range_m`: the
# refiner moves a candidate by up to half a metre).
CROP_WITHIN_M = 2.0
MAX_NEAR_FALSE_ALARMS_PER_FRAME = 0.002
# Near validation runs (seeds of their own; the bench's near runs are 108-110).
NEAR_VALIDATION_RUNS: tuple[Run, ...] = (
    ("mockup", "lawnmower", "follow_near", 311),
    ("mockup", "random", "follow_near", 312),
    ("mockup", "square", "follow_near_side", 313),
    ("mockup", "bouncing", "follow_near", 314),
)


@dataclass(frozen=True)
class NearRefinerConfig:
    seed: int = 0
    near_runs: int = 32
    other_runs: int = 24
    duration_s: float = 60.0
    sonar_hz: float = 2.0
    workers: int = 2
    threads: int = 2
    epochs: int = 4
    lr: float = 1e-3
    max_range_m: float = 1.5
    # Seconds of each validation run in each look (split over the bench's three stretches).
    calibration_duration_s: float = 21.0
    # "heldout": the weights' stored evaluation (bench/detect's held-out runs) refreshed with
    # the near refiner; "none" keeps the main network's (stale under 1.5 m).
    evaluate: Literal["heldout", "none"] = "heldout"
    eval_duration_s: float = 20.0


def train_near_refiner(
    weights: Path, out_dir: Path, config: NearRefinerConfig = NearRefinerConfig()
) -> dict[str, Any]:
    """`weights` with a near refiner trained and calibrated; written to `out_dir`."""
    if not 0.5 <= config.max_range_m <= CROP_WITHIN_M:
        raise CapsdError(f"near-refiner: max range {config.max_range_m} m: 0.5 to {CROP_WITHIN_M}")
    started = time.monotonic()
    torch.manual_seed(config.seed)
    torch.set_num_threads(config.threads)
    gen = torch.Generator().manual_seed(config.seed)
    main = load(weights)
    if main.inputs != DEFAULT_INPUTS:
        raise CapsdError(f"{weights}: near-refiner trains on weights with the default inputs only")
    buffer = io.BytesIO()
    torch.save({k: v.cpu() for k, v in main.proposal.state_dict().items()}, buffer)
    # Seeds of their own streams: never the main training's (0-3 with its seed) nor the bench's.
    plans = plan_runs(
        runs=config.near_runs,
        seed=1000 + config.seed,
        duration_s=config.duration_s,
        sonar_hz=config.sonar_hz,
        near_share=1.0,
    ) + plan_runs(
        runs=config.other_runs,
        seed=2000 + config.seed,
        duration_s=config.duration_s,
        sonar_hz=config.sonar_hz,
        far_share=0.2,
    )
    samples = render(
        plans,
        workers=config.workers,
        proposal_state=buffer.getvalue(),
        crops_within_m=CROP_WITHIN_M,
    )
    if not samples.crops:
        raise CapsdError("near-refiner: no crop rendered near the sonar")
    n_pos = int(sum(t[0] for t in samples.crop_targets))
    print(f"{len(samples.crops)} near crops ({n_pos} on the ROV)")
    scratch = copy.deepcopy(main)
    losses = _train_refine(
        scratch,
        samples,
        TrainConfig(threads=config.threads),
        gen,
        label="training the near refiner",
        epochs=config.epochs,
        lr=config.lr,
    )
    net = PolarNet(
        crop_size=main.crop_size,
        refine_channels=main.refine_channels,
        inputs=main.inputs,
        near_refiner=True,
    )
    state = {k: v for k, v in main.state_dict().items() if not k.startswith("near_")}
    net.load_state_dict(state, strict=False)
    assert net.near_refine is not None
    net.near_refine.load_state_dict(scratch.refine.state_dict())
    net.near_max_range_m.fill_(config.max_range_m)
    net.eval()
    meta = stored_meta(weights)
    meta["near_refiner"] = {
        "config": asdict(config),
        "from_weights": str(weights),
        "crops": len(samples.crops),
        "crops_on_rov": n_pos,
        "loss_first_last": [_mean(losses[:50]), _mean(losses[-50:])],
        "seconds_render_and_train": round(time.monotonic() - started, 1),
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "polar_net.pt"
    save(net, path, meta=meta)
    meta["near_refiner"]["calibration"] = calibrate_near(
        net, duration_s=config.calibration_duration_s
    )
    save(net, path, meta=meta)
    if config.evaluate == "heldout":
        from capsd.bench.detect import evaluate_cnn

        meta["evaluation"] = evaluate_cnn(net, duration_s=config.eval_duration_s)
    (out_dir / "polar_net.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")
    print(f"weights: {path}; total {time.monotonic() - started:.0f} s")
    return meta


def calibrate_near(net: PolarNet, *, duration_s: float) -> dict[str, Any]:
    """Set the near refiner's operating point (its logit offset) on validation runs.

    Every candidate nearer than the net's `near_max_range_m` that is not the ROV (or is a
    second one on it) is a false alarm; the offset is the lowest that leaves at most
    MAX_NEAR_FALSE_ALARMS_PER_FRAME of them over all frames, never below the raw 50 %.
    """
    bar_m = float(net.near_max_range_m)
    net.near_logit_offset.zero_()
    runs = NEAR_VALIDATION_RUNS + VALIDATION_RUNS
    logits = validation_logits(
        net,
        duration_s=duration_s,
        runs=runs,
        label="calibrating the near refiner",
        scored=lambda range_m: range_m < bar_m,
        counted=lambda p: p.visible and p.range_m < bar_m,
    )
    offset = max(
        0.0,
        operating_offset(logits.false_logits, logits.frames, MAX_NEAR_FALSE_ALARMS_PER_FRAME),
    )
    net.near_logit_offset.fill_(offset)

    def rates(threshold: float) -> dict[str, float]:
        false_alarms, found = logits.rates(threshold)
        return {"near_false_alarms_per_frame": false_alarms, "near_detection_rate": found}

    result = {
        "near_logit_offset": round(offset, 4),
        "validation_runs": [list(r) for r in runs],
        "frames": logits.frames,
        "pings_with_the_rov_near": len(logits.hit_logits),
        "max_near_false_alarms_per_frame": MAX_NEAR_FALSE_ALARMS_PER_FRAME,
        "at_raw_0.5": rates(0.0),
        "at_operating_point": rates(offset),
    }
    print(f"near operating point: logit offset {offset:.3f}; {result}")
    return result
