"""`capsd evaluate`: fixes in a recording scored against a reference system (motion capture).

The recording(s) hold the locator's fixes (`locator/fix`) and a reference track: ReferencePose
payloads (`ref/pose`, from `capsd import-bag` with `as: reference` or the ROS 2 input's
`reference_topic`), or, in a simulated recording, the simulator's truth. The reference frame and
clock are aligned to the fixes' (capsd.alignment: robust Umeyama, clock offset by search) unless
given; then each fix is scored against the reference at its stamp, as the accuracy bench scores
it against truth (capsd.accuracy): MED, RMSE per axis, p95, availability, the plots. A fix
counts only where the reference has a value at its stamp (no gap longer than `max_gap_s`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from capsd.accuracy import HEADER, Accuracy, fix_estimate, row, scored
from capsd.alignment import Alignment, Track, align
from capsd.codec import Codec
from capsd.errors import CapsdError, PayloadError
from capsd.keys import Subject, subject_of
from capsd.payloads import GroundTruth, ReferencePose, RovFix
from capsd.recording import read


@dataclass(frozen=True)
class Inputs:
    """What a recording gives: fixes (in stamp order) and a reference track."""

    fixes: list[RovFix]
    fixes_key: str
    reference_stamps_ns: np.ndarray
    reference_m: np.ndarray
    reference_key: str
    rejected: int  # payloads on the chosen keys that did not decode


def _pick(keys: set[str], wanted: str | None, subject: Subject, what: str) -> str:
    """The one key `wanted` names (a whole key, or its end), else the one key of `subject`."""
    if wanted is not None:
        matches = sorted(k for k in keys if k == wanted or k.endswith("/" + wanted.strip("/")))
    else:
        matches = sorted(k for k in keys if subject_of(k) == subject.value)
    if len(matches) == 1:
        return matches[0]
    if not matches:
        raise CapsdError(
            f"no {what} key{f' matching {wanted!r}' if wanted else ''} in the recording "
            f"(keys: {sorted(keys)})"
        )
    raise CapsdError(f"several {what} keys match, name one: {matches}")


def load(recordings: list[Path], *, reference: str | None, fixes: str | None) -> Inputs:
    """Read the fixes and the reference track (by key) from one or more recordings."""
    messages = [m for path in recordings for m in read(path)]
    keys = {m.key for m in messages}
    fixes_key = _pick(keys, fixes, Subject.ROV_FIX, "fix")
    candidates = {k for k in keys if subject_of(k) in (Subject.REFERENCE_POSE, Subject.SIM_TRUTH)}
    reference_key = _pick(candidates if reference is None else keys, reference,
                          Subject.REFERENCE_POSE, "reference")  # fmt: skip
    fix_codec, ref_codec, truth_codec = Codec(RovFix), Codec(ReferencePose), Codec(GroundTruth)
    got: list[RovFix] = []
    stamps: list[int] = []
    positions: list[tuple[float, float, float]] = []
    rejected = 0
    for m in messages:
        try:
            if m.key == fixes_key:
                got.append(fix_codec.decode(m.data, encoding=m.encoding, key_expr=m.key))
            elif m.key == reference_key and subject_of(m.key) == Subject.SIM_TRUTH.value:
                truth = truth_codec.decode(m.data, encoding=m.encoding, key_expr=m.key)
                stamps.append(truth.stamp_ns)
                positions.append(truth.rov_position_m)
            elif m.key == reference_key:
                pose = ref_codec.decode(m.data, encoding=m.encoding, key_expr=m.key)
                stamps.append(pose.stamp_ns)
                positions.append(pose.position_m)
        except PayloadError:
            rejected += 1
    if len(stamps) < 2:
        raise CapsdError(f"{reference_key}: {len(stamps)} reference poses, a track needs 2")
    if not any(f.quality == "good" for f in got):
        raise CapsdError(f"{fixes_key}: no good fix to evaluate")
    got.sort(key=lambda f: f.stamp_ns)
    return Inputs(
        got, fixes_key, np.array(stamps, dtype=np.int64), np.array(positions), reference_key,
        rejected,
    )  # fmt: skip


@dataclass(frozen=True)
class Evaluation:
    accuracy: Accuracy
    alignment: Alignment
    inputs: Inputs
    outside: int  # fixes with no reference value at their stamp (not scored)
    reference_spikes: int  # reference samples dropped as jumps off the track


def evaluate(
    inputs: Inputs,
    *,
    with_scale: bool = False,
    max_offset_s: float = 1.0,
    offset_s: float | None = None,
    max_gap_s: float = 0.1,
) -> Evaluation:
    """Align the reference to the good fixes, then score every fix the reference covers."""
    track = Track.of(inputs.reference_stamps_ns, inputs.reference_m, max_gap_s=max_gap_s)
    good = [f for f in inputs.fixes if f.quality == "good"]
    estimates = np.array([fix_estimate(f)[0] for f in good])
    stamps = np.array([f.stamp_ns for f in good], dtype=np.int64)
    try:
        alignment = align(
            stamps, estimates, track, max_offset_s=max_offset_s, with_scale=with_scale,
            offset_s=offset_s,
        )  # fmt: skip
    except ValueError as exc:
        raise CapsdError(f"no alignment: {exc}") from None
    all_stamps = np.array([f.stamp_ns for f in inputs.fixes], dtype=np.int64)
    reference, valid = track.at(all_stamps + alignment.offset_ns)
    in_tank = alignment.transform.apply(reference)
    accuracy = Accuracy()
    for fix, truth, ok in zip(inputs.fixes, in_tank, valid, strict=True):
        if ok:
            accuracy.add(scored(fix, (float(truth[0]), float(truth[1]), float(truth[2]))))
    return Evaluation(accuracy, alignment, inputs, int(np.count_nonzero(~valid)), track.spikes)


def report(evaluation: Evaluation, out_dir: Path, *, title: str) -> dict[str, Any]:
    """Write evaluation.md, evaluation.json and the accuracy bench's three PNGs; return figures."""
    from capsd import plots

    out_dir.mkdir(parents=True, exist_ok=True)
    summary = evaluation.accuracy.summary()
    alignment = evaluation.alignment.summary()
    inputs = evaluation.inputs
    figures: dict[str, Any] = {
        "fixes_key": inputs.fixes_key,
        "reference_key": inputs.reference_key,
        "fixes": len(inputs.fixes),
        "reference_poses": len(inputs.reference_stamps_ns),
        "not_covered_by_reference": evaluation.outside,
        "reference_spikes_dropped": evaluation.reference_spikes,
        "undecodable": inputs.rejected,
        "alignment": alignment,
        "accuracy": summary,
    }
    shown = {"CAP-SD fixes": evaluation.accuracy}
    plots.trajectory_3d(shown, out_dir / "trajectory_3d.png", title=f"{title}: trajectory",
                        truth_label="reference")  # fmt: skip
    plots.per_axis(shown, out_dir / "axes.png", title=f"{title}: position over time",
                   truth_label="reference")  # fmt: skip
    plots.error_histograms(shown, out_dir / "errors.png", title=f"{title}: errors")
    lines = [
        f"# Evaluation against a reference: {title}",
        "",
        f"Fixes `{inputs.fixes_key}` ({len(inputs.fixes)}), reference `{inputs.reference_key}` "
        f"({len(inputs.reference_stamps_ns)} poses, {evaluation.reference_spikes} dropped as "
        f"jumps off the track); {evaluation.outside} fixes fall where the reference has no "
        "value and are not scored.",
        "",
        "## Alignment (reference frame and clock -> tank frame and the fixes' clock)",
        "",
        f"- rotation: yaw {alignment['yaw_deg']} deg, pitch {alignment['pitch_deg']} deg, "
        f"roll {alignment['roll_deg']} deg ({alignment['rotation_angle_deg']} deg in all)",
        f"- translation: ({alignment['x_m']}, {alignment['y_m']}, {alignment['z_m']}) m, "
        f"scale {alignment['scale']}",
        f"- clock: the reference's stamps run {alignment['clock_offset_ms']} ms ahead of the "
        "fixes'",
        f"- residual: RMS {alignment['residual_rms_mm']} mm over {alignment['inliers']} of "
        f"{alignment['pairs']} pairs (robust sigma {alignment['residual_sigma_mm']} mm; the "
        "rest were outliers)",
        f"- determined to about {alignment['rotation_sigma_deg']} deg (worst axis) and "
        f"{alignment['offset_sigma_ms']} ms: the matched track spans {alignment['spread_m']} m "
        "(std along its principal axes)",
        "",
        *(f"**NOT TRUSTED: {problem}**" for problem in alignment["problems"]),
        "",
        "The fitted transform absorbs any constant bias the fixes share: these figures are the "
        "fixes' scatter and shape error, not an absolute offset.",
        "",
        "## Accuracy (what the autopilot would be sent: good fixes)",
        "",
        HEADER,
        row("CAP-SD fixes", summary),
        "",
        "PNGs: trajectory_3d.png, axes.png, errors.png",
        "",
    ]
    (out_dir / "evaluation.md").write_text("\n".join(lines))
    (out_dir / "evaluation.json").write_text(json.dumps(figures, indent=1, sort_keys=True) + "\n")
    return figures


__all__ = ["Evaluation", "Inputs", "evaluate", "load", "report"]
