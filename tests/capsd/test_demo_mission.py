"""`capsd demo --mission`: the whole closed loop, every part its own process, on the CPU.

The simulated ROV is flown by the ArduSub stand-in the simulator hosts, on CAP-SD's own
estimates; the mission commands it through the bridge. A short plan in clear water ahead of
the ASV's station must be flown to the end, close to its line.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from tests.conftest import REPO

pytestmark = pytest.mark.integration


def _demo(tmp_path: Path, plan_text: str, *flags: str) -> tuple[Path, dict[str, Any]]:
    """`capsd demo --mission PLAN FLAGS`; its report folder and figures (exit 0 asserted)."""
    plan = tmp_path / "plan.yaml"
    plan.write_text(plan_text)
    out = tmp_path / "demo"
    run = subprocess.run(
        [sys.executable, "-m", "capsd", "demo", "--mission", str(plan), *flags,
         "--duration", "150", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=280,
        cwd=REPO,
    )  # fmt: skip
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]
    assert "the mission ended" in run.stdout
    return out, json.loads((out / "figures.json").read_text())


@pytest.mark.timeout(300)
def test_demo_flies_a_short_mission_closed_loop(tmp_path: Path) -> None:
    out, figures = _demo(
        tmp_path,
        "name: short\nresume_after_s: 2.0\npoints:\n"
        "  - {position_m: [15.0, 7.0], depth_m: 3.5}\n"
        "  - {position_m: [16.5, 7.0], depth_m: 3.5, dwell_s: 2}\n",
        # A perfect installation: the truth then measures the loop. Uncalibrated, the fixes
        # carry the drawn mount errors (this seed's sonar 1.16 deg off in yaw: 0.14 m at 7 m),
        # and a ROV kept on the line its fixes show is that far off the true one.
        "--install-errors",
        "off",
    )
    mission = figures["mission"]
    assert mission["state"] == "done", mission
    assert mission["waypoint_reached"] == 2
    assert mission["cross_track_max_m"] is not None
    assert mission["cross_track_rms_m"] < 0.15, mission
    # The autopilot was commanded: one engage, targets, the final hold.
    assert mission["commands"]["engage"] >= 1
    assert mission["commands"]["hold"] >= 1
    assert (out / "mission" / "mission.png").exists()
    # The simulator's truth against the plan, while flying.
    truth = mission["truth"]
    assert truth["pings"] > 50
    assert truth["cross_track_rms_m"] < 0.15, truth
    assert truth["availability"] > 0.5, truth
    assert mission["asv"]["travelled_m"] < 0.5, mission["asv"]  # on station: waves only


@pytest.mark.timeout(300)
def test_demo_with_the_asv_following(tmp_path: Path) -> None:
    """The ASV's bridge and the follower drive the simulated ASV after the ROV."""
    _, figures = _demo(
        tmp_path,
        "name: follow\nresume_after_s: 2.0\npoints:\n"
        "  - {position_m: [15.0, 7.0], depth_m: 3.5}\n"
        "  - {position_m: [17.5, 7.0], depth_m: 3.5, dwell_s: 2}\n",
        "--asv",
        "follow",
    )
    mission = figures["mission"]
    assert mission["state"] == "done", mission
    follower = figures["health"]["asv_follow"]["counters"]
    bridge = figures["health"]["asv_bridge"]["counters"]
    assert follower["stations_chosen"] >= 2, follower  # the first, and one as the ROV moved
    assert bridge["commands_sent_target"] > 10, bridge
    assert bridge["gate_sent"] > 100, bridge  # the ASV's own pose into its autopilot
    assert mission["asv"]["travelled_m"] > 0.5, mission["asv"]
    assert mission["asv"]["min_wall_distance_m"] >= 1.6, mission["asv"]  # hull: 1 m
