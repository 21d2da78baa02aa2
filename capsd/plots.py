"""The benches' PNGs: 3D trajectory against truth, per-axis position, errors, detector examples.

matplotlib with the Agg backend (no display needed); only topside installs draw.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np

from capsd.accuracy import Accuracy

if TYPE_CHECKING:
    from capsd.bench.detect import Example


def _series(accuracy: Accuracy) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t_s of every ping, truth n x 3, estimate n x 3 with NaN where no good fix)."""
    pings = sorted(accuracy.pings, key=lambda p: p.stamp_ns)
    if not pings:
        return np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3))
    t0 = pings[0].stamp_ns
    t = np.array([(p.stamp_ns - t0) / 1e9 for p in pings])
    truth = np.array([p.truth_m for p in pings])
    est = np.array([p.estimate_m if p.estimate_m is not None else (np.nan,) * 3 for p in pings])
    return t, truth, est


def trajectory_3d(
    runs: dict[str, Accuracy], out: Path, *, title: str, truth_label: str = "truth"
) -> None:
    """Truth (black) and each method's estimates in 3D."""
    fig = plt.figure(figsize=(8, 6))
    ax = fig.add_subplot(projection="3d")
    drawn_truth = False
    for name, accuracy in runs.items():
        _, truth, est = _series(accuracy)
        if not drawn_truth and len(truth):
            ax.plot(truth[:, 0], truth[:, 1], truth[:, 2], color="black", lw=1.5, label=truth_label)
            drawn_truth = True
        ax.plot(est[:, 0], est[:, 1], est[:, 2], lw=0.8, label=name)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    # Equal scale on the three axes: a 16 mm error must not look like a zig-zag because z
    # spans centimetres while x spans metres.
    ax.set_box_aspect((1.0, 1.0, 1.0))
    spans = [(float(np.nanmin(v)), float(np.nanmax(v))) for v in _all_points(runs).T]
    if spans and all(np.isfinite(lo) and np.isfinite(hi) for lo, hi in spans):
        half = max(max(hi - lo for lo, hi in spans) / 2.0, 0.5)
        for setter, (lo, hi) in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), spans, strict=True):
            setter((lo + hi) / 2.0 - half, (lo + hi) / 2.0 + half)
    ax.set_title(title)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def _all_points(runs: dict[str, Accuracy]) -> np.ndarray:
    """Every truth and estimate point of every run (n x 3), for a common scale."""
    parts = []
    for accuracy in runs.values():
        _, truth, est = _series(accuracy)
        parts += [truth, est]
    points = np.concatenate(parts) if parts else np.zeros((0, 3))
    return points if len(points) else np.zeros((1, 3))


def per_axis(
    runs: dict[str, Accuracy], out: Path, *, title: str, truth_label: str = "truth"
) -> None:
    """x, y and z over time: truth and each method."""
    fig, axes = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    drawn_truth = False
    for name, accuracy in runs.items():
        t, truth, est = _series(accuracy)
        for k, ax in enumerate(axes):
            if not drawn_truth:
                ax.plot(t, truth[:, k], color="black", lw=1.5, label=truth_label)
            ax.plot(t, est[:, k], lw=0.8, label=name)
        drawn_truth = True
    for k, ax in enumerate(axes):
        ax.set_ylabel(f"{'xyz'[k]} (m)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[0].set_title(title)
    axes[-1].set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def error_histograms(runs: dict[str, Accuracy], out: Path, *, title: str) -> None:
    """Euclidean error histograms, one per method, on a shared millimetre axis."""
    fig, ax = plt.subplots(figsize=(8, 4.5))
    errors = {name: acc.errors()[1] * 1000 for name, acc in runs.items()}
    top = max((float(np.percentile(e, 99)) for e in errors.values() if len(e)), default=1.0)
    top = max(top, 1.0)
    # The range covers the 99th percentile; what lies beyond goes into one bar of its own,
    # drawn apart and labelled, never piled into the last ordinary bin as a false spike.
    bins = np.linspace(0.0, top, 60)
    width = float(bins[1] - bins[0])
    overflow_at = top + 2 * width
    for name, e in errors.items():
        if len(e):
            ax.hist(
                e[e <= top],
                bins=[float(b) for b in bins],
                alpha=0.5,
                label=f"{name} (MED {e.mean():.0f} mm, {int((e > top).sum())} beyond {top:.0f})",
            )
            beyond = int((e > top).sum())
            if beyond:
                ax.bar(overflow_at, beyond, width=width, alpha=0.5, hatch="//")
    ax.axvline(top + width, color="grey", lw=0.8, ls=":")
    ax.text(overflow_at, ax.get_ylim()[1] * 0.95, f"> {top:.0f}", ha="center", fontsize=7)
    ax.set_xlabel("Euclidean error (mm)")
    ax.set_ylabel("pings")
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def sigma_strips(groups: dict[str, list[float]], out: Path, *, title: str, limit: float) -> None:
    """One row of dots per group: each estimate's worst error in its own sigmas, and the limit."""
    names = [name for name, values in groups.items() if values]
    fig, ax = plt.subplots(figsize=(9, 0.45 * len(names) + 1.6))
    rng = np.random.default_rng(0)  # the jitter only spreads the dots; the same every time
    for row, name in enumerate(names):
        values = np.asarray(groups[name])
        ax.scatter(values, row + rng.uniform(-0.25, 0.25, len(values)), s=4, alpha=0.5)
        ax.text(
            max(limit * 1.02, float(values.max()) + 0.1),
            row,
            f"{len(values)}, max {values.max():.2f}",
            va="center",
            fontsize=7,
        )
    ax.axvline(limit, color="red", lw=1.0, label=f"{limit:g} sigma")
    ax.set_yticks(range(len(names)), names, fontsize=7)
    ax.invert_yaxis()
    ax.set_xlim(0.0, max(limit * 1.35, 1.0))
    ax.set_xlabel("largest |error| / sigma over the three axes, per estimate sent")
    ax.set_title(title)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def example_sheets(
    found: dict[tuple[str, str], list[Example]], out: Path, *, detector: str
) -> list[Path]:
    """One PNG per look: a row per run, its misses then its false alarms (`bench.detect`).

    `found` maps (look, run) to examples: a crop of the normalised image
    around the place (range up, cross-range right), what it was, and when.
    """
    paths = []
    for look in dict.fromkeys(look for look, _ in found):
        rows = [
            (run, sorted(found[(lk, run)], key=lambda e: e.kind != "missed"))  # misses first
            for lk, run in found
            if lk == look and found[(lk, run)]
        ]
        if not rows:
            continue
        columns = max(len(examples) for _, examples in rows)
        fig, axes = plt.subplots(
            len(rows), columns, figsize=(1.9 * columns, 2.1 * len(rows)), squeeze=False
        )
        for (run, examples), line in zip(rows, axes, strict=True):
            for k, ax in enumerate(line):
                ax.set_xticks([])
                ax.set_yticks([])
                if k >= len(examples):
                    ax.axis("off")
                    continue
                e = examples[k]
                colour = "green" if e.kind == "missed" else "red"
                show_crop(ax, e.crop, title=e.title, colour=colour, fontsize=6)
                if k == 0:
                    ax.set_ylabel(run, fontsize=6)
        fig.suptitle(
            f"{detector}, look '{look}': misses (green cross: the ROV's centre) and false alarms "
            "(red cross), a 1.9 m square each, range up, cross-range right"
        )
        paths.append(save_sheet(fig, out / f"examples_{look}.png"))
    return paths


def show_crop(ax: Any, crop: np.ndarray, *, title: str, colour: str, fontsize: int) -> None:
    """A polar_input crop of the normalised image, a cross on its centre, titled."""
    from capsd.services.sonar_detect.polar_input import NORM_HIGH, NORM_LOW

    ax.imshow(crop, cmap="gray", vmin=NORM_LOW, vmax=NORM_HIGH, origin="lower")
    c = (crop.shape[0] - 1) / 2
    ax.plot([c], [c], "+", color=colour, markersize=10)
    ax.set_title(title, fontsize=fontsize, color=colour)


def save_sheet(fig: Any, path: Path) -> Path:
    """Lay out (room at the top for its title), write (70 dpi) and close a sheet of crops."""
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - 0.4 / fig.get_figheight()))
    fig.savefig(path, dpi=70)
    plt.close(fig)
    return path
