"""`capsd train range-bias`: the detector's range error to a near ROV by how the sonar sees it.

Two kinds of runs, drawn as training runs are (the tuning tanks, the training region of the
sonar's look, seeds of their own: never the bench's held-out runs nor the held-out pond):
training-like ones, the sonar pitched as the network was trained (their near ROVs seen less
than TRAINED_DEPRESSION_DEG down), and steep ones, the sonar pitched from `pitch_deg` (a tilt
servo or a steep mount sees the ROV from above) with the ASV following. The configured CNN
searches each ping through the depth-aware search (the true ASV pose and ROV depth, as `capsd
bench detect --depth-gate truth`); each detection matched to the ROV nearer than WITHIN_M is
binned by the line of sight's depression and the elevation the gate puts it at (a share of the
half aperture), and each cell's median signed range error is the table
(capsd.services.sonar_detect.range_bias): under TRAINED_DEPRESSION_DEG from the training-like
runs alone, beyond it from the steep ones. A cell with fewer than MIN_SAMPLES takes its band's
nearest measured cell, a band without any the nearest band's: a step to 0 between measured
cells would be a wrong answer too. `--evaluate` scores tables on runs of a seed of its own.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from capsd.bench.detect import MATCH_M, MIN_CONFIDENCE, truth_gate
from capsd.errors import CapsdError
from capsd.mounts import SonarMountConfig
from capsd.progress import Progress
from capsd.services.sonar_detect.range_bias import (
    DEFAULT_TABLE,
    RangeBias,
    depression_rad,
    load,
    save,
)
from capsd.services.sonar_detect.service import Config as DetectConfig
from capsd.services.sonar_detect.service import detect_gated, make_detector
from capsd.simulator.config import OFFLINE_START_NS
from capsd.simulator.sim import Simulation
from capsd.train.data import RunPlan, plan_runs

WITHIN_M = 4.0  # beyond it a BlueROV2 spans less than a third of a 20 deg aperture
SHARE_EDGES = (-1.6, -1.2, -0.8, -0.4, 0.0, 0.4, 0.8, 1.2, 1.6)
# The training runs' sonars are pitched 8-30 deg (capsd.train.data): with the half aperture
# they see a ROV at most this far down. Under it the table is by elevation alone, measured on
# training-like runs (as before session 43); from it, steep runs' bands.
TRAINED_DEPRESSION_DEG = 40.0
# Depression bands (deg): the first and last take everything beyond them.
DEPRESSION_EDGES_DEG = (-90.0, TRAINED_DEPRESSION_DEG, 50.0, 60.0, 70.0, 90.0)
STEEP_PITCH_DEG = (40.0, 85.0)  # the steep runs' sonars: steeper than trained, to a servo's max
PITCH_DEG = (10.0, 85.0)  # `--evaluate`'s runs: a fixed mount's to a servo's steepest
MIN_SAMPLES = 30  # a cell with fewer matched detections has no median of its own
SEED = 2929  # the runs' own stream (training and validation draw from others)
EVALUATE_SEED = 4343  # `--evaluate`'s runs: a stream no table is measured on


def filled(medians: list[float | None], bins: int) -> list[float]:
    """Cells without a median take the nearest cell of their band that has one.

    Ties go to the cell nearer the aperture's centre. A band with no median at all takes the
    nearest band that has one (the shallower on a tie), bin by bin; none anywhere: all 0.
    """
    centre = (bins - 1) / 2.0
    rows: list[list[float] | None] = []
    for start in range(0, len(medians), bins):
        band = medians[start : start + bins]
        measured = {k: m for k, m in enumerate(band) if m is not None}
        if not measured:
            rows.append(None)
            continue
        rows.append(
            [
                measured[min(measured, key=lambda j: (abs(j - k), abs(j - centre)))]
                for k in range(bins)
            ]
        )
    full = {b: row for b, row in enumerate(rows) if row is not None}
    out: list[float] = []
    for b, maybe in enumerate(rows):
        if maybe is not None:
            out.extend(maybe)
        elif full:
            out.extend(full[min(full, key=lambda j: abs(j - b))])
        else:
            out.extend([0.0] * bins)
    return out


@dataclass(frozen=True)
class Sample:
    """A near ROV in view: how the gate sees its detection and its signed range error.

    A ROV not detected (`error_m` None) is placed where the gate puts its true centre.
    """

    elevation_rad: float  # where the gate puts the detection in the aperture
    depression_rad: float  # the line of sight's angle below the horizontal
    range_m: float  # the detection's (uncorrected)
    error_m: float | None  # detected less true; None: not detected


def training_plans(*, runs: int, duration_s: float, seed: int) -> list[RunPlan]:
    """Runs drawn as the training runs are: their tanks, looks, ASV modes and sonar pitch."""
    return plan_runs(
        runs=runs, seed=seed, duration_s=duration_s, sonar_hz=10.0, start_spread_s=300.0
    )


def steep_plans(
    *, runs: int, duration_s: float, pitch_deg: tuple[float, float], seed: int
) -> list[RunPlan]:
    """Training-like runs with the sonar pitched from `pitch_deg`, the ASV following.

    Each follows the ROV from where its pitch puts it on the boresight (the simulator's standoff
    for a pitch): a stationary ASV or a fixed standoff sees few near ROVs steeply.
    """
    pitch_rng = np.random.default_rng([seed, 0x917C])
    return [
        dataclasses.replace(
            plan,
            asv_mode="follow",
            standoff_m=None,
            sonar_pitch_deg=float(pitch_rng.uniform(*pitch_deg)),
        )
        for plan in training_plans(runs=runs, duration_s=duration_s, seed=seed)
    ]


def samples(plans: list[RunPlan], *, duration_s: float, label: str) -> Iterator[Sample]:
    """The shipped CNN's near-ROV detections on `plans` (10 Hz pings), with a progress bar."""
    detect_config = DetectConfig()  # the shipped weights
    bar = Progress(float(len(plans)), label=label, unit=" runs")
    for k, plan in enumerate(plans):
        detector = make_detector(detect_config)  # a fresh track per run
        sim = Simulation(plan.config(), horizon_s=plan.start_s + duration_s + 5.0)
        for t_s, frame, truth in sim.labelled_pings(
            start_ns=OFFLINE_START_NS, duration_s=duration_s, from_s=plan.start_s
        ):
            gate = truth_gate(sim, t_s, truth)
            found = detect_gated(
                detector, frame, gate, min_confidence=MIN_CONFIDENCE,
                confidence=detect_config.cnn.confidence,
            ).detections  # fmt: skip
            if not truth.visible or truth.range_m >= WITHIN_M:
                continue
            near = [
                d
                for d in found
                if abs(d.range_m - truth.range_m) < MATCH_M
                and abs(d.azimuth_rad - truth.azimuth_rad) * truth.range_m < MATCH_M
            ]
            # Where the gate puts the detection, or the true centre of a ROV not detected.
            if near:
                match = max(near, key=lambda d: d.confidence)
                range_m, azimuth_rad = match.range_m, match.azimuth_rad
                error: float | None = match.range_m - truth.range_m
            else:
                range_m, azimuth_rad, error = truth.range_m, truth.azimuth_rad, None
            elevation = gate.elevation_at(range_m, azimuth_rad)
            if elevation is not None:
                yield Sample(
                    elevation_rad=elevation,
                    depression_rad=depression_rad(gate, range_m),
                    range_m=range_m,
                    error_m=error,
                )
        bar.update(float(k + 1))
    bar.close()


def near_refiner_range_m() -> float:
    """Where the configured detector's near refiner takes over (0: it has none)."""
    from capsd.services.sonar_detect.cnn import CnnDetector

    detector = make_detector(DetectConfig())
    if not isinstance(detector, CnnDetector) or detector.net.near_refine is None:
        return 0.0
    return float(detector.net.near_max_range_m)


def measure(
    *,
    runs: int,
    steep_runs: int,
    duration_s: float,
    pitch_deg: tuple[float, float] = STEEP_PITCH_DEG,
    seed: int = SEED,
) -> RangeBias:
    """The table: `runs` training-like runs and `steep_runs` steep ones, `duration_s` each.

    Where the training runs look (depressions under TRAINED_DEPRESSION_DEG) the table is
    theirs alone, as the network learned there; beyond it, the steep runs'. With a near
    refiner, its detections (nearer than where it takes over) fill a grid of their own.
    """
    half_aperture_deg = SonarMountConfig().vertical_aperture_deg / 2.0  # the runs' sonar
    bins = len(SHARE_EDGES) - 1
    bands = len(DEPRESSION_EDGES_DEG) - 1
    near_m = near_refiner_range_m()
    errors: list[list[float]] = [[] for _ in range(bins * bands)]
    near_errors: list[list[float]] = [[] for _ in range(bins * bands)]
    trained = training_plans(runs=runs, duration_s=duration_s, seed=seed)
    steep = steep_plans(runs=steep_runs, duration_s=duration_s, pitch_deg=pitch_deg, seed=seed + 1)
    for plans, within_training in ((trained, True), (steep, False)):
        label = "range bias, training runs" if within_training else "range bias, steep runs"
        for sample in samples(plans, duration_s=duration_s, label=label):
            if sample.error_m is None:
                continue
            depression = math.degrees(sample.depression_rad)
            if (depression < TRAINED_DEPRESSION_DEG) != within_training:
                continue
            share = math.degrees(sample.elevation_rad) / half_aperture_deg
            b = int(np.searchsorted(SHARE_EDGES, share, side="right")) - 1
            band = int(np.searchsorted(DEPRESSION_EDGES_DEG, depression, side="right")) - 1
            if 0 <= b < bins and 0 <= band < bands:
                grid = near_errors if sample.range_m < near_m else errors
                grid[band * bins + b].append(sample.error_m)

    def medians(cells: list[list[float]]) -> tuple[float, ...]:
        found = [round(float(np.median(e)), 4) if len(e) >= MIN_SAMPLES else None for e in cells]
        return tuple(filled(found, bins))

    low, high = pitch_deg
    return RangeBias(
        share_edges=SHARE_EDGES,
        depression_edges_deg=DEPRESSION_EDGES_DEG,
        bias_m=medians(errors),
        samples=tuple(len(e) for e in errors),
        within_m=WITHIN_M,
        half_aperture_deg=half_aperture_deg,
        near_within_m=near_m,
        near_bias_m=medians(near_errors) if near_m > 0.0 else (),
        near_samples=tuple(len(e) for e in near_errors) if near_m > 0.0 else (),
        provenance={
            "command": f"capsd train range-bias --runs {runs} --steep-runs {steep_runs} "
            f"--duration {duration_s:g} --pitch-deg {low:g} {high:g}",
            "runs": runs,
            "steep_runs": steep_runs,
            "seed": seed,
            "duration_s": duration_s,
            "bands": f"under {TRAINED_DEPRESSION_DEG:g} deg down: training-like runs (sonar "
            f"pitched as trained); from it: steep runs, pitched {low:g}-{high:g} deg "
            "(uniform per run), the ASV following",
            "weights": "shipped",  # the service's default config: the shipped weights
            "near_grid": (
                f"detections nearer than {near_m:g} m (the near refiner's): a grid of their own"
                if near_m > 0.0
                else "none (the weights have no near refiner)"
            ),
            "tanks": "nfp, mockup (training runs' tanks; pond held out)",
            "renderer": "the project's simulator: a real sonar's table is measured on its own",
            "filled": f"a cell with fewer than {MIN_SAMPLES} detections: its band's nearest "
            "cell; a band without any: the nearest band",
        },
    )


# Bands the evaluation reports (deg): a fixed mount's looks, steeper, a servo's steepest.
EVALUATE_BANDS_DEG = ((-90.0, 30.0), (30.0, 50.0), (50.0, 90.0), (-90.0, 90.0))


def evaluate(
    tables: dict[str, RangeBias | None],
    *,
    runs: int,
    duration_s: float,
    pitch_deg: tuple[float, float] = PITCH_DEG,
    seed: int = EVALUATE_SEED,
) -> dict[str, dict[str, dict[str, float | int]]]:
    """Each table's (None: no correction) range error on runs of a seed no table is measured on.

    By depression band (EVALUATE_BANDS_DEG, the last every ping): the near ROVs in view, the
    share detected, and of the detections the signed median, the median and 90th percentile
    of the absolute error (cm). The same detections for every table: a correction moves a
    range, never what is found.
    """
    plans = steep_plans(runs=runs, duration_s=duration_s, pitch_deg=pitch_deg, seed=seed)
    seen = list(samples(plans, duration_s=duration_s, label="evaluate"))
    out: dict[str, dict[str, dict[str, float | int]]] = {}
    for name, table in tables.items():
        rows: dict[str, dict[str, float | int]] = {}
        for low, high in EVALUATE_BANDS_DEG:
            band = [s for s in seen if low <= math.degrees(s.depression_rad) < high]
            errors = np.array(
                [
                    s.error_m
                    - (
                        0.0
                        if table is None
                        else table.at(s.elevation_rad, s.range_m, s.depression_rad)
                    )
                    for s in band
                    if s.error_m is not None
                ]
            )
            key = "all" if (low, high) == (-90.0, 90.0) else f"{max(low, 0.0):g}-{high:g} deg"
            rows[key] = {"in_view": len(band), "detections": int(errors.size)}
            if band:
                rows[key]["found_pct"] = round(100.0 * errors.size / len(band), 1)
            if errors.size:
                rows[key] |= {
                    "signed_median_cm": round(float(np.median(errors)) * 100.0, 2),
                    "abs_median_cm": round(float(np.median(np.abs(errors))) * 100.0, 2),
                    "abs_p90_cm": round(float(np.percentile(np.abs(errors), 90)) * 100.0, 2),
                }
        out[name] = rows
    return out


def run(
    *,
    runs: int,
    steep_runs: int,
    duration_s: float,
    out: Path,
    pitch_deg: tuple[float, float] = STEEP_PITCH_DEG,
) -> RangeBias:
    """Measure the table, write it to `out`, print it."""
    check_pitch(pitch_deg)
    table = measure(runs=runs, steep_runs=steep_runs, duration_s=duration_s, pitch_deg=pitch_deg)
    out.parent.mkdir(parents=True, exist_ok=True)
    save(table, out)
    grids = [(f"{table.near_within_m:g}-{table.within_m:g} m", table.bias_m, table.samples)]
    if table.near_within_m > 0.0:
        near = (f"under {table.near_within_m:g} m (the near refiner's)", table.near_bias_m)
        grids.append((*near, table.near_samples))
    for name, bias, counts in grids:
        _print_grid(table, name, bias, counts)
    print(f"written: {out}")
    return table


def _print_grid(
    table: RangeBias, name: str, bias: tuple[float, ...], counts: tuple[int, ...]
) -> None:
    bins = len(table.share_edges) - 1
    edges = table.share_edges
    print(f"detections {name}: median signed range error (cm) [detections] by depression")
    print("(deg, rows) and elevation share of the half aperture (columns); (f): filled")
    print("            " + " ".join(f"{edges[k]:+.1f}..{edges[k + 1]:+.1f}" for k in range(bins)))
    bands = table.depression_edges_deg
    for band in range(len(bands) - 1):
        cells = []
        for k in range(bins):
            i = band * bins + k
            mark = "f" if counts[i] < MIN_SAMPLES else " "
            cells.append(f"{bias[i] * 100:+5.1f}{mark}[{counts[i]:4d}]")
        print(f"  {bands[band]:+4.0f}..{bands[band + 1]:+3.0f} " + " ".join(cells))


def check_pitch(pitch_deg: tuple[float, float]) -> None:
    """A pitch range 0 <= LOW <= HIGH <= 90 deg, or an error naming the flag."""
    if not 0.0 <= pitch_deg[0] <= pitch_deg[1] <= 90.0:
        raise CapsdError(
            f"--pitch-deg {pitch_deg[0]:g} {pitch_deg[1]:g}: want 0 <= LOW <= HIGH <= 90"
        )


def run_evaluate(
    tables: list[str],
    *,
    runs: int,
    duration_s: float,
    pitch_deg: tuple[float, float] = PITCH_DEG,
    json_out: Path | None = None,
) -> dict[str, dict[str, dict[str, float | int]]]:
    """`--evaluate`: each table (a path, `none`, `shipped`) on the evaluation runs; print it."""
    check_pitch(pitch_deg)
    loaded: dict[str, RangeBias | None] = {}
    for name in tables:
        if name == "none":
            loaded[name] = None
        else:
            loaded[name] = load(DEFAULT_TABLE if name == "shipped" else Path(name))
    figures = evaluate(loaded, runs=runs, duration_s=duration_s, pitch_deg=pitch_deg)
    low, high = pitch_deg
    print(
        f"near-ROV range error (cm) on {runs} runs of {duration_s:g} s, seed {EVALUATE_SEED}, "
        f"sonar pitched {low:g}-{high:g} deg; by the line of sight's depression"
    )
    print(
        f"  {'table':<28} {'depression':<11} {'in view':>7} {'found':>6} {'n':>6} "
        f"{'signed':>7} {'|err| med':>9} {'p90':>6}"
    )
    for name, rows in figures.items():
        for band, row in rows.items():
            found = f"{row['found_pct']:5.1f}%" if "found_pct" in row else "     -"
            head = f"  {name:<28} {band:<11} {row['in_view']:>7} {found} {row['detections']:>6}"
            if "abs_median_cm" not in row:
                print(head)
                continue
            print(
                f"{head} {row['signed_median_cm']:>+7.2f} {row['abs_median_cm']:>9.2f} "
                f"{row['abs_p90_cm']:>6.2f}"
            )
    if json_out is not None:
        record = {
            "command": f"capsd train range-bias --evaluate {' '.join(tables)} --runs {runs} "
            f"--duration {duration_s:g} --pitch-deg {low:g} {high:g}",
            "seed": EVALUATE_SEED,
            "tables": figures,
        }
        json_out.write_text(json.dumps(record, indent=1) + "\n")
        print(f"written: {json_out}")
    return figures


__all__ = ["Sample", "evaluate", "filled", "measure", "run", "run_evaluate", "samples"]
