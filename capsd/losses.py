"""`capsd losses`: where a simulated recording's pings lost their good fix, against the labels.

Each ping the simulator labelled (`sim/label`) is joined by its stamp with the detector's
candidates (`sonar/detections`) and the locator's fix (`locator/fix`) for the same ping, and
put in exactly one class, the first that holds:

- `out_of_view`: the label says the ROV is not in the fan: above or below the vertical
  aperture (its elevation beyond half the aperture), else outside the fan's bearings or range;
- `no_detections`: in view, but the recording has no detections for the ping (the detector
  did not answer, or the frame was dropped);
- `missed`: in view, no candidate at or above `min_confidence` within `match_m` of the label
  (in range and in arc length, as `capsd bench detect` matches); "in the skirt" when the
  ROV's centre lies beyond the aperture's edge and only part of it is in view;
- `no_fix`: a candidate on the ROV, but no fix for the ping in the recording;
- `refused`: a candidate on the ROV, the fix not good; split by the locator's `no_fix_reason`
  (or, with a position, its track state: a tentative track is "unsure" until confirmed);
- `good`: a good fix; split into `on_rov` and `off_rov` (more than `off_m` from the truth).

A good fix on a ping of another class (the ROV out of view or missed) is a fix on something
else: those are counted too (`good_without_rov`). A field recording has no labels: the command
says so rather than guess.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from capsd.codec import Codec
from capsd.errors import CapsdError, PayloadError
from capsd.keys import Subject, subject_of
from capsd.payloads import RovFix, SonarDetections, SonarLabel
from capsd.recording import read

PingClass = Literal["out_of_view", "no_detections", "missed", "no_fix", "refused", "good"]
CLASSES: tuple[PingClass, ...] = (
    "out_of_view", "no_detections", "missed", "no_fix", "refused", "good",
)  # fmt: skip


@dataclass(frozen=True)
class Thresholds:
    """How a ping is judged; the defaults are `capsd bench detect`'s and the demo's."""

    vertical_aperture_rad: float = math.radians(20.0)
    min_confidence: float = 0.5
    match_m: float = 0.5
    off_m: float = 0.3


@dataclass(frozen=True)
class Ping:
    """One labelled ping, judged."""

    stamp_ns: int
    label: SonarLabel
    kind: PingClass
    detail: str  # the sub-class: where out of view, why refused, on or off the ROV
    good_fix: bool
    fix_error_m: float | None  # a good fix's distance from the truth


@dataclass
class Losses:
    """The judged pings, in stamp order, and what the recording held besides."""

    pings: list[Ping] = field(default_factory=list)
    undecodable: int = 0  # payloads on the three keys that did not decode
    label_key: str = ""
    detections_key: str = ""
    fix_key: str = ""

    def counts(self) -> Counter[tuple[PingClass, str]]:
        return Counter((p.kind, p.detail) for p in self.pings)

    def good_without_rov(self) -> int:
        return sum(1 for p in self.pings if p.good_fix and p.kind != "good")


def _one_key(keys: set[str], subject: Subject, what: str, path: Path) -> str:
    found = sorted(k for k in keys if subject_of(k) == subject.value)
    if not found:
        hint = " (a simulated recording: `capsd demo --record`)" if what == "label" else ""
        raise CapsdError(f"{path}: no {what} key (…/{subject.value}){hint}")
    if len(found) > 1:
        raise CapsdError(f"{path}: {len(found)} {what} keys ({', '.join(found)}): expected one")
    return found[0]


def _matched(detections: SonarDetections, label: SonarLabel, t: Thresholds) -> bool:
    return any(
        d.confidence >= t.min_confidence
        and abs(d.range_m - label.range_m) < t.match_m
        and abs(d.azimuth_rad - label.azimuth_rad) * label.range_m < t.match_m
        for d in detections.detections
    )


def _out_of_view(label: SonarLabel, t: Thresholds) -> str:
    half = t.vertical_aperture_rad / 2.0
    if label.elevation_rad > half:
        return "above the aperture"
    if label.elevation_rad < -half:
        return "below the aperture"
    return "outside the fan (bearing, range) or hidden"


def judge(
    label: SonarLabel,
    detections: SonarDetections | None,
    fix: RovFix | None,
    thresholds: Thresholds,
) -> Ping:
    """The class of one labelled ping (the module docstring's order)."""
    good = fix is not None and fix.quality == "good"
    error = None
    if good:
        assert fix is not None
        position = fix.position_m if fix.position_m is not None else fix.raw_position_m
        assert position is not None  # a good fix carries one (RovFix's own check)
        error = float(np.linalg.norm(np.subtract(position, label.rov_position_m)))

    def ping(kind: PingClass, detail: str) -> Ping:
        return Ping(label.stamp_ns, label, kind, detail, good, error)

    if not label.visible:
        return ping("out_of_view", _out_of_view(label, thresholds))
    if detections is None:
        return ping("no_detections", "")
    if not _matched(detections, label, thresholds):
        confident = sum(d.confidence >= thresholds.min_confidence for d in detections.detections)
        detail = "candidates elsewhere" if confident else "no candidate"
        if abs(label.elevation_rad) > thresholds.vertical_aperture_rad / 2.0:
            detail += ", centre in the skirt"
        return ping("missed", detail)
    if fix is None:
        return ping("no_fix", "")
    if not good:
        if fix.no_fix_reason:
            return ping("refused", fix.no_fix_reason)
        return ping("refused", f"{fix.quality}, track {fix.track_state}")
    assert error is not None
    return ping("good", "off the ROV" if error > thresholds.off_m else "on the ROV")


def load(path: Path, *, thresholds: Thresholds = Thresholds()) -> Losses:
    """Read a recording and judge every labelled ping."""
    messages = list(read(path))
    keys = {m.key for m in messages}
    out = Losses(
        label_key=_one_key(keys, Subject.SIM_LABEL, "label", path),
        detections_key=_one_key(keys, Subject.SONAR_DETECTIONS, "detections", path),
        fix_key=_one_key(keys, Subject.ROV_FIX, "fix", path),
    )
    label_codec, det_codec, fix_codec = Codec(SonarLabel), Codec(SonarDetections), Codec(RovFix)
    labels: dict[int, SonarLabel] = {}
    detections: dict[int, SonarDetections] = {}
    fixes: dict[int, RovFix] = {}
    for m in messages:
        try:
            if m.key == out.label_key:
                label = label_codec.decode(m.data, encoding=m.encoding, key_expr=m.key)
                labels[label.stamp_ns] = label
            elif m.key == out.detections_key:
                found = det_codec.decode(m.data, encoding=m.encoding, key_expr=m.key)
                detections[found.stamp_ns] = found
            elif m.key == out.fix_key:
                fix = fix_codec.decode(m.data, encoding=m.encoding, key_expr=m.key)
                fixes[fix.stamp_ns] = fix
        except PayloadError:
            out.undecodable += 1
    if not labels:
        raise CapsdError(f"{path}: {out.label_key} holds no label that decodes")
    for stamp in sorted(labels):
        out.pings.append(judge(labels[stamp], detections.get(stamp), fixes.get(stamp), thresholds))
    return out


def since(losses: Losses, start_s: float) -> Losses:
    """The pings from `start_s` seconds after the first labelled one."""
    if not losses.pings:
        return losses
    first = losses.pings[0].stamp_ns
    kept = [p for p in losses.pings if p.stamp_ns - first >= start_s * 1e9]
    return Losses(kept, losses.undecodable, losses.label_key, losses.detections_key, losses.fix_key)


def summary(losses: Losses) -> dict[str, Any]:
    """Counts and shares per class and sub-class (what `capsd losses --json` writes)."""
    n = len(losses.pings)
    by_class: dict[str, Any] = {}
    counts = losses.counts()
    for kind in CLASSES:
        details = {d: c for (k, d), c in sorted(counts.items()) if k == kind}
        total = sum(details.values())
        by_class[kind] = {
            "pings": total,
            "share": round(total / n, 4) if n else None,
            "details": {d or "-": c for d, c in details.items()},
        }
    errors = [p.fix_error_m for p in losses.pings if p.fix_error_m is not None]
    return {
        "pings": n,
        "classes": by_class,
        "good_fixes": len(errors),
        "good_without_rov": losses.good_without_rov(),
        "good_fix_error_median_m": round(float(np.median(errors)), 4) if errors else None,
        "undecodable": losses.undecodable,
        "keys": {
            "label": losses.label_key,
            "detections": losses.detections_key,
            "fix": losses.fix_key,
        },
    }


def table(losses: Losses) -> str:
    """The summary as aligned text lines: class, sub-class, pings, share."""
    n = len(losses.pings)
    if not n:
        return "no labelled ping in the window"
    lines = [f"{'class':<15} {'detail':<45} {'pings':>6} {'share':>7}"]
    counts = losses.counts()
    for kind in CLASSES:
        total = sum(c for (k, _), c in counts.items() if k == kind)
        lines.append(f"{kind:<15} {'':<45} {total:>6} {100 * total / n:>6.1f}%")
        for (k, detail), c in sorted(counts.items(), key=lambda kv: -kv[1]):
            if k == kind and detail:
                lines.append(f"{'':<15} {detail[:45]:<45} {c:>6} {100 * c / n:>6.1f}%")
    lines.append(f"{'all':<15} {'':<45} {n:>6}")
    lines.append(f"good fixes on pings without the ROV found: {losses.good_without_rov()}")
    return "\n".join(lines)


_COLOURS: dict[PingClass, str] = {
    "out_of_view": "tab:grey",
    "no_detections": "black",
    "missed": "tab:red",
    "no_fix": "tab:purple",
    "refused": "tab:orange",
    "good": "tab:green",
}


def plot(losses: Losses, png: Path, *, thresholds: Thresholds = Thresholds()) -> None:
    """The ROV's elevation and range in the sonar over time, each ping coloured by its class."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not losses.pings:
        raise CapsdError("no labelled ping to plot")
    first = losses.pings[0].stamp_ns
    fig, (ax_el, ax_r) = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    half = math.degrees(thresholds.vertical_aperture_rad / 2.0)
    for kind in CLASSES:
        chosen = [p for p in losses.pings if p.kind == kind]
        if not chosen:
            continue
        t = [(p.stamp_ns - first) / 1e9 for p in chosen]
        ax_el.scatter(t, [math.degrees(p.label.elevation_rad) for p in chosen], s=3,
                      c=_COLOURS[kind], label=f"{kind} ({len(chosen)})")  # fmt: skip
        ax_r.scatter(t, [p.label.range_m for p in chosen], s=3, c=_COLOURS[kind])
    for edge in (-half, half):
        ax_el.axhline(edge, color="k", lw=0.8, ls="--")
    ax_el.set_ylabel("ROV elevation in the sonar (deg)")
    ax_el.legend(loc="upper right", markerscale=4, fontsize=8)
    ax_r.set_ylabel("ROV range (m)")
    ax_r.set_xlabel("seconds since the first labelled ping")
    ax_el.set_title("Each ping's class (capsd losses); dashed: the vertical aperture's edges")
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)
    plt.close(fig)


def write_json(losses: Losses, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(summary(losses), indent=2) + "\n")
