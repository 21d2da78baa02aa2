"""The per-role configs load (with a site's certificates) and join the way each role must."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
import zenoh

from capsd.cli import RouterConfig
from capsd.config import load_config
from capsd.registry import service_of_config
from tests.conftest import REPO

ROLES = REPO / "deploy" / "roles"


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("certs")
    script = REPO / "deploy" / "security" / "make-site-certs.sh"
    subprocess.run(["bash", str(script), str(out)], check=True, capture_output=True, timeout=60)
    return out


@pytest.mark.parametrize(
    "path", sorted(ROLES.glob("*/*.yaml")), ids=lambda p: f"{p.parent.name}/{p.name}"
)
def test_role_config_loads(path: Path, certs: Path, tmp_path: Path) -> None:
    text = path.read_text().replace("/etc/capsd/certs", str(certs))
    text = text.replace(
        "/etc/capsd/access_control.json5", str(REPO / "deploy/security/access_control.json5")
    )
    local = tmp_path / path.name
    local.write_text(text)
    name = path.stem
    cls = RouterConfig if name == "router" else service_of_config(name).load()[0]
    config = load_config(local, cls)
    role = path.parent.name
    if role == "rov":  # the Pi: BlueOS's router on loopback, no second router
        assert config.bus.connect == ("tcp/127.0.0.1:7447",)
        assert config.bus.mode == "client"
    elif name == "router":
        assert config.bus.tls is not None
        assert config.bus.access_control_file is not None
    else:  # between computers: mutual TLS
        assert config.bus.tls is not None
        assert all(e.startswith("tls/") for e in config.bus.connect)


def test_blueos_uplink_is_valid_zenoh_config(certs: Path) -> None:
    text = (ROLES / "rov" / "blueos-router-uplink.json5").read_text()
    # The whole file parses as Zenoh's own JSON5 configuration.
    full = zenoh.Config.from_json5(text.replace("/etc/capsd/certs", str(certs)))
    assert "tls/topside:7447" in str(full.get_json("connect/endpoints"))
