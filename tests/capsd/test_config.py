"""Config loading: every error names the file, the key path and the line."""

from __future__ import annotations

import math
from pathlib import Path

import msgspec
import pytest
import yaml

from capsd.config import (
    BusConfig,
    ServiceConfig,
    _unique_key_loader,
    dump_config,
    load_config,
    parse_config,
)
from capsd.errors import ConfigError
from capsd.mounts import SonarMountConfig
from capsd.services.locator.service import Config as LocatorConfig


def _error(text: str, cls: type = ServiceConfig) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        parse_config(text, cls, source="svc.yaml")
    return info.value


def test_unknown_key_names_path_and_line() -> None:
    err = _error("site: t1\nbus:\n  mode: client\n  conect: []\n")
    assert err.key_path == "bus.conect"
    assert err.line == 4
    assert "svc.yaml:4" in str(err)
    assert "unknown key" in str(err)


def test_wrong_type() -> None:
    err = _error("health_period_s: fast\n")
    assert err.key_path == "health_period_s"
    assert "Expected `float`, got `str`" in err.reason


def test_out_of_range_and_nan() -> None:
    assert "<= 60.0" in _error("health_period_s: 100\n").reason
    assert _error("health_period_s: .nan\n").key_path == "health_period_s"


def test_bad_endpoint_points_at_the_list_item() -> None:
    err = _error("bus:\n  connect:\n    - tcp/127.0.0.1:7447\n    - 127.0.0.1\n")
    assert err.key_path == "bus.connect[1]"
    assert err.line == 4


def test_bad_site_name() -> None:
    err = _error("site: Tank One\n")
    assert err.key_path == "site"
    assert "invalid" in err.reason


def test_duplicate_keys_and_bad_yaml() -> None:
    assert "duplicate key 'site'" in str(_error("site: a\nsite: b\n"))
    assert _error("bus: [\n").line == 2
    assert "mapping" in str(_error("- a\n- b\n"))


def test_nested_service_section_error() -> None:
    err = _error("sonar:\n  pitch_deg: 120\n", LocatorConfig)
    assert err.key_path == "sonar.pitch_deg"
    assert err.line == 2


def test_router_and_client_rules() -> None:
    assert "listen" in str(_error("bus:\n  mode: router\n  connect: []\n"))
    assert "connect" in str(_error("bus:\n  connect: []\n"))


def test_empty_file_gives_defaults_and_missing_file_is_named(tmp_path: Path) -> None:
    empty = tmp_path / "empty.yaml"
    empty.write_text("")
    assert load_config(empty, ServiceConfig) == ServiceConfig()
    with pytest.raises(ConfigError, match=r"missing\.yaml"):
        load_config(tmp_path / "missing.yaml", ServiceConfig)


def test_degrees_in_file_radians_in_code() -> None:
    mount = parse_config("pitch_deg: 90\nyaw_deg: 0\n", SonarMountConfig, source="m.yaml")
    boresight = mount.transform().rotation @ [1.0, 0.0, 0.0]
    assert boresight == pytest.approx([0.0, 0.0, -1.0], abs=1e-12)  # pitched 90 deg: looks down
    assert math.isclose(mount.vertical_aperture_deg, 20.0)


def test_dump_round_trips() -> None:
    config = LocatorConfig(site="pond", bus=BusConfig(connect=("tcp/10.0.0.1:7447",)))
    assert parse_config(dump_config(config), LocatorConfig, source="x") == config


@pytest.mark.parametrize("path", sorted(Path("deploy/config").glob("*.yaml")), ids=str)
def test_shipped_example_configs_load(path: Path) -> None:
    from capsd.cli import RouterConfig
    from capsd.registry import service_of_config

    name = path.name.split(".")[0]
    cls = RouterConfig if name == "router" else service_of_config(name).load()[0]
    load_config(path, cls)


def test_a_bare_off_is_the_choice_off_and_true_stays_a_boolean() -> None:
    # YAML 1.1 reads a bare off/on/yes/no as a boolean: a choice named "off" was refused.
    from capsd.mission.plan import Plan

    text = "points:\n  - {position_m: [1.0, 1.0], depth_m: 1.0}\nview_guard: {mode: off}\n"
    assert parse_config(text, Plan, source="plan.yaml").view_guard.mode == "off"
    assert yaml.load("a: true\nb: False\nc: yes\nd: on\n", Loader=_unique_key_loader()) == {
        "a": True, "b": False, "c": "yes", "d": "on",
    }  # fmt: skip
    # The stock loader is left as it was.
    assert yaml.safe_load("d: on\n") == {"d": True}


def test_the_shipped_depth_gate_sees_the_sonar_where_the_locator_does() -> None:
    # Two services, two files: a mount changed in one only would gate every ping against a
    # sonar that is not there (the gate's margins allow for a protractor's error, not more).
    from capsd.services.sonar_detect.service import Config as DetectConfig

    locator = load_config(Path("deploy/config/locator.yaml"), LocatorConfig).sonar
    gate = load_config(Path("deploy/config/sonar_detect.yaml"), DetectConfig).depth_gate
    assert gate.mode == "reject"
    # The range offset is the locator's alone (the gate never reads a range so finely).
    assert msgspec.structs.replace(gate.sonar, range_offset_m=locator.range_offset_m) == locator
