"""`capsd docs figures`: the README's tables written from the benches' own JSON, never by hand.

A table in a Markdown file is a block between two markers naming its renderer and its source:

    <!-- figures: accuracy_table docs/figures/accuracy.json -->
    (generated: do not edit)
    <!-- /figures -->

`render` rewrites every block from its JSON (a bench's output file, copied into
docs/figures/ when the README is to quote it) and adds the line naming the command that
produced the numbers (indented as the opening marker is, so a table can sit in a list item);
`--check` says whether the file is up to date. A renderer refuses a JSON
that is not its bench's (a clear error naming the file and the missing field).
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from capsd.errors import CapsdError

_BLOCK = re.compile(
    r"^(?P<indent>[ ]*)(?P<open><!-- figures: (?P<name>\w+) (?P<source>\S+) -->\n)"
    r"(?P<body>.*?)(?P<close>[ ]*<!-- /figures -->)",
    re.DOTALL | re.MULTILINE,
)
BASELINE = "paper (baseline)"
CALIBRATED = "paper, box range calibrated"
OURS = "ours (CAP-SD)"
OURS_SELF_CALIBRATED = "ours, mount self-calibrated"
PERFECT_DETECTOR = "ours, a perfect detector"
# The accuracy bench's variants with the CNN's own candidate on the ROV moved to the truth
# (capsd.offline_pipeline.with_exact): its header, then the variant's name.
_EXACT = (
    ("centre exact", "ours + the detector's centre exact"),
    ("range exact", "ours + the detector's range exact"),
    ("bearing exact", "ours + the detector's bearing exact"),
)
HELD_OUT = ("pond/",)


def _run_name(name: str) -> str:
    label = name.replace("/", " ")
    return f"{label} (held out)" if name.startswith(HELD_OUT) else label


def _ci(values: list[float], digits: int = 1) -> str:
    return f"[{values[0]:.{digits}f}, {values[1]:.{digits}f}]"


_TANKS = ("nfp", "mockup", "pond")
_TRAJECTORIES = ("square", "bouncing", "lawnmower", "random", "two_floor")


def _in_order(runs: dict[str, Any]) -> list[tuple[str, Any]]:
    """Runs as the bench lists them (its JSON is written with sorted keys)."""

    def rank(name: str) -> tuple[int, int, str]:
        tank, _, trajectory = name.partition("/")
        return (
            _TANKS.index(tank) if tank in _TANKS else len(_TANKS),
            _TRAJECTORIES.index(trajectory) if trajectory in _TRAJECTORIES else 99,
            name,
        )

    return sorted(runs.items(), key=lambda item: rank(item[0]))


def accuracy_table(figures: dict[str, Any]) -> list[str]:
    """The paper's method against ours per run: MED, ratio, our availability."""
    lines = [
        "| run | paper's method | ours | ratio | ours, availability |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, methods in _in_order(figures["runs"]):
        paper, ours = methods[BASELINE], methods[OURS]
        if "med_mm" not in paper or "med_mm" not in ours:
            lines.append(f"| {_run_name(name)} | - | - | - | - |")
            continue
        lines.append(
            f"| {_run_name(name)} | {paper['med_mm']:.1f} mm | {ours['med_mm']:.1f} mm "
            f"| {ours['med_mm'] / paper['med_mm']:.2f} | {100 * ours['availability']:.1f} % |"
        )
    return lines


def accuracy_common(figures: dict[str, Any]) -> list[str]:
    """Ours against the calibrated baseline on common pings, with bootstrap intervals."""
    lines = [
        "| run | common pings | ours | paper, calibrated | ours / calibrated "
        "| a perfect detector / calibrated |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    perfect = figures.get("perfect_detector", {})
    for name, against in _in_order(figures["common"]):
        c = against[CALIBRATED]
        if "ratio" not in c:
            lines.append(f"| {_run_name(name)} | 0 | - | - | - | {_ratio(perfect.get(name))} |")
            continue
        lines.append(
            f"| {_run_name(name)} | {c['common_pings']} "
            f"| {c['ours_med_mm']:.1f} {_ci(c['ours_med_ci_mm'])} "
            f"| {c['other_med_mm']:.1f} {_ci(c['other_med_ci_mm'])} "
            f"| {c['ratio']:.2f} {_ci(c['ratio_ci'], 2)} | {_ratio(perfect.get(name))} |"
        )
    return lines


def detector_budget(figures: dict[str, Any]) -> list[str]:
    """What the detector's errors cost ours: its own pings with its range or bearing exact."""
    lines = [
        "| run | ours | "
        + " | ".join(f"ours, the detector's {header}" for header, _ in _EXACT)
        + " | a perfect detector |",
        "|---|---:|" + "---:|" * (len(_EXACT) + 1),
    ]

    def cell(summary: dict[str, Any]) -> str:
        if "med_mm" not in summary:
            return "-"
        return f"{summary['med_mm']:.1f} mm, {100 * summary['availability']:.1f} %"

    for name, methods in _in_order(figures["runs"]):
        exact = [methods.get(variant, {}) for _, variant in _EXACT]
        lines.append(
            f"| {_run_name(name)} | {cell(methods[OURS])} | "
            + " | ".join(cell(s) for s in exact)
            + f" | {cell(methods[PERFECT_DETECTOR])} |"
        )
    return lines


def _ratio(comparison: dict[str, Any] | None) -> str:
    """A comparison's ratio with its interval, or '-' (none, or figures from before it)."""
    if not comparison or "ratio" not in comparison:
        return "-"
    return f"{comparison['ratio']:.2f} {_ci(comparison['ratio_ci'], 2)}"


def demo_summary(figures: dict[str, Any]) -> list[str]:
    """One live demo run: its fixes against the truth, the autopilot's side, exit codes."""
    a = figures["accuracy"]
    codes = figures["exit_codes"]
    clean = all(code == 0 for code in codes.values())
    # Older reports had no field: their installation was perfect.
    installation = "realistic, uncalibrated" if figures.get("install_errors") else "off"
    return [
        f"`capsd demo --duration {figures['duration_s']:g}` ({figures['tank']}, "
        f"{figures['trajectory']}, seed {figures['seed']}, installation errors "
        f"{installation}): {a['pings']} pings, "
        f"{100 * a['availability']:.1f} % with a good fix, mean Euclidean error {a['med_mm']} mm "
        f"against the truth (p95 {a['p95_mm']} mm); {figures['autopilot'].splitlines()[0]}; "
        + ("every process exited 0." if clean else f"exit codes {codes}.")
    ]


_LATENCY_SERVICES = ("asv_pose", "sonar_detect", "locator", "mav_bridge")
# The pipeline's order (the bench's JSON has its stages in sorted order): by first word.
_STAGE_ORDER = ("sonar", "frame", "detection", "of", "detections", "fix", "fix transport",
                "bridge", "END")  # fmt: skip


def _stage_rank(stage: str) -> int:
    words = stage.replace(":", "").split()
    for key in (" ".join(words[:2]), words[0]):
        if key in _STAGE_ORDER:
            return _STAGE_ORDER.index(key)
    return len(_STAGE_ORDER)


def latency_table(figures: dict[str, Any]) -> list[str]:
    """Per-stage medians (p99) in ms at each sonar rate, CPU, memory, the Zenoh floor."""
    rates = sorted(figures["rates"], key=lambda r: r["rate_hz"])
    stages = sorted(rates[0]["stages"], key=_stage_rank)

    def cell(s: dict[str, Any]) -> str:
        if s.get("median_ms") is None:
            return "-"
        return f"{s['median_ms']:.1f} ({s['p99_ms']:.1f})"

    lines = [
        "| stage | " + " | ".join(f"{r['rate_hz']:g} Hz" for r in rates) + " |",
        "|---|" + "---:|" * len(rates),
    ]
    for stage in stages:
        label = stage.strip()
        lines.append(f"| {label} | " + " | ".join(cell(r["stages"][stage]) for r in rates) + " |")

    def row(label: str, cells: list[str]) -> str:
        return f"| {label} | " + " | ".join(cells) + " |"

    cpu = [sum(r["cpu_cores"].get(n, 0.0) for n in _LATENCY_SERVICES) for r in rates]
    lines.append(row("CPU of the four services (cores)", [f"{c:.2f}" for c in cpu]))
    for service in ("mav_bridge", "sonar_detect"):
        rss = [f"{r['rss_mb'].get(service, 0.0):.0f}" for r in rates]
        lines.append(row(f"{service} resident MB", rss))
    sent = [f"{r['frames']['vpe_sent']} / {r['frames']['published']}" for r in rates]
    lines.append(row("VPE sent / frames published", sent))
    floor = ", ".join(
        f"{name} ({f['bytes']} B) {f['median_ms']:.2f} ms" for name, f in figures["floor"].items()
    )
    problems = [p for r in rates for p in r["problems"]]
    lines += ["", f"Zenoh floor, bare put to callback through the router: {floor}."]
    if problems:
        lines.append("Problems: " + "; ".join(problems))
    return lines


def box_range_bias(figures: dict[str, Any]) -> list[str]:
    """The paper's box-centre range shortfall the calibrated baseline adds back."""
    bias = figures["box_range_bias_mm"]
    return [
        f"The paper's box centre falls {bias['mean']} mm short in range (std {bias['std']} mm, "
        f"measured on {bias['training_pings']} pings of training runs that share no seed with "
        "the bench's, `capsd/bench/baseline.py`); the calibrated baseline adds that constant."
    ]


def evaluate_checks(figures: dict[str, Any]) -> list[str]:
    """`capsd evaluate` against a known answer: what it recovered."""
    c, mocap = figures["checks"], figures["mocap"]
    return [
        f"Simulated dive {figures['run']}, {figures['duration_s']:g} s, seed {figures['seed']}; "
        f"reference rotated {mocap['yaw_deg']:g} deg, shifted {mocap['shift_m']} m, "
        f"{mocap['late_ms']:g} ms late, {mocap['swaps']} marker swaps.",
        "",
        "| recovered | error | issue 23's limit |",
        "|---|---:|---:|",
        f"| rotation | {c['rotation_error_deg']} deg | 0.1 deg |",
        f"| translation (worst over the dive) | {c['translation_error_mm']} mm | 5 mm |",
        f"| clock offset | {c['offset_error_ms']} ms | 5 ms |",
        f"| MED: evaluated {c['evaluated_med_mm']} mm, bench {c['bench_med_mm']} mm "
        f"| {c['med_difference_mm']} mm | 1 mm |",
    ]


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.1f} %"


def _err(g: dict[str, Any], key: str, unit: str, digits: int) -> str:
    median, p90 = g.get(f"{key}_median"), g.get(f"{key}_p90")
    if median is None or p90 is None:
        return "-"
    return f"{median:.{digits}f} {unit} ({p90:.{digits}f})"


_BANDS = ("0.5-1.5 m", "1.5-4 m", "4-8 m", "8-14 m", "14-20 m")
# The ROV's place in the vertical aperture (capsd.bench.detect.APERTURE_PLACES), under 4 m.
_PLACES = ("lower third", "middle third", "upper third", "beyond an edge")
# The bench's row that is no detector (capsd.bench.detect.BRIGHTEST).
_BRIGHTEST = "(no detector) the ROV brightest in its band"
# capsd.bench.detect.ALARM_KINDS: what the ping held when a false alarm came.
_ALARM_KINDS = ("rov_found", "rov_missed", "rov_out_of_view")


def _detect_row(figures: dict[str, Any], label: str, name: str) -> str:
    """One detector's row of the detect tables: all its pings in one group."""
    g = figures["groups"][name]
    return (
        f"| {label} | {_pct(g['detection_rate'])} | {g['false_alarms_per_frame']:.3f} "
        f"| {_err(g, 'range_err_cm', 'cm', 2)} | {_err(g, 'azimuth_err_deg', 'deg', 2)} |"
    )


def _cnn_rows(figures: dict[str, Any]) -> list[str]:
    """The configured CNN's rows per look (all pings, range bands, clutter)."""
    groups = figures["groups"]
    lines = [
        "| look / pings | detected | false alarms / frame | range err median (p90) "
        "| bearing err median (p90) |",
        "|---|---:|---:|---:|---:|",
    ]

    def split(label: str, names: list[str]) -> str:
        found = [groups.get(n, {}) for n in names]
        rates = " / ".join(_pct(g.get("detection_rate")).removesuffix(" %") for g in found)
        alarms = " / ".join(f"{g.get('false_alarms_per_frame', 0):.3f}" for g in found)
        return f"| {label} | {rates} % | {alarms} | | |"

    def by_place(names: list[str]) -> str:
        found = [groups[n] for n in names]
        rates = " / ".join(_pct(g.get("detection_rate")).removesuffix(" %") for g in found)
        biases = " / ".join(
            "-" if g.get("range_bias_cm_median") is None else f"{g['range_bias_cm_median']:+.1f}"
            for g in found
        )
        return (
            f"| ... under 4 m: the aperture's {' / '.join(_PLACES)} | {rates} % | "
            f"| signed {biases} cm | |"
        )

    for look, label in (("off", "fixed look"), ("heldout", "held-out look")):
        lines.append(_detect_row(figures, f"{label}, all", f"cnn / {look} / all"))
        spread = figures.get("over_runs", {}).get(f"cnn / {look}")  # since session 65
        if spread is not None:
            # Runs without the ROV in view have no detection rate.
            by_run = [r for r in spread["detection_rate_by_run"] if r is not None]
            low, high = (min(by_run), max(by_run)) if by_run else (None, None)
            found, alarms = spread["detection_rate_ci95"], spread["false_alarms_per_frame_ci95"]
            lines.append(
                f"| ... run by run ({spread['runs']} runs): lowest to highest; 95 % interval, "
                f"runs resampled | {_pct(low)} to {_pct(high)}; "
                f"{_pct(found[0])} to {_pct(found[1])} | {alarms[0]:.3f} to {alarms[1]:.3f} "
                "| | |"
            )
        if look == "heldout":
            lines.append(split("... clear / overlapping clutter",
                               [f"cnn / {look} / clear", f"cnn / {look} / overlap"]))  # fmt: skip
        lines.append(split("... " + " / ".join(b.removesuffix(" m") for b in _BANDS) + " m",
                           [f"cnn / {look} / {b}" for b in _BANDS]))  # fmt: skip
        brightest = [f"{_BRIGHTEST} / {look} / {b}" for b in _BANDS]
        if all(name in groups for name in brightest):
            rates = " / ".join(
                _pct(groups[n].get("detection_rate")).removesuffix(" %") for n in brightest
            )
            lines.append(
                "| ... no detector: the ROV's echo the brightest of its range band, same bands "
                f"| {rates} % | | | |"
            )
        places = [f"cnn / {look} / under 4 m, {p}" for p in _PLACES]
        if all(name in groups for name in places):
            lines.append(by_place(places))
        every = groups[f"cnn / {look} / all"]
        if "false_alarms_per_frame_on_rov_bearing" in every:  # since session 63
            kinds = " / ".join(
                f"{every[f'false_alarms_per_frame_{kind}']:.3f}" for kind in _ALARM_KINDS
            )
            lines.append(
                "| ... false alarms: the ROV found beside them / the ROV missed / the ROV out "
                f"of view; on the ROV's bearing | | {kinds}; "
                f"{every['false_alarms_per_frame_on_rov_bearing']:.3f} | | |"
            )
    return lines


def detect_table(figures: dict[str, Any]) -> list[str]:
    """The configured CNN per look (all pings, range bands, clutter), and the fallback."""
    fallback = "classical (CFAR) fallback, held-out look"
    return [*_cnn_rows(figures), _detect_row(figures, fallback, "classical / heldout / all")]


def detect_gated_table(figures: dict[str, Any]) -> list[str]:
    """The configured CNN through the service's depth-aware search, given the truth."""
    if figures["depth_gate"] != "truth":  # another run of the bench: not this table's
        raise KeyError("depth_gate")
    fallback = [  # with --detector all (since session 67): the classical one through the gate
        _detect_row(figures, f"classical (CFAR) fallback, {label}", f"classical / {look} / all")
        for look, label in (("off", "fixed look"), ("heldout", "held-out look"))
        if f"classical / {look} / all" in figures["groups"]
    ]
    return [*_cnn_rows(figures), *fallback]


def finetune_table(figures: dict[str, Any]) -> list[str]:
    """The fine-tune path: shipped against fine-tuned weights at the dive's site and elsewhere."""
    groups = figures["groups"]
    labels = figures["labels"]
    tank, trajectory, seed = figures["dive"]
    # The site look's knobs beyond the range trained on (since session 68; null: all five).
    knobs = figures.get("outside_knobs")
    look = (
        "a look outside the training variety"
        if knobs is None
        else f"a look with {', '.join(knobs) or 'no knob'} beyond the range trained on, the "
        f"other knobs from their whole range (`--outside-knobs {' '.join(knobs) or 'none'}`)"
    )
    lines = [
        f"First dive: {tank} {trajectory} (seed {seed}), {figures['dive_duration_s']:g} s in "
        f"{look}; {labels['labelled']} of {labels['frames']} "
        f"recorded pings labelled from confident tracked fixes; fine-tuned in "
        f"{figures['finetune_seconds'] / 60:.1f} min (operating point "
        f"{figures['operating_point']['offset']:.2f} against the shipped "
        f"{figures['operating_point']['shipped_offset']:.2f}); held-out runs "
        f"{figures['eval_duration_s']:g} s each.",
        "",
        "| look / weights | detected | false alarms / frame | range err median (p90) "
        "| bearing err median (p90) | clear / overlapping clutter | 4-8 / 8-14 m |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]

    def rates(weights: str, look: str, names: tuple[str, ...]) -> str:
        found = [groups.get(f"{weights} / {look} / {n}", {}).get("detection_rate") for n in names]
        return " / ".join(_pct(r).removesuffix(" %") for r in found) + " %"

    for look, label in (("this site", "the dive's site (its look)"), ("heldout", "held-out look")):
        for weights in ("shipped", "fine-tuned"):
            g = groups[f"{weights} / {look} / all"]
            lines.append(
                f"| {label}, {weights} | {_pct(g['detection_rate'])} "
                f"| {g['false_alarms_per_frame']:.3f} | {_err(g, 'range_err_cm', 'cm', 2)} "
                f"| {_err(g, 'azimuth_err_deg', 'deg', 2)} "
                f"| {rates(weights, look, ('clear', 'overlap'))} "
                f"| {rates(weights, look, ('4-8 m', '8-14 m'))} |"
            )
    return lines


def consistency_table(figures: dict[str, Any]) -> list[str]:
    """NEES of the fixes with no floor, the derived floor and the configured one."""
    lines = [
        f"Derived floor {figures['derived_floor_mm']} mm, configured "
        f"{figures['configured_floor_mm']} mm; {figures['duration_s']:g} s per run.",
        "",
        "| runs | floor mm | fixes | mean NEES | within the 95 % bound |",
        "|---|---:|---:|---:|---:|",
    ]
    for r in figures["rows"]:
        nees = "-" if r["nees_mean"] is None else f"{r['nees_mean']:.2f}"
        lines.append(
            f"| {r['runs']} | {r['floor_mm']} | {r['fixes']} | {nees} | {_pct(r['within_95'])} |"
        )
    return lines


DETERMINED_TERMS = (
    "yaw", "roll", "shift", "depth_offset", "range_offset", "forward", "pitch", "height",
)  # fmt: skip


def _written_position(runs: list[dict[str, Any]]) -> str:
    """The sonar's forward position written: against where the fixes need it and the drawn one.

    (Since session 28; the height's is the bench's own mean, in the sentence before.)
    """
    if not runs or "forward_error_vs_wanted_mm" not in runs[0]:
        return ""

    def mean_abs(key: str) -> str:
        values = [abs(r[key]) for r in runs if r.get(key) is not None]
        return f"{sum(values) / len(values):.1f}" if values else "-"

    determined = sum(1 for r in runs if r.get("forward_determined"))
    return (
        f" The sonar's forward position determined on {determined} of {len(runs)}, written "
        f"mean |error| {mean_abs('forward_error_vs_wanted_mm')} mm against where a fix needs "
        f"the sonar in the ASV's LiDAR-derived frame (the LiDAR's drawn forward error in it, as "
        f"in the sideways figure), "
        f"{mean_abs('forward_error_mm')} mm against the sonar's drawn position alone."
    )


def calibrate_table(figures: dict[str, Any]) -> list[str]:
    """`capsd calibrate` per seed against the corrections the hidden errors call for."""
    lines = [
        f"{figures['tank']}, {len(figures['runs'])} seeds, {figures['duration_s']:g} s each: "
        f"mean |yaw error| {figures['mean_abs_yaw_error_deg']} deg, |roll error| "
        f"{figures['mean_abs_roll_error_deg']} deg, sideways {figures['mean_shift_error_mm']} mm, "
        f"|depth offset error| {figures['mean_abs_depth_offset_error_mm']} mm, "
        f"|range offset error| {figures.get('mean_abs_range_offset_error_mm', '-')} mm, "
        f"|elevation offset error| {figures.get('mean_abs_elevation_offset_error_deg', '-')} deg "
        f"(against the drawn pitch alone "
        f"{figures.get('mean_abs_pitch_error_vs_drawn_deg', '-')} deg)"
        + (
            f"; the sonar's height determined on {figures['height_determined_runs']} of "
            f"{len(figures['runs'])}"
            + (
                f" ({figures['height_by_profiles_alone_runs']} by the profiles alone, without "
                "the tape's 1-sigma)"
                if "height_by_profiles_alone_runs" in figures
                else ""
            )
            + ", mean |height error| "
            f"{figures.get('mean_abs_height_error_mm') or '-'} mm against what the elevations "
            f"need, {figures.get('mean_abs_height_error_vs_drawn_mm') or '-'} mm against the "
            "drawn height alone."
            if "height_determined_runs" in figures
            else "."
        )
        + _written_position(figures["runs"]),
        "",
        "| seed | yaw wanted / fitted (sigma) deg | roll wanted / fitted (sigma) deg "
        "| sideways error mm | depth offset wanted / fitted (sigma) mm "
        "| range offset wanted / fitted (sigma) mm "
        "| forward: the orbit's fixes off / fitted (sigma) mm "
        "| sonar's drawn forward error mm "
        "| elevation offset wanted / fitted (sigma) deg | drawn pitch correction deg, height mm "
        "| height wanted / fitted (sigma) mm "
        "| written position error: forward against where a fix needs it (against drawn), "
        "height mm "
        "| determined |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in figures["runs"]:
        determined = [k for k in DETERMINED_TERMS if r.get(f"{k}_determined")]
        height = (
            f"{r.get('wanted_height_mm')} / {r.get('fitted_height_mm')} "
            f"({r.get('height_sigma_mm')}"
            + (
                f"; the profiles alone {r['height_data_sigma_mm']}"
                if r.get("height_data_sigma_mm") is not None
                else ""
            )
            + ")"
            if r.get("fitted_height_mm") is not None
            else "-"
        )
        lines.append(
            f"| {r['seed']} | {r['wanted_yaw_deg']} / {r['fitted_yaw_deg']} "
            f"({r['yaw_sigma_deg']}) | {r['wanted_roll_deg']} / {r['fitted_roll_deg']} "
            f"({r['roll_sigma_deg']}) | {r['shift_error_mm']} "
            f"| {r['wanted_depth_offset_mm']} / {r['fitted_depth_offset_mm']} "
            f"({r['depth_offset_sigma_mm']}) "
            f"| {r.get('wanted_range_offset_mm', '-')} / {r.get('fitted_range_offset_mm', '-')} "
            f"({r.get('range_offset_sigma_mm', '-')}) "
            f"| {r.get('wanted_forward_mm', '-')} / {r.get('fitted_forward_mm', '-')} "
            f"({r.get('forward_sigma_mm', '-')}) | {r.get('drawn_x_mm', '-')} "
            f"| {r.get('wanted_elevation_offset_deg', '-')} / "
            f"{r.get('fitted_elevation_offset_deg', '-')} "
            f"({r.get('elevation_offset_sigma_deg', '-')}) "
            f"| {r.get('drawn_pitch_correction_deg', '-')}, {r.get('drawn_height_mm', '-')} "
            f"| {height} | {r.get('forward_error_vs_wanted_mm', '-')} "
            f"({r.get('forward_error_mm', '-')}), "
            f"{r.get('height_error_written_mm', '-')} | {', '.join(determined)} |"
        )
    return lines


def fitted_wanted(calibration: dict[str, Any], name: str) -> str:
    """'fitted / wanted' of one calibrated term ('-' fitted where it was not determined)."""
    fitted = calibration.get(f"{name}_mm")
    return f"{'-' if fitted is None else fitted} / {calibration.get(f'{name}_wanted_mm', '-')}"


def self_calibrated_table(figures: dict[str, Any]) -> list[str]:
    """With installation errors: ours uncalibrated, then both methods after self-calibration."""
    lines = [
        "| run | ours uncalibrated | yaw fitted / wanted (deg) | depth offset fitted / wanted "
        "(mm) | range offset fitted / wanted (mm) | forward fitted / wanted (mm) | ours "
        "| baseline (box range, mount, depth and range calibrated) | ratio "
        "| ours: mean NEES, share within the 95 % bound | a perfect detector: ratio |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    perfect = figures.get("perfect_detector_self_calibrated", {})
    for name, c in _in_order(figures["common_self_calibrated"]):
        cal = figures["self_calibration"][name]
        before = figures["runs"][name][OURS].get("med_mm")
        before_cell = "-" if before is None else f"{before:.1f}"
        if "ratio" not in c:
            lines.append(
                f"| {_run_name(name)} | {before_cell} | - | - | - | - | - | - | - | - "
                f"| {_ratio(perfect.get(name))} |"
            )
            continue
        ours = figures["runs"][name][OURS_SELF_CALIBRATED]
        lines.append(
            f"| {_run_name(name)} | {before_cell} | {cal['yaw_deg']} / {cal['yaw_wanted_deg']} "
            f"| {cal['depth_offset_mm']} / {cal['depth_offset_wanted_mm']} "
            f"| {fitted_wanted(cal, 'range_offset')} | {fitted_wanted(cal, 'forward')} "
            f"| {c['ours_med_mm']:.1f} | {c['other_med_mm']:.1f} "
            f"| {c['ratio']:.2f} {_ci(c['ratio_ci'], 2)} "
            f"| {ours['nees_mean']}, {_pct(ours['nees_within_95'])} "
            f"| {_ratio(perfect.get(name))} |"
        )
    return lines


RENDERERS: dict[str, tuple[Callable[[dict[str, Any]], list[str]], str]] = {
    "accuracy_table": (accuracy_table, "capsd bench accuracy"),
    "accuracy_common": (accuracy_common, "capsd bench accuracy"),
    "box_range_bias": (box_range_bias, "capsd bench accuracy"),
    "detector_budget": (detector_budget, "capsd bench accuracy"),
    "evaluate_checks": (evaluate_checks, "capsd bench evaluate"),
    "demo_summary": (demo_summary, "capsd demo"),
    "latency_table": (latency_table, "capsd bench latency"),
    "detect_table": (detect_table, "capsd bench detect --json FILE"),
    "detect_gated_table": (detect_gated_table, "capsd bench detect --depth-gate truth --json FILE"),
    "consistency_table": (consistency_table, "capsd bench consistency"),
    "finetune_table": (finetune_table, "capsd bench finetune"),
    "calibrate_table": (calibrate_table, "capsd bench calibrate"),
    "self_calibrated_table": (
        self_calibrated_table,
        "capsd bench accuracy --install-errors realistic",
    ),
}


def render(text: str, *, root: Path) -> str:
    """`text` with every figures block rewritten from its source (paths relative to `root`)."""

    def block(match: re.Match[str]) -> str:
        name, source = match["name"], match["source"]
        if name not in RENDERERS:
            raise CapsdError(f"figures block '{name}': no such table ({sorted(RENDERERS)})")
        renderer, command = RENDERERS[name]
        path = root / source
        try:
            figures = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise CapsdError(f"figures block '{name}': {path} unreadable ({exc})") from None
        try:
            lines = renderer(figures)
        except (KeyError, TypeError, ZeroDivisionError) as exc:
            raise CapsdError(
                f"figures block '{name}': {path} is not `{command}`'s output (field {exc})"
            ) from None
        caption = f"_Written by `capsd docs figures` from `{source}` (`{command}`)._"
        indent = match["indent"]
        body = "".join(f"{indent}{line}\n" if line else "\n" for line in [*lines, "", caption])
        return f"{indent}{match['open']}{body}{match['close']}"

    return _BLOCK.sub(block, text)


def blocks(text: str) -> list[tuple[str, str]]:
    """(renderer, source) of each figures block in `text`."""
    return [(m["name"], m["source"]) for m in _BLOCK.finditer(text)]
