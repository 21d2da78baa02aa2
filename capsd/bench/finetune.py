"""`capsd bench finetune`: the field team's fine-tune path, measured on a look never trained on.

1. A "first dive": a simulated run whose sonar look lies outside the training variety (five
   knobs past their trained range: water level, dynamic range, gamma, ROV strength, speckle
   shape; capsd.simulator.sonar_look, region "outside"), through the offline pipeline with the
   shipped detector, written as an MCAP recording of what the live system would record
   (frames, ASV poses, fixes).
2. `capsd label` on it: confident tracked fixes projected back into the frames.
3. `capsd train detector --finetune`: the shipped weights adapted to those labels.
4. Both weights on held-out runs at the same site (the dive's look, tank and clutter; other
   trajectories and seeds), and on the bench's held-out looks (what it costs elsewhere):
   detection, false alarms, range and bearing error, before and after.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

from capsd import topics
from capsd.bench.detect import HEADER, MIN_CONFIDENCE, evaluate
from capsd.codec import Codec
from capsd.offline_pipeline import Variant
from capsd.offline_pipeline import run as run_pipeline
from capsd.payloads import AsvPose, Payload, RovAttitude, RovDepth, RovFix, SonarFrame
from capsd.progress import Progress
from capsd.recording import McapRecorder, Sample
from capsd.simulator.config import Config as SimConfig
from capsd.simulator.config import Rates, SonarImageConfig
from capsd.simulator.install_errors import InstallErrorsConfig
from capsd.simulator.sonar_look import OutsideKnob
from capsd.simulator.world import TankName, TrajectoryName

DIVE: tuple[TankName, TrajectoryName, int] = ("nfp", "square", 404)  # the "first dive"
# Held-out runs at the same site (the dive's sonar, tank and look), other motions and seeds:
# (tank, trajectory, ASV mode, seed).
HELD_OUT: tuple[tuple[Any, Any, Any, int], ...] = (
    ("nfp", "lawnmower", "follow", 411),
    ("nfp", "random", "follow", 412),
    ("nfp", "bouncing", "stationary", 413),
)
_KEYS = {
    SonarFrame: topics.SONAR_FRAME.key("tank", "asv"),
    AsvPose: topics.ASV_POSE.key("tank", "asv"),
    RovFix: topics.ROV_FIX.key("tank", "topside"),
    RovDepth: topics.ROV_DEPTH.key("tank", "rov"),
    RovAttitude: topics.ROV_ATTITUDE.key("tank", "rov"),
}


def record_dive(
    path: Path,
    *,
    duration_s: float,
    sonar_hz: float,
    outside_knobs: tuple[OutsideKnob, ...] | None = None,
) -> int:
    """The first dive through the offline pipeline into an MCAP recording; fixes recorded.

    `outside_knobs`: the knobs of its look beyond the range trained on (None: all five).
    """
    tank, trajectory, seed = DIVE
    sim = SimConfig(
        tank=tank,
        trajectory=trajectory,
        seed=seed,
        sonar_image=SonarImageConfig(variety="outside", outside_knobs=outside_knobs),
        rates=Rates(sonar_hz=sonar_hz),
        install_errors=InstallErrorsConfig(mode="off"),  # the detector's path, not the mounts'
    )
    codecs: dict[type, Codec[Any]] = {cls: Codec(cls) for cls in _KEYS}
    recorder = McapRecorder(path)
    fixes = 0

    def sink(payload: Payload) -> None:
        nonlocal fixes
        cls = type(payload)
        codec = codecs[cls]
        recorder.write(Sample(_KEYS[cls], codec.encoding, codec.encode(payload), payload.stamp_ns))
        fixes += isinstance(payload, RovFix) and payload.quality == "good"

    bar = Progress(duration_s, label="first dive (offline pipeline)", unit=" sim s")
    try:
        run_pipeline(
            sim, duration_s=duration_s, variants=[Variant("capsd")], progress=bar, sink=sink
        )
    finally:
        recorder.close()
        bar.close()
    return fixes


def _cnn(weights: Path) -> Any:
    from capsd.services.sonar_detect.cnn import CnnDetector, CnnSettings

    return CnnDetector(CnnSettings(weights=weights)).detect


def run(
    *,
    out: Path,
    duration_s: float,
    eval_duration_s: float,
    outside_knobs: tuple[OutsideKnob, ...] | None = None,
) -> int:
    """The whole path; `outside_knobs`: the site look's knobs beyond training (None: five)."""
    from capsd.services.locator.service import Config as LocatorConfig
    from capsd.services.sonar_detect.cnn import DEFAULT_WEIGHTS
    from capsd.train.finetune import FinetuneConfig, finetune
    from capsd.train.labelling import label_recording, write_labels

    out.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    recording = out / "first_dive.mcap"
    good = record_dive(recording, duration_s=duration_s, sonar_hz=5.0, outside_knobs=outside_knobs)
    beyond = "all five" if outside_knobs is None else ", ".join(outside_knobs) or "none"
    print(f"the site's look: beyond the range trained on {beyond}")
    print(f"first dive: {recording} ({recording.stat().st_size / 1e6:.0f} MB), {good} good fixes")
    labels, summary = label_recording(recording, sonar=LocatorConfig().sonar)
    print(f"labels: {summary}")
    if not labels:
        print("no confident tracked fix in the first dive: nothing to fine-tune on")
        return 1
    write_labels(labels, out / "labels")
    tuned = finetune(DEFAULT_WEIGHTS, out / "labels", out / "weights", FinetuneConfig())
    detectors = {"shipped": _cnn(DEFAULT_WEIGHTS), "fine-tuned": _cnn(out / "weights/polar_net.pt")}
    # The dive's own look (what a site's fine-tune is for), and, to see what it costs
    # elsewhere, the bench's held-out look of each run.
    site = evaluate(
        detectors,
        duration_s=eval_duration_s,
        runs=HELD_OUT,
        looks=("outside",),
        look_seed=DIVE[2],
        outside_knobs=outside_knobs,
    )
    tallies = {name.replace("/ outside /", "/ this site /"): t for name, t in site.items()}
    tallies.update(
        evaluate(detectors, duration_s=eval_duration_s, runs=HELD_OUT, looks=("heldout",))
    )
    print(f"\nheld-out runs, {eval_duration_s:g} s each; confidence >= {MIN_CONFIDENCE}")
    print(HEADER)
    rows = {}
    for name in sorted(tallies):
        if name.startswith("paper"):
            continue
        rows[name] = tallies[name].summary()  # every group: clear/overlap, range bands
        if name.endswith("/ all"):
            print(tallies[name].row(name))
    result = {
        "dive": list(DIVE),
        "dive_duration_s": duration_s,
        # The site look's knobs beyond the range trained on (null: all five).
        "outside_knobs": None if outside_knobs is None else list(outside_knobs),
        "good_fixes": good,
        "labels": asdict(summary),
        "held_out": [list(r) for r in HELD_OUT],
        "eval_duration_s": eval_duration_s,
        "groups": rows,
        "finetune_seconds": tuned["seconds"],
        "finetune_samples": tuned["samples"],
        "operating_point": tuned["operating_point"],
        "seconds": round(time.monotonic() - started, 1),
    }
    (out / "finetune.json").write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")
    print(f"\n{out / 'finetune.json'}; {result['seconds']:.0f} s in all")
    return 0
