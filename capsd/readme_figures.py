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
        "| run | common pings | ours | paper, calibrated | ours / calibrated |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, against in _in_order(figures["common"]):
        c = against[CALIBRATED]
        if "ratio" not in c:
            lines.append(f"| {_run_name(name)} | 0 | - | - | - |")
            continue
        lines.append(
            f"| {_run_name(name)} | {c['common_pings']} "
            f"| {c['ours_med_mm']:.1f} {_ci(c['ours_med_ci_mm'])} "
            f"| {c['other_med_mm']:.1f} {_ci(c['other_med_ci_mm'])} "
            f"| {c['ratio']:.2f} {_ci(c['ratio_ci'], 2)} |"
        )
    return lines


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


RENDERERS: dict[str, tuple[Callable[[dict[str, Any]], list[str]], str]] = {
    "accuracy_table": (accuracy_table, "capsd bench accuracy"),
    "accuracy_common": (accuracy_common, "capsd bench accuracy"),
    "evaluate_checks": (evaluate_checks, "capsd bench evaluate"),
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
