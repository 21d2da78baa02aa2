"""`capsd train range-bias`: the detector's range error by where a near ROV lies in the aperture.

On runs drawn as training runs are (the tuning tanks, the training region of the sonar's look,
seeds of their own: never the bench's held-out runs nor the held-out pond), the configured
CNN searches each ping through the depth-aware search (the true ASV pose and ROV depth, as
`capsd bench detect --depth-gate truth`); each detection matched to the ROV nearer than
WITHIN_M is binned by the elevation the gate puts it at (a share of the half aperture), and
each bin's median signed range error is the table (capsd.services.sonar_detect.range_bias).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from capsd.bench.detect import MATCH_M, MIN_CONFIDENCE, truth_gate
from capsd.progress import Progress
from capsd.services.sonar_detect.range_bias import RangeBias, save
from capsd.services.sonar_detect.service import Config as DetectConfig
from capsd.services.sonar_detect.service import detect_gated, make_detector
from capsd.simulator.config import OFFLINE_START_NS
from capsd.simulator.sim import Simulation
from capsd.train.data import plan_runs

WITHIN_M = 4.0  # beyond it a BlueROV2 spans less than a third of a 20 deg aperture
SHARE_EDGES = (-1.6, -1.2, -0.8, -0.4, 0.0, 0.4, 0.8, 1.2, 1.6)
MIN_SAMPLES = 30  # a bin with fewer matched detections keeps bias 0
SEED = 2929  # the runs' own stream (training and validation draw from others)


def measure(*, runs: int, duration_s: float, seed: int = SEED) -> RangeBias:
    """The table from `runs` runs of `duration_s` each (pings at 10 Hz)."""
    detect_config = DetectConfig()  # the shipped weights
    plans = plan_runs(
        runs=runs, seed=seed, duration_s=duration_s, sonar_hz=10.0, start_spread_s=300.0
    )
    errors: list[list[float]] = [[] for _ in range(len(SHARE_EDGES) - 1)]
    bar = Progress(float(len(plans)), label="range bias", unit=" runs")
    half_aperture_deg = 0.0
    for k, plan in enumerate(plans):
        config = plan.config()
        half_aperture_deg = config.sonar.vertical_aperture_deg / 2.0
        detector = make_detector(detect_config)  # a fresh track per run
        sim = Simulation(config, horizon_s=plan.start_s + duration_s + 5.0)
        for t_s, frame, label in sim.labelled_pings(
            start_ns=OFFLINE_START_NS, duration_s=duration_s, from_s=plan.start_s
        ):
            gate = truth_gate(sim, t_s, label)
            found, _ = detect_gated(detector, frame, gate, min_confidence=MIN_CONFIDENCE)
            if not label.visible or label.range_m >= WITHIN_M:
                continue
            near = [
                d
                for d in found
                if abs(d.range_m - label.range_m) < MATCH_M
                and abs(d.azimuth_rad - label.azimuth_rad) * label.range_m < MATCH_M
            ]
            if not near:
                continue
            match = max(near, key=lambda d: d.confidence)
            elevation = gate.elevation_at(match.range_m, match.azimuth_rad)
            if elevation is None:
                continue
            share = math.degrees(elevation) / half_aperture_deg
            b = int(np.searchsorted(SHARE_EDGES, share, side="right")) - 1
            if 0 <= b < len(errors):
                errors[b].append(match.range_m - label.range_m)
        bar.update(float(k + 1))
    bar.close()
    return RangeBias(
        share_edges=SHARE_EDGES,
        bias_m=tuple(
            round(float(np.median(e)), 4) if len(e) >= MIN_SAMPLES else 0.0 for e in errors
        ),
        samples=tuple(len(e) for e in errors),
        within_m=WITHIN_M,
        half_aperture_deg=half_aperture_deg,
        provenance={
            "command": f"capsd train range-bias --runs {runs} --duration {duration_s:g}",
            "runs": runs,
            "seed": seed,
            "duration_s": duration_s,
            "weights": "shipped",  # the service's default config: the shipped weights
            "tanks": "nfp, mockup (training runs' tanks; pond held out)",
        },
    )


def run(*, runs: int, duration_s: float, out: Path) -> RangeBias:
    """Measure the table, write it to `out`, print it."""
    table = measure(runs=runs, duration_s=duration_s)
    out.parent.mkdir(parents=True, exist_ok=True)
    save(table, out)
    print("elevation share of the half aperture -> median signed range error (cm), detections")
    edges = table.share_edges
    for k, (bias, n) in enumerate(zip(table.bias_m, table.samples, strict=True)):
        print(f"  {edges[k]:+.1f} .. {edges[k + 1]:+.1f}: {bias * 100:+6.2f}  ({n})")
    print(f"written: {out}")
    return table


__all__ = ["measure", "run"]
