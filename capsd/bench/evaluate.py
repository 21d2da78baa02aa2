"""`capsd bench evaluate`: `capsd evaluate` checked on a simulated dive whose answer is known.

One run of the offline pipeline (the services' code) gives the fixes and the accuracy bench's
figures against truth. A motion-capture stand-in then states the ROV's true position in a frame
of its own (rotated, shifted) and on a clock of its own (late), at 100 Hz with mocap-like noise,
occasional marker swaps (outliers) and an occlusion gap. Fixes and reference go into an MCAP
recording as a field team's would; `capsd evaluate`'s code must recover the transform and the
clock offset and reproduce the bench's MED. Printed and written (Markdown, JSON, the
evaluation's PNGs).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from capsd import topics
from capsd.alignment import Similarity, rotation_angle_deg
from capsd.codec import Codec
from capsd.evaluate import evaluate, load, report
from capsd.geometry import euler_zyx_to_matrix
from capsd.payloads import Payload, ReferencePose, RovFix
from capsd.progress import Progress
from capsd.recording import McapRecorder, Sample
from capsd.simulator.config import OFFLINE_START_NS
from capsd.simulator.config import Config as SimConfig
from capsd.simulator.install_errors import InstallErrorsConfig
from capsd.simulator.sim import Simulation
from capsd.simulator.world import TankName, TrajectoryName

if TYPE_CHECKING:
    from capsd.offline_pipeline import DetectorKind

OURS = "ours (CAP-SD)"
# Issue 23's acceptance.
MAX_ROTATION_DEG = 0.1
MAX_TRANSLATION_MM = 5.0
MAX_OFFSET_MS = 5.0
MAX_MED_DIFFERENCE_MM = 1.0


@dataclass(frozen=True)
class MocapStandIn:
    """How the reference system sees the tank: its frame, its clock, its flaws."""

    yaw_deg: float = 30.0
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    shift_m: tuple[float, float, float] = (2.0, 0.0, 0.0)
    late_ms: float = 150.0  # the reference's stamps run this far ahead of true time
    rate_hz: float = 100.0
    noise_mm: float = 0.5  # per axis, white
    swap_share: float = 0.005  # marker swaps: positions off by 0.1-0.4 m
    gap_s: tuple[float, float] = (0.4, 0.45)  # an occlusion, as shares of the dive

    def tank_to_reference(self) -> Similarity:
        rotation = euler_zyx_to_matrix(
            math.radians(self.yaw_deg), math.radians(self.pitch_deg), math.radians(self.roll_deg)
        )
        return Similarity(rotation, np.array(self.shift_m))


def simulated_dive(
    *,
    tank: TankName,
    trajectory: TrajectoryName,
    seed: int,
    duration_s: float,
    recording: Path,
    mocap: MocapStandIn,
    detector: DetectorKind = "cnn",
) -> dict[str, Any]:
    """Run the pipeline, write fixes and the stand-in's reference to `recording`."""
    from capsd.offline_pipeline import Variant, run

    config = SimConfig(
        tank=tank,
        trajectory=trajectory,
        seed=seed,
        install_errors=InstallErrorsConfig(mode="off"),  # the evaluation's path, not the mounts
    )
    fixes: list[RovFix] = []

    def sink(payload: Payload) -> None:
        if isinstance(payload, RovFix):
            fixes.append(payload)

    bar = Progress(duration_s, label="simulated dive", unit=" sim s")
    variants = [Variant(OURS, detector=detector)]
    results = run(config, duration_s=duration_s, variants=variants, progress=bar, sink=sink)
    bar.close()
    # The same world the pipeline ran in (the same horizon: the trajectory depends on it).
    sim = Simulation(config, horizon_s=duration_s + 5.0)
    rng = np.random.default_rng(seed + 23)
    t = np.arange(0.0, duration_s, 1.0 / mocap.rate_hz)
    t = t[(t < mocap.gap_s[0] * duration_s) | (t > mocap.gap_s[1] * duration_s)]
    truth = np.array([sim.rov_state(float(s)).position_m for s in t])
    seen = mocap.tank_to_reference().apply(truth)
    seen += rng.normal(0.0, mocap.noise_mm / 1000, seen.shape)
    swaps = rng.random(len(t)) < mocap.swap_share
    direction = rng.normal(size=(int(swaps.sum()), 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    seen[swaps] += direction * rng.uniform(0.1, 0.4, (len(direction), 1))
    # The simulator's ASV clock (the fixes' stamps) may itself be off true time.
    asv_clock_s = config.clocks.asv.offset_s
    fix_codec, ref_codec = Codec(RovFix), Codec(ReferencePose)
    fix_key = topics.ROV_FIX.key("tank", "topside")
    ref_key = topics.REFERENCE_POSE.key("tank", "rov")
    with McapRecorder(recording) as recorder:
        for fix in fixes:
            recorder.write(Sample(fix_key, fix_codec.encoding, fix_codec.encode(fix), fix.stamp_ns))
        for k, (s, p) in enumerate(zip(t, seen, strict=True)):
            stamp = OFFLINE_START_NS + round((s + mocap.late_ms / 1000) * 1e9)
            pose = ReferencePose(stamp_ns=stamp, seq=k, position_m=(float(p[0]), float(p[1]),
                                 float(p[2])), frame_id="mocap")  # fmt: skip
            recorder.write(Sample(ref_key, ref_codec.encoding, ref_codec.encode(pose), stamp))
    return {
        "bench": results[OURS].summary(),
        "expected_offset_ms": mocap.late_ms - asv_clock_s * 1000,
        "swaps": int(swaps.sum()),
        "reference_poses": len(t),
    }


def bench(
    *,
    tank: TankName,
    trajectory: TrajectoryName,
    seed: int,
    duration_s: float,
    out_dir: Path,
    mocap: MocapStandIn | None = None,
    detector: DetectorKind = "cnn",
) -> dict[str, Any]:
    """The whole check: dive, record, evaluate, compare; writes the report into `out_dir`.

    `detector` "truth" (the ROV's true centre) checks the evaluation alone, without the
    detector's misses and outliers in the fixes (and in a third of the time).
    """
    mocap = mocap or MocapStandIn()
    out_dir.mkdir(parents=True, exist_ok=True)
    recording = out_dir / "dive.mcap"
    dive = simulated_dive(tank=tank, trajectory=trajectory, seed=seed, duration_s=duration_s,
                          recording=recording, mocap=mocap, detector=detector)  # fmt: skip
    evaluation = evaluate(load([recording], reference=None, fixes=None))
    name = f"{tank}/{trajectory}"
    figures = report(evaluation, out_dir, title=f"simulated dive {name}")
    wanted = mocap.tank_to_reference().inverse()
    got = evaluation.alignment.transform
    # The transform's error where it matters: at the points the ROV visited.
    points = evaluation.inputs.reference_m
    moved = np.linalg.norm(got.apply(points) - wanted.apply(points), axis=1)
    bench_med = dive["bench"]["med_mm"]
    eval_med = figures["accuracy"]["med_mm"]
    checks = {
        "rotation_error_deg": round(rotation_angle_deg(got.rotation @ wanted.rotation.T), 4),
        "translation_error_mm": round(float(np.max(moved)) * 1000, 2),
        "offset_error_ms": round(
            evaluation.alignment.offset_ns / 1e6 - dive["expected_offset_ms"], 2
        ),
        "bench_med_mm": bench_med,
        "evaluated_med_mm": eval_med,
        "med_difference_mm": round(eval_med - bench_med, 2),
    }
    verdicts = {
        "rotation": checks["rotation_error_deg"] <= MAX_ROTATION_DEG,
        "translation": checks["translation_error_mm"] <= MAX_TRANSLATION_MM,
        "offset": abs(checks["offset_error_ms"]) <= MAX_OFFSET_MS,
        "med": abs(checks["med_difference_mm"]) <= MAX_MED_DIFFERENCE_MM,
    }
    result = {
        "run": name,
        "seed": seed,
        "duration_s": duration_s,
        "detector": detector,
        "mocap": {
            "yaw_deg": mocap.yaw_deg,
            "shift_m": list(mocap.shift_m),
            "late_ms": mocap.late_ms,
            "noise_mm": mocap.noise_mm,
            "swaps": dive["swaps"],
            "reference_poses": dive["reference_poses"],
        },
        "checks": checks,
        "verdicts": verdicts,
        "bench": dive["bench"],
        "evaluation": figures,
    }
    lines = [
        f"# capsd evaluate on a simulated dive ({name}, {duration_s:g} s, seed {seed}, "
        f"detector {detector})",
        "",
        f"Reference stand-in: the tank frame rotated {mocap.yaw_deg:g} deg and shifted "
        f"{list(mocap.shift_m)} m, stamps {mocap.late_ms:g} ms late, {mocap.rate_hz:g} Hz, "
        f"{mocap.noise_mm:g} mm noise, {dive['swaps']} marker swaps, one occlusion gap.",
        "",
        "| check | found | limit | verdict |",
        "|---|---:|---:|:-:|",
        f"| rotation error deg | {checks['rotation_error_deg']} | {MAX_ROTATION_DEG} "
        f"| {_verdict(verdicts['rotation'])} |",
        f"| translation error mm (worst over the dive's points) | "
        f"{checks['translation_error_mm']} | {MAX_TRANSLATION_MM} "
        f"| {_verdict(verdicts['translation'])} |",
        f"| clock offset error ms | {checks['offset_error_ms']} | {MAX_OFFSET_MS} "
        f"| {_verdict(verdicts['offset'])} |",
        f"| MED: evaluated {eval_med} mm, bench {bench_med} mm | "
        f"{checks['med_difference_mm']} | {MAX_MED_DIFFERENCE_MM} | {_verdict(verdicts['med'])} |",
        "",
        f"All met: {'yes' if all(verdicts.values()) else 'no'}",
        "",
    ]
    markdown = "\n".join(lines)
    (out_dir / "bench_evaluate.md").write_text(markdown)
    (out_dir / "bench_evaluate.json").write_text(json.dumps(result, indent=1, sort_keys=True))
    print(markdown)
    print(f"written: {out_dir}/bench_evaluate.md, .json, evaluation.md and its PNGs")
    return result


def _verdict(ok: bool) -> str:
    return "met" if ok else "NOT met"
