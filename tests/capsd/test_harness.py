"""The demo's configs: a calibration dive gives every service that reads the mount its fit."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import msgspec
import pytest
import yaml

from capsd.config import load_config
from capsd.errors import ConfigError
from capsd.harness import SonarTilt, detector_settings_of, follow_config, write_configs
from capsd.mounts import SonarMountConfig
from capsd.registry import service_of_config
from capsd.services.asv_follow.service import Config as FollowConfig
from capsd.simulator.config import Config as SimConfig
from capsd.simulator.sim import Simulation
from capsd.simulator.world import TankName

ENDPOINT = "tcp/127.0.0.1:7447"  # written into the configs only; nothing connects


def _configs(folder: Path, *, tank: TankName = "nfp", **options: Any) -> dict[str, dict[str, Any]]:
    folder.mkdir()
    paths = write_configs(
        folder, ENDPOINT, trajectory="square", tank=tank, seed=3, mav_port=5760, **options
    )
    for name, path in paths.items():
        if name != "mission":  # capsd mission run's own config, not a service's
            config_class, _ = service_of_config(name).load()
            load_config(path, config_class)  # each service takes what it is given
    return {name: yaml.safe_load(path.read_text()) for name, path in paths.items()}


def test_a_calibration_dive_gives_the_services_the_calibrated_mount(tmp_path: Path) -> None:
    tape = _configs(tmp_path / "tape")
    # Half a minute of each manoeuvre (the demo: two minutes) determines the depth offset and
    # the range offset; the yaw needs longer (capsd bench calibrate measures
    # the fits; this is what the services are given).
    dived = _configs(tmp_path / "dived", calibration="dive", calibration_s=30.0)
    found = json.loads((tmp_path / "dived" / "calibration.json").read_text())
    assert {"depth_offset", "range_offset"} <= set(found["determined"])
    # The dive calibrated this run's installation (drawn from the run's seed), not another.
    live = Simulation(msgspec.convert(tape["sim"], SimConfig), horizon_s=10.0)
    assert found["drawn"] == json.loads(json.dumps(live.errors.summary()))
    before = msgspec.convert(tape["locator"].get("sonar", {}), SonarMountConfig)
    after = msgspec.convert(dived["locator"]["sonar"], SonarMountConfig)
    # Ranges too long: every range less that much, less what it took of the height where the
    # two profiles determined it; fixes too far along the ASV's axis (when the ROV was seen
    # across the fan): the sonar sits that much further back than the tape said.
    assert after.range_offset_m == pytest.approx(
        before.range_offset_m - (found["range_offset_mm"] - found["range_give_back_mm"]) / 1000,
        abs=1e-3,
    )
    forward = found["forward_mm"] / 1000 if "forward" in found["determined"] else 0.0
    assert after.position_m[0] == pytest.approx(before.position_m[0] - forward, abs=1e-3)
    height = found["height_mm"] / 1000 if "height" in found["determined"] else 0.0
    assert after.position_m[2] == pytest.approx(before.position_m[2] + height, abs=1e-3)
    assert ("height" in found["determined"]) == (found["range_give_back_mm"] != 0.0)
    assert dived["locator"]["rov"]["depth_offset_m"] == pytest.approx(
        found["depth_offset_mm"] / 1000, abs=1e-3
    )
    # Not determined: left as the tape had it.
    assert ("yaw" in found["determined"]) == (after.yaw_deg != before.yaw_deg)
    # The detector's depth gate and the follower look through the same mount; the sigmas left
    # shrink to what the dive did not determine.
    assert dived["sonar_detect"]["depth_gate"]["sonar"] == dived["locator"]["sonar"]
    left, tape_sigmas = dived["locator"]["installation"], tape["locator"]["installation"]
    assert left["depth_offset_m"] < tape_sigmas["depth_offset_m"]
    assert not (tmp_path / "tape" / "calibration.json").exists()


def test_the_depth_gate_looks_through_the_tanks_sonar_mount(tmp_path: Path) -> None:
    configs = _configs(tmp_path / "mockup", tank="mockup")
    assert configs["sonar_detect"]["depth_gate"]["sonar"] == configs["locator"]["sonar"]
    assert configs["locator"]["sonar"]["pitch_deg"] == 45.0


def test_a_detector_config_sets_how_it_detects_not_where_it_listens(tmp_path: Path) -> None:
    # The deployed file with a site's changes (as text: YAML 1.1 reads its `on` as true).
    text = Path("deploy/config/sonar_detect.yaml").read_text()
    for old, new in (
        ("close_proposal: on", "close_proposal: off"),
        ("  max_candidates: 6 ", "  max_candidates: 5 "),  # the cnn's (the classical's: 3)
        ("min_confidence: 0.5", "min_confidence: 0.6"),
        ("connect: [tcp/127.0.0.1:7447]", "connect: [tcp/192.0.2.1:7447]"),  # never the demo's
        ("  tolerance_m: 0.3 ", "  tolerance_m: 0.4 "),  # the depth gate's
        ("    pitch_deg: 30.0", "    pitch_deg: 10.0"),  # the depth gate's sonar: never the demo's
        ("  mode: reject ", "  mode: reject\n  rov_vehicle: bluerov "),  # never the demo's
    ):
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / "sonar_detect.yaml"
    path.write_text(text)
    settings = detector_settings_of(path)
    configs = _configs(tmp_path / "mockup", tank="mockup", detector_settings=settings)
    detect = configs["sonar_detect"]
    assert detect["cnn"]["close_proposal"] == "off"
    assert detect["cnn"]["max_candidates"] == 5
    assert detect["min_confidence"] == 0.6
    assert detect["bus"] == {"connect": [ENDPOINT]}
    # The gate's own settings the file's, what it looks through and listens to the demo's.
    assert detect["depth_gate"]["sonar"] == configs["locator"]["sonar"]
    assert detect["depth_gate"]["tolerance_m"] == 0.4
    assert "rov_vehicle" not in detect["depth_gate"]
    plain = _configs(tmp_path / "plain", tank="mockup")["sonar_detect"]
    assert "cnn" not in plain
    path.write_text("cnn:\n  close_proposal: maybe\n")
    with pytest.raises(ConfigError, match=r"sonar_detect.yaml:2 at 'cnn.close_proposal'"):
        detector_settings_of(path)


def test_a_perfect_installation_is_not_calibrated(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="calibrates a realistic installation"):
        _configs(tmp_path / "off", install_errors="off", calibration="dive")


def test_a_pan_tilt_mount_reaches_every_service_that_looks_through_it(tmp_path: Path) -> None:
    """`--sonar-tilt pan-tilt`: the services are told both servos.

    Also after a calibration dive (which holds them at their zeros and fits the mount there).
    """
    followed = _configs(
        tmp_path / "followed", tank="mockup", sonar_tilt="pan-tilt", asv="follow",
        asv_mav_port=5761, rov_start_m=(3.8, 1.0, -1.0),
    )  # fmt: skip
    # (Ten seconds a manoeuvre: what reaches the services, not what the fits determine.)
    dived = _configs(tmp_path / "dived", sonar_tilt="pan-tilt", calibration="dive",
                     calibration_s=10.0)  # fmt: skip
    told = [
        (configs, name) for configs in (followed, dived) for name in ("locator", "sonar_detect")
    ]
    told.append((followed, "asv_follow"))
    for configs, name in told:
        body = configs[name]["depth_gate"] if name == "sonar_detect" else configs[name]
        mount = msgspec.convert(body["sonar"], SonarMountConfig)
        assert mount.tilt is not None, name
        assert mount.pan is not None, name
    assert followed["asv_bridge"]["sonar_tilt"]["pan"] == "servo"
    assert msgspec.convert(followed["sim"]["sonar"], SonarMountConfig).pan is not None


@pytest.mark.parametrize(
    ("tilt", "min_m", "preferred_m", "abeam_deg"),
    [("fixed", 1.0, None, 60.0), ("servo", 1.0, None, 60.0), ("pan-tilt", 1.1, 1.2, 0.0)],
)
def test_the_mockup_follower_keeps_a_pan_tilt_sonar_further_off_the_rov(
    tmp_path: Path, tilt: SonarTilt, min_m: float, preferred_m: float | None, abeam_deg: float
) -> None:
    """The demo's follower and `follow_config` (benches, mission check) get the same rules."""
    configs = _configs(
        tmp_path / "followed", tank="mockup", sonar_tilt=tilt, asv="follow",
        asv_mav_port=5761, rov_start_m=(3.8, 1.0, -1.0),
    )  # fmt: skip
    demo = load_config(tmp_path / "followed" / "asv_follow.yaml", FollowConfig)
    assert configs["asv_follow"]["station"].get("preferred_min_range_m") == preferred_m
    shared = follow_config("mockup", tilt=tilt)
    for config in (demo, shared):
        assert config.station.min_range_m == min_m
        assert config.station.preferred_min_range_m == preferred_m
        assert config.motion.pan_abeam_deg == abeam_deg
