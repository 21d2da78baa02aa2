"""`capsd bench detect`: detectors on held-out simulated frames, against the labels.

For each run (tank, trajectory, seed not used in tuning) the simulator renders frames and
labels; each detector's candidates are matched to the truth (within 0.5 m). Reported per
detector, for pings without and with clutter overlapping the ROV: detection rate, false alarms
per frame, range and azimuth error (median and p95 of absolute values), and the time per frame.
The paper's pipeline is the baseline: the centre of a perfect bounding box of the ROV's echo in
the Cartesian fan image, converted back to (R, theta).
"""

from __future__ import annotations

import math
import statistics
import time
from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np

from capsd.payloads import SonarFrame, SonarLabel
from capsd.progress import Progress
from services.sonar_detect.classical import ClassicalDetector
from simulator.config import OFFLINE_START_NS, Config, Streams
from simulator.sim import Simulation
from simulator.world import TankName, TrajectoryName

RUNS: tuple[tuple[TankName, TrajectoryName, int], ...] = (
    ("nfp", "square", 101),
    ("nfp", "lawnmower", 102),
    ("nfp", "bouncing", 103),
    ("mockup", "square", 104),
    ("mockup", "random", 105),
)


@dataclass
class Tally:
    frames: int = 0
    visible: int = 0
    hits: int = 0
    false_alarms: int = 0
    range_err: list[float] = field(default_factory=list)
    azimuth_err: list[float] = field(default_factory=list)

    def row(self, name: str) -> str:
        def stat(values: list[float], scale: float) -> str:
            if not values:
                return f"{'-':>7} {'-':>7}"
            a = np.abs(values) * scale
            return f"{float(np.median(a)):>7.3f} {float(np.percentile(a, 95)):>7.3f}"

        rate = self.hits / self.visible if self.visible else float("nan")
        return (
            f"{name:<34} {100 * rate:>6.1f}% {self.false_alarms / max(self.frames, 1):>7.3f} "
            f"{stat(self.range_err, 100)} {stat(self.azimuth_err, 1)}"
        )


def _box_centre(label: SonarLabel) -> tuple[float, float] | None:
    """The paper: the centre of the fan-image box around the echo, back to (R, theta)."""
    if (
        label.range_min_m is None
        or label.range_max_m is None
        or (label.azimuth_min_rad is None or label.azimuth_max_rad is None)
    ):
        return None
    xs, ys = [], []
    for r in (label.range_min_m, label.range_max_m):
        for a in np.linspace(label.azimuth_min_rad, label.azimuth_max_rad, 9):
            xs.append(r * math.cos(a))
            ys.append(r * math.sin(a))
    x, y = (min(xs) + max(xs)) / 2, (min(ys) + max(ys)) / 2
    return math.hypot(x, y), math.atan2(y, x)


def run(*, duration_s: float) -> int:
    tallies: dict[str, Tally] = defaultdict(Tally)
    times: list[float] = []
    bar = Progress(duration_s * len(RUNS), label="detect bench", unit=" s")
    done = 0.0
    for tank, trajectory, seed in RUNS:
        config = Config(
            tank=tank,
            trajectory=trajectory,
            seed=seed,
            streams=Streams(
                lidar="off", imu="off", asv_pose_truth_noise="off", detections_truth_noise="off"
            ),
        )
        sim = Simulation(config, horizon_s=duration_s + 5)
        detector = ClassicalDetector()
        frame: SonarFrame | None = None
        for event in sim.events(start_ns=OFFLINE_START_NS, duration_s=duration_s):
            payload = event.payload
            if isinstance(payload, SonarFrame):
                frame = payload
            elif isinstance(payload, SonarLabel) and frame is not None:
                start = time.perf_counter()
                found = detector.detect(frame)
                times.append(time.perf_counter() - start)
                _score(tallies, "classical", payload, [(d.range_m, d.azimuth_rad) for d in found])
                box = _box_centre(payload)
                _score(
                    tallies,
                    "paper: box centre (perfect box)",
                    payload,
                    [box] if box is not None else [],
                )
                bar.update(done + event.t_s)
        done += duration_s
    bar.close()
    print()
    print(
        f"{len(RUNS)} held-out runs of {duration_s:g} s: "
        + ", ".join(f"{t}/{tr} seed {s}" for t, tr, s in RUNS)
    )
    print(
        f"{'detector / pings':<34} {'detect':>7} {'FA/frm':>7} {'r cm50':>7} {'r cm95':>7} "
        f"{'az50 deg':>8} {'az95':>7}"
    )
    for name in sorted(tallies):
        print(tallies[name].row(name))
    ms = np.array(times) * 1000
    print(
        f"classical detector: {statistics.median(ms):.1f} ms median, "
        f"{float(np.percentile(ms, 99)):.1f} ms p99 per frame (target for the CNN: <= 15 ms)"
    )
    return 0


def _score(
    tallies: dict[str, Tally], detector: str, label: SonarLabel, found: list[tuple[float, float]]
) -> None:
    group = f"{detector} / {'overlap' if label.overlap else 'clear'}"
    tally = tallies[group]
    tally.frames += 1
    match = None
    if label.visible:
        tally.visible += 1
        near = [
            (r, a)
            for r, a in found
            if abs(r - label.range_m) < 0.5 and abs(a - label.azimuth_rad) * label.range_m < 0.5
        ]
        if near:
            match = min(near, key=lambda c: abs(c[0] - label.range_m))
            tally.hits += 1
            tally.range_err.append(match[0] - label.range_m)
            tally.azimuth_err.append(math.degrees(match[1] - label.azimuth_rad))
    tally.false_alarms += len(found) - (1 if match is not None else 0)
