"""`capsd bench consistency`: the locator's covariance floor derived, and checked on held-out runs.

The locator adds `unmodelled_sigma_m` to every covariance it reports, for what it does not
model (where on the hull the echo's centre lies, map and mount residuals). This bench derives
that floor instead of choosing it: on tuning runs, the smallest floor with which 95 % of the
fixes' NEES (normalised estimation error squared, 3 degrees of freedom) fall under the
chi-square 95 % bound; then it reports the NEES on held-out runs (the pond, never tuned on)
with the derived floor, with the configured one and with none.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from capsd.accuracy import CHI2_3_95, Scored, nees
from capsd.offline_pipeline import Variant, run
from capsd.progress import Progress
from capsd.services.locator.service import Config as LocatorConfig
from capsd.simulator.config import Config as SimConfig
from capsd.simulator.install_errors import InstallErrorsConfig
from capsd.simulator.world import TankName, TrajectoryName

Run = tuple[TankName, TrajectoryName, int]
TUNING_RUNS: tuple[Run, ...] = (
    ("nfp", "square", 801),
    ("nfp", "lawnmower", 802),
    ("nfp", "random", 803),
    ("mockup", "random", 804),
)
HELD_OUT_RUNS: tuple[Run, ...] = (("pond", "lawnmower", 805), ("pond", "random", 806))
TARGET_SHARE = 0.95
BARE = Variant("ours, no covariance floor", unmodelled_sigma_m=0.0)


def floor_for(pings: list[Scored], *, share: float = TARGET_SHARE) -> float:
    """The smallest floor (m) with which `share` of the NEES fall under the 95 % bound."""
    low, high = 0.0, 0.5
    if len(nees(pings)) == 0:
        return 0.0
    if float(np.mean(nees(pings, floor_m=low) <= CHI2_3_95)) >= share:
        return 0.0
    for _ in range(30):
        mid = (low + high) / 2
        if float(np.mean(nees(pings, floor_m=mid) <= CHI2_3_95)) >= share:
            high = mid
        else:
            low = mid
    return high


def _pings(runs: tuple[Run, ...], duration_s: float, bar: Progress, done: float) -> list[Scored]:
    out: list[Scored] = []
    for k, (tank, trajectory, seed) in enumerate(runs):
        # The floor for what no model carries; the installation has its own section.
        config = SimConfig(
            tank=tank,
            trajectory=trajectory,
            seed=seed,
            install_errors=InstallErrorsConfig(mode="off"),
        )
        result = run(
            config,
            duration_s=duration_s,
            variants=[BARE],
            progress=bar,
            progress_offset_s=done + k * duration_s,
        )
        out += result[BARE.name].pings
    return out


def _row(name: str, pings: list[Scored], floor_m: float) -> dict[str, Any]:
    values = nees(pings, floor_m=floor_m)
    return {
        "runs": name,
        "floor_mm": round(floor_m * 1000, 1),
        "fixes": len(values),
        "nees_mean": round(float(np.mean(values)), 2) if len(values) else None,
        "within_95": round(float(np.mean(values <= CHI2_3_95)), 4) if len(values) else None,
    }


def bench(*, duration_s: float, out: Path | None) -> dict[str, Any]:
    runs = len(TUNING_RUNS) + len(HELD_OUT_RUNS)
    bar = Progress(duration_s * runs, label="consistency bench", unit=" sim s")
    tuning = _pings(TUNING_RUNS, duration_s, bar, 0.0)
    held_out = _pings(HELD_OUT_RUNS, duration_s, bar, duration_s * len(TUNING_RUNS))
    bar.close()
    derived = floor_for(tuning)
    configured = LocatorConfig().unmodelled_sigma_m
    rows = [
        _row("tuning", tuning, 0.0),
        _row("tuning", tuning, derived),
        _row("held-out pond", held_out, 0.0),
        _row("held-out pond", held_out, configured),
        _row("held-out pond", held_out, derived),
    ]
    print(
        f"tuning runs {', '.join(f'{t}/{tr} seed {s}' for t, tr, s in TUNING_RUNS)}; held-out "
        f"{', '.join(f'{t}/{tr} seed {s}' for t, tr, s in HELD_OUT_RUNS)}; {duration_s:g} s each"
    )
    print(
        f"derived floor (smallest with {TARGET_SHARE:.0%} of NEES under the chi-square 3-dof 95 % "
        f"bound {CHI2_3_95} on the tuning runs): {derived * 1000:.1f} mm; configured: "
        f"{configured * 1000:.1f} mm"
    )
    print(f"{'runs':<14} {'floor mm':>9} {'fixes':>6} {'mean NEES':>10} {'within 95 %':>12}")
    for r in rows:
        within = "-" if r["within_95"] is None else f"{100 * r['within_95']:.1f} %"
        print(
            f"{r['runs']:<14} {r['floor_mm']:>9} {r['fixes']:>6} {r['nees_mean']!s:>10} "
            f"{within:>12}"
        )
    print("consistent: mean NEES about 3, 95 % within the bound")
    figures = {
        "duration_s": duration_s,
        "tuning_runs": [list(r) for r in TUNING_RUNS],
        "held_out_runs": [list(r) for r in HELD_OUT_RUNS],
        "derived_floor_mm": round(derived * 1000, 2),
        "configured_floor_mm": round(configured * 1000, 2),
        "rows": rows,
    }
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(figures, indent=1) + "\n")
    return figures
