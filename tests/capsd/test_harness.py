"""The demo's configs: a calibration dive gives every service that reads the mount its fit."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest
import yaml

from capsd.geometry import Transform
from capsd.harness import write_configs
from capsd.mounts import SonarMountConfig

ENDPOINT = "tcp/127.0.0.1:7447"  # written into the configs only; nothing connects


def _configs(folder: Path, **options: Any) -> dict[str, dict[str, Any]]:
    folder.mkdir()
    paths = write_configs(
        folder, ENDPOINT, trajectory="square", tank="nfp", seed=3, mav_port=5760, **options
    )
    return {name: yaml.safe_load(path.read_text()) for name, path in paths.items()}


def test_a_calibration_dive_gives_the_services_the_calibrated_mount(tmp_path: Path) -> None:
    tape = _configs(tmp_path / "tape")
    # A minute of each manoeuvre (the demo: two): every term determined (30 s leaves the yaw).
    dived = _configs(tmp_path / "dived", calibration="dive", calibration_s=60.0)
    found = json.loads((tmp_path / "dived" / "calibration.json").read_text())
    assert "yaw" in found["determined"]
    assert abs(found["yaw_deg"] - found["yaw_wanted_deg"]) < 0.2
    sonar = dived["locator"]["sonar"]
    # The services' sonar is turned by the fitted yaw, a turn about the sonar's own vertical:
    # its boresight's bearing on the ASV moves by yaw / cos(pitch); roll leaves it.
    before = msgspec.convert(tape["locator"].get("sonar", {}), SonarMountConfig)
    after = msgspec.convert(sonar, SonarMountConfig)
    turned = _boresight_deg(after.transform()) - _boresight_deg(before.transform())
    expected = found["yaw_deg"] / math.cos(math.radians(before.pitch_deg))
    assert turned == pytest.approx(expected, abs=0.005)
    assert after.roll_deg == pytest.approx(before.roll_deg + found["roll_deg"], abs=0.05)
    # The detector's depth gate looks through the same mount; the sigmas shrink to what is left.
    assert dived["sonar_detect"]["sonar"] == sonar
    left, tape_sigmas = dived["locator"]["installation"], tape["locator"]["installation"]
    assert left["sonar_angles_deg"][0] < tape_sigmas["sonar_angles_deg"][0]  # yaw
    assert not (tmp_path / "tape" / "calibration.json").exists()


def _boresight_deg(mount: Transform) -> float:
    """The sonar's heading on the ASV: its boresight's bearing in the body frame."""
    axis = mount.rotation @ np.array([1.0, 0.0, 0.0])
    return math.degrees(math.atan2(axis[1], axis[0]))


def test_a_perfect_installation_is_not_calibrated(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="calibrates a realistic installation"):
        _configs(tmp_path / "off", install_errors="off", calibration="dive")
