"""The Foxglove layout names only channels the view makes and fields the payloads have."""

from __future__ import annotations

import json
import re

from capsd import topics
from capsd.payloads import Health, RovFix
from capsd.scene import TOPICS
from tests.conftest import REPO

LAYOUT = json.loads((REPO / "deploy" / "foxglove" / "capsd-layout.json").read_text())


def _panels(node: object) -> list[str]:
    if isinstance(node, str):
        return [node]
    assert isinstance(node, dict)
    return _panels(node["first"]) + _panels(node["second"])


def test_every_panel_in_the_layout_is_configured() -> None:
    panels = _panels(LAYOUT["layout"])
    assert sorted(panels) == sorted(LAYOUT["configById"])
    kinds = {p.split("!")[0] for p in panels}
    assert {"3D", "Image", "Plot", "Table", "RosOut"} <= kinds


def test_the_layout_names_real_channels_and_fields() -> None:
    view = set(TOPICS)
    config = LAYOUT["configById"]
    assert set(config["3D!capsd_scene"]["topics"]) <= view
    assert config["Image!capsd_fan"]["imageMode"]["imageTopic"] in view
    assert config["Image!capsd_map"]["imageMode"]["imageTopic"] in view
    assert config["RosOut!capsd_log"]["topicToRender"] in view
    fix_key = topics.ROV_FIX.key("tank", "topside")
    for panel in ("Plot!capsd_xyz", "Plot!capsd_sigma"):
        for path in config[panel]["paths"]:
            key, field = re.fullmatch(r'"([^"]+)"\.(\w+)\[\d\].*', path["value"]).groups()  # type: ignore[union-attr]
            assert key == fix_key
            assert field in RovFix.__struct_fields__
    for panel in ("Table!capsd_health", "Table!capsd_bridge"):
        key = config[panel]["topicPath"].strip('"')
        assert re.fullmatch(r"cap/tank/\w+/health/\w+", key)
    assert "state" in Health.__struct_fields__
