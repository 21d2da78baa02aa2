"""Fix accuracy against the simulator's truth: pairing, the paper's figures, a table row.

A fix and the label of the same ping share `stamp_ns` (the simulator stamps its label with the
frame's stamp), so pairing holds whatever the vehicles' clocks. The figures are the paper's:
x/y/z RMSE, mean Euclidean distance (MED), and ours on top: p95 and availability (the share of
pings that gave a good fix, i.e. one the bridge would send). The estimate scored is what goes
to the autopilot: the tracked position, or the single-ping fix for per-frame methods.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from capsd.payloads import RovFix, SonarLabel


@dataclass(frozen=True)
class Scored:
    """One ping: when, the estimate sent (None unless good), the single-ping fix, the truth."""

    stamp_ns: int
    estimate_m: tuple[float, float, float] | None
    raw_m: tuple[float, float, float] | None
    truth_m: tuple[float, float, float]
    covariance_m2: tuple[float, ...] | None = None  # the reported covariance of the estimate


def fix_estimate(
    fix: RovFix,
) -> tuple[tuple[float, float, float] | None, tuple[float, ...] | None]:
    """The position a fix offers and its covariance: the tracked one, else the single-ping one."""
    if fix.position_m is not None:
        return fix.position_m, fix.covariance_m2
    return fix.raw_position_m, fix.raw_covariance_m2


def scored(fix: RovFix, truth_m: tuple[float, float, float]) -> Scored:
    """A fix against where the ROV truly was (the simulator's label, or a reference)."""
    good = fix.quality == "good"
    estimate, covariance = fix_estimate(fix) if good else (None, None)
    raw = fix.raw_position_m if good else None
    return Scored(fix.stamp_ns, estimate, raw, truth_m, covariance)


def score(fix: RovFix, label: SonarLabel) -> Scored:
    return scored(fix, label.rov_position_m)


# 95 % of a chi-square law with 3 degrees of freedom: a consistent 3-D estimate's NEES is
# below this 95 % of the time.
CHI2_3_95 = 7.815


def nees(pings: list[Scored], *, floor_m: float = 0.0) -> np.ndarray:
    """Normalised estimation error squared per ping with a covariance (plus floor_m^2 I)."""
    out = []
    for p in pings:
        if p.estimate_m is None or p.covariance_m2 is None:
            continue
        error = np.subtract(p.estimate_m, p.truth_m)
        cov = np.array(p.covariance_m2).reshape(3, 3) + np.eye(3) * floor_m**2
        out.append(float(error @ np.linalg.solve(cov, error)))
    return np.array(out)


@dataclass
class Accuracy:
    """Scored pings of one run (or one method); `summary()` gives the table's figures."""

    pings: list[Scored] = field(default_factory=list)

    def add(self, scored: Scored) -> None:
        self.pings.append(scored)

    def errors(self) -> tuple[np.ndarray, np.ndarray]:
        """(per-axis errors n x 3, Euclidean errors n) of the good estimates."""
        pairs = [(p.estimate_m, p.truth_m) for p in self.pings if p.estimate_m is not None]
        if not pairs:
            return np.zeros((0, 3)), np.zeros(0)
        delta = np.array([e for e, _ in pairs]) - np.array([t for _, t in pairs])
        return delta, np.linalg.norm(delta, axis=1)

    def summary(self) -> dict[str, Any]:
        delta, dist = self.errors()
        n = len(self.pings)
        out: dict[str, Any] = {
            "pings": n,
            "good": len(dist),
            "availability": round(len(dist) / n, 4) if n else None,
        }
        if len(dist):
            rmse = np.sqrt(np.mean(delta**2, axis=0))
            out.update(
                rmse_x_mm=round(float(rmse[0]) * 1000, 1),
                rmse_y_mm=round(float(rmse[1]) * 1000, 1),
                rmse_z_mm=round(float(rmse[2]) * 1000, 1),
                med_mm=round(float(np.mean(dist)) * 1000, 1),
                median_mm=round(float(np.median(dist)) * 1000, 1),
                p95_mm=round(float(np.percentile(dist, 95)) * 1000, 1),
            )
            raw = [math.dist(p.raw_m, p.truth_m) for p in self.pings if p.raw_m is not None]
            if raw:
                out["single_ping_med_mm"] = round(float(np.mean(raw)) * 1000, 1)
            values = nees(self.pings)
            if len(values):
                out["nees_mean"] = round(float(np.mean(values)), 2)
                out["nees_within_95"] = round(float(np.mean(values <= CHI2_3_95)), 4)
        return out


def common_pings(methods: list[Accuracy]) -> list[Accuracy]:
    """Each method restricted to the pings every one of them has a good estimate for."""
    shared = set.intersection(
        *({p.stamp_ns for p in m.pings if p.estimate_m is not None} for m in methods)
    )
    return [Accuracy([p for p in m.pings if p.stamp_ns in shared]) for m in methods]


def bootstrap_med(
    ours: Accuracy,
    other: Accuracy,
    *,
    block: int = 20,
    resamples: int = 1000,
    seed: int = 0,
) -> dict[str, Any]:
    """MED of each and their ratio with 95 % intervals, on pings both fix (moving blocks).

    Errors a few pings apart are correlated (tracking, slow drifts), so pings are resampled in
    runs of `block` consecutive common pings (1 s at 20 Hz), not one by one.
    """
    a, b = common_pings([ours, other])
    ea, eb = a.errors()[1], b.errors()[1]
    n = len(ea)
    out: dict[str, Any] = {"common_pings": n}
    if n == 0:
        return out
    rng = np.random.default_rng(seed)
    size = min(block, n)
    starts = rng.integers(0, n - size + 1, size=(resamples, math.ceil(n / size)))
    index = (starts[:, :, None] + np.arange(size)).reshape(resamples, -1)[:, :n]
    med_a, med_b = ea[index].mean(axis=1), eb[index].mean(axis=1)
    ratio = med_a / med_b

    def interval(values: np.ndarray, scale: float, digits: int) -> list[float]:
        low, high = np.percentile(values, [2.5, 97.5])
        return [round(float(low) * scale, digits), round(float(high) * scale, digits)]

    out.update(
        ours_med_mm=round(float(ea.mean()) * 1000, 1),
        ours_med_ci_mm=interval(med_a, 1000, 1),
        other_med_mm=round(float(eb.mean()) * 1000, 1),
        other_med_ci_mm=interval(med_b, 1000, 1),
        ratio=round(float(ea.mean() / eb.mean()), 3),
        ratio_ci=interval(ratio, 1, 3),
    )
    return out


def row(name: str, s: dict[str, Any]) -> str:
    """A Markdown table row: name, MED, p95, RMSE x/y/z, availability."""

    def mm(key: str) -> str:
        return f"{s[key]:.1f}" if key in s else "-"

    availability = s.get("availability")
    avail = f"{100 * availability:.1f}%" if availability is not None else "-"
    return (
        f"| {name} | {mm('med_mm')} | {mm('p95_mm')} | {mm('rmse_x_mm')} | {mm('rmse_y_mm')} "
        f"| {mm('rmse_z_mm')} | {avail} |"
    )


HEADER = (
    "| run / method | MED mm | p95 mm | RMSE x mm | RMSE y mm | RMSE z mm | availability |\n"
    "|---|---:|---:|---:|---:|---:|---:|"
)


class LivePairing:
    """Online pairing (fixes and labels arrive on different threads, in either order)."""

    def __init__(self, accuracy: Accuracy):
        self.accuracy = accuracy
        self.lock = threading.Lock()
        self.labels: dict[int, SonarLabel] = {}
        self.fixes: dict[int, RovFix] = {}
        self.count_fixes = 0

    def add_label(self, label: SonarLabel) -> None:
        with self.lock:
            fix = self.fixes.pop(label.stamp_ns, None)
            if fix is not None:
                self.accuracy.add(score(fix, label))
            else:
                self.labels[label.stamp_ns] = label
                if len(self.labels) > 2000:
                    del self.labels[min(self.labels)]

    def add_fix(self, fix: RovFix) -> None:
        with self.lock:
            self.count_fixes += 1
            label = self.labels.pop(fix.stamp_ns, None)
            if label is not None:
                self.accuracy.add(score(fix, label))
            else:
                self.fixes[fix.stamp_ns] = fix
                if len(self.fixes) > 2000:
                    del self.fixes[min(self.fixes)]
