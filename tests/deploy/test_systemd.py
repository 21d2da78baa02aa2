"""The systemd units: the settings a field deployment relies on, and `systemd-analyze verify`."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import REPO

UNITS = sorted((REPO / "deploy" / "systemd").glob("capsd-*.service"))


def test_every_deployed_service_has_a_unit() -> None:
    names = {u.stem.removeprefix("capsd-").replace("-", "_") for u in UNITS}
    assert {
        "router",
        "asv_pose",
        "sonar_detect",
        "oculus",
        "tim5xx",
        "locator",
        "mav_bridge",
    } <= names


@pytest.mark.parametrize("unit", UNITS, ids=lambda p: p.name)
def test_unit_settings(unit: Path) -> None:
    lines = {
        line.split("=", 1)[0]: line.split("=", 1)[1]
        for line in unit.read_text().splitlines()
        if "=" in line and not line.startswith("#")
    }
    assert lines["Type"] == "notify"
    assert int(lines["WatchdogSec"]) > 0
    assert lines["Restart"] == "on-failure"
    assert lines["RestartPreventExitStatus"] == "2"  # a bad config is not a crash loop
    assert lines["EnvironmentFile"].lstrip("-") == "/etc/capsd/capsd.env"
    assert lines["User"] == "capsd"
    assert lines["MemoryMax"].endswith("M")
    config = lines["ExecStart"].split("--config ")[1]
    example = REPO / "deploy" / "config" / Path(config).name
    assert example.exists(), f"{unit.name}: no example config {example.name}"


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed")
def test_systemd_analyze_verify(tmp_path: Path) -> None:
    capsd = Path(sys.executable).parent / "capsd"
    assert capsd.exists()
    for unit in UNITS:
        text = unit.read_text().replace("/opt/capsd/venv/bin/capsd", str(capsd))
        (tmp_path / unit.name).write_text(text)
    proc = subprocess.run(
        ["systemd-analyze", "verify", "--man=no", *sorted(str(p) for p in tmp_path.iterdir())],
        capture_output=True,
        text=True,
        timeout=60,
    )
    # Warnings (an unknown value is "ignored") count as failures too.
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.strip() == "", proc.stderr


@pytest.mark.integration
@pytest.mark.shares_cpu  # an install: nothing timed
def test_install_script_for_the_rov_role(tmp_path: Path) -> None:
    """The ROV role installs without torch/scipy/opencv, its units point at its venv.

    CI's only check of the ROV role's install (capsd[rov] alone, as the ROV computer has it).
    """
    prefix, etc, units = tmp_path / "opt", tmp_path / "etc", tmp_path / "units"
    proc = subprocess.run(
        [
            "bash",
            str(REPO / "deploy" / "install.sh"),
            "rov",
            "--prefix",
            str(prefix),
            "--etc",
            str(etc),
            "--unit-dir",
            str(units),
            "--no-enable",
            "--no-user",
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    unit = (units / "capsd-mav-bridge.service").read_text()
    assert (
        f"ExecStart={prefix}/venv/bin/capsd run mav_bridge --config {etc}/mav_bridge.yaml" in unit
    )
    assert (etc / "mav_bridge.yaml").exists()
    check = subprocess.run(
        [
            str(prefix / "venv" / "bin" / "python"),
            "-c",
            "import importlib.util as u, capsd.services.mav_bridge.service; "
            "print([m for m in ('torch', 'scipy', 'cv2') if u.find_spec(m)])",
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert check.returncode == 0, check.stderr
    assert check.stdout.strip() == "[]"
    # The bridge's config checks and prints in that venv (no heavy import on its path).
    shown = subprocess.run(
        [str(prefix / "venv" / "bin" / "capsd"), "run", "mav_bridge", "--print-config"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert shown.returncode == 0, shown.stderr
    assert "fix_auth" in shown.stdout
    if shutil.which("systemd-analyze"):
        verify = subprocess.run(
            ["systemd-analyze", "verify", "--man=no", str(units / "capsd-mav-bridge.service")],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert verify.returncode == 0, verify.stderr


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed")
@pytest.mark.parametrize("unit", UNITS, ids=lambda p: p.name)
def test_units_are_hardened(unit: Path) -> None:
    proc = subprocess.run(
        ["systemd-analyze", "security", "--offline=true", "--no-pager", str(unit)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    line = [x for x in proc.stdout.splitlines() if "Overall exposure level" in x]
    assert line, proc.stdout + proc.stderr
    exposure = float(line[0].split(":")[1].split()[0])
    assert exposure <= 4.5, line[0]
