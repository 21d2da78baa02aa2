"""The shipped security: mutual TLS and deny-by-default access control on a real router."""

from __future__ import annotations

import subprocess
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml
import zenoh

from capsd.bus import open_session
from capsd.config import BusConfig, TlsConfig
from capsd.errors import BusError
from tests.conftest import REPO, Proc, free_port, wait_for

pytestmark = pytest.mark.integration
SECURITY = REPO / "deploy" / "security"
FIX = "cap/tank/topside/locator/fix"


@pytest.fixture
def certs(tmp_path: Path) -> Path:
    out = tmp_path / "certs"
    subprocess.run(
        ["bash", str(SECURITY / "make-site-certs.sh"), str(out)],
        check=True,
        capture_output=True,
        timeout=60,
    )
    return out


@pytest.fixture
def secure_router_proc(spawn: Callable[..., Proc], certs: Path, tmp_path: Path) -> tuple[str, Proc]:
    """The shipped router.secure.yaml with this test's certificates and a free port."""
    config = yaml.safe_load((SECURITY / "router.secure.yaml").read_text())
    port = free_port()
    config["bus"]["listen"] = [f"tls/127.0.0.1:{port}"]
    config["bus"]["tls"] = {
        "ca_certificate": str(certs / "ca.pem"),
        "certificate": str(certs / "capsd-router.pem"),
        "private_key": str(certs / "capsd-router.key"),
    }
    config["bus"]["access_control_file"] = str(SECURITY / "access_control.json5")
    path = tmp_path / "router.yaml"
    path.write_text(yaml.safe_dump(config))
    proc = spawn("router", "--config", str(path))
    endpoint = f"tls/localhost:{port}"
    time.sleep(1.5)
    assert proc.popen.poll() is None, proc.output()
    return endpoint, proc


@pytest.fixture
def secure_router(secure_router_proc: tuple[str, Proc]) -> str:
    return secure_router_proc[0]


def _bus(endpoint: str, certs: Path, identity: str) -> BusConfig:
    return BusConfig(
        connect=(endpoint,),
        tls=TlsConfig(
            ca_certificate=str(certs / "ca.pem"),
            certificate=str(certs / f"{identity}.pem"),
            private_key=str(certs / f"{identity}.key"),
        ),
    )


class Inbox:
    def __init__(self, session: zenoh.Session, key: str):
        self.got: list[tuple[str, bytes]] = []
        self.lock = threading.Lock()
        self.sub = session.declare_subscriber(key, self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        with self.lock:
            self.got.append((str(sample.key_expr), sample.payload.to_bytes()))

    def payloads(self) -> list[bytes]:
        with self.lock:
            return [p for _, p in self.got]


def test_a_client_without_credentials_cannot_connect(secure_router: str, certs: Path) -> None:
    plain = f"tcp/127.0.0.1:{secure_router.rsplit(':', 1)[1]}"
    with pytest.raises(BusError):
        open_session(BusConfig(connect=(plain,), connect_timeout_s=1.0))
    # TLS that trusts the site CA but presents no client certificate: refused by mTLS.
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", f'["{secure_router}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("transport/link/tls/root_ca_certificate", f'"{certs / "ca.pem"}"')
    with pytest.raises(zenoh.ZError):
        zenoh.open(conf)


def test_laptop_taps_but_cannot_move_the_vehicle(secure_router: str, certs: Path) -> None:
    with (
        open_session(_bus(secure_router, certs, "capsd-rov")) as bridge,
        open_session(_bus(secure_router, certs, "capsd-laptop")) as laptop,
        open_session(_bus(secure_router, certs, "capsd-locator")) as locator,
    ):
        at_bridge = Inbox(bridge, FIX)
        at_laptop = Inbox(laptop, "cap/**")
        time.sleep(1.0)
        # The locator's estimate reaches the bridge and the laptop's tap.
        wait_for(
            lambda: locator.put(FIX, b"locator") or b"locator" in at_bridge.payloads(),
            timeout_s=10,
            what="the locator's estimate at the bridge",
        )
        wait_for(lambda: b"locator" in at_laptop.payloads(), timeout_s=5, what="laptop tap")
        # The laptop's puts on the estimate key, directly and through wildcards, never arrive.
        for key in (FIX, "cap/tank/topside/**", "cap/**", "cap/*/topside/locator/fix"):
            for _ in range(5):
                laptop.put(key, b"laptop")
                time.sleep(0.05)
        time.sleep(1.0)
        assert b"laptop" not in at_bridge.payloads()
        # The ROV's bridge may put its telemetry; it is not allowed to put estimates either.
        bridge.put(FIX, b"bridge-fix")
        bridge.put("cap/tank/rov/rov/depth", b"depth")
        wait_for(lambda: b"depth" in at_laptop.payloads(), timeout_s=5, what="ROV telemetry")
        time.sleep(0.5)
        # (A session hears its own puts locally; the router is what must refuse them.)
        assert b"bridge-fix" not in at_laptop.payloads()
        assert b"laptop" not in at_bridge.payloads()


def test_certificate_recipe_names_hosts_and_limits_client_certificates(tmp_path: Path) -> None:
    out = tmp_path / "site"
    subprocess.run(
        ["bash", str(SECURITY / "make-site-certs.sh"), str(out), "topside"],
        check=True,
        capture_output=True,
        timeout=60,
    )

    def text(name: str) -> str:
        return subprocess.run(
            ["openssl", "x509", "-in", str(out / f"{name}.pem"), "-noout", "-text"],
            check=True,
            capture_output=True,
            text=True,
        ).stdout

    router = text("capsd-router")
    # The topside locator connects to tls/localhost: the router must name it, and topside.
    for name in ("DNS:localhost", "IP Address:127.0.0.1", "DNS:topside"):
        assert name in router
    for client in ("capsd-asv", "capsd-locator", "capsd-rov", "capsd-laptop"):
        usage = text(client).split("Extended Key Usage:")[1].splitlines()[1]
        assert "Client Authentication" in usage
        assert "Server Authentication" not in usage
    key = out / "fix.key"
    assert key.stat().st_mode & 0o077 == 0
    assert len(bytes.fromhex(key.read_text().strip())) == 32


def _peak_rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise AssertionError(f"no VmHWM for {pid}")


def _attacker(endpoint: str, certs: Path | None, identity: str = "capsd-laptop") -> zenoh.Session:
    """A client configured by the attacker: zenoh's defaults (1 GiB messages), no capsd code."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", f'["{endpoint}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    if certs is not None:
        conf.insert_json5("transport/link/tls/root_ca_certificate", f'"{certs / "ca.pem"}"')
        conf.insert_json5("transport/link/tls/connect_certificate", f'"{certs / identity}.pem"')
        conf.insert_json5("transport/link/tls/connect_private_key", f'"{certs / identity}.key"')
        conf.insert_json5("transport/link/tls/enable_mtls", "true")
    return zenoh.open(conf)


def test_a_huge_denied_put_costs_the_router_nothing(
    secure_router_proc: tuple[str, Proc], certs: Path
) -> None:
    secure_router, router = secure_router_proc
    router_pid = router.popen.pid
    before_mb = _peak_rss_mb(router_pid)
    with _attacker(secure_router, certs) as laptop:
        laptop.put(FIX, bytes(300 * 1024 * 1024))  # read-only, and 150 x the message limit
        time.sleep(2.0)
    # (Measured before the message limit: 41 -> 328 MB; the unit's MemoryMax is 256M.)
    assert _peak_rss_mb(router_pid) - before_mb < 30.0
    with (
        open_session(_bus(secure_router, certs, "capsd-rov")) as bridge,
        open_session(_bus(secure_router, certs, "capsd-locator")) as locator,
    ):
        at_bridge = Inbox(bridge, FIX)
        wait_for(
            lambda: locator.put(FIX, b"locator") or b"locator" in at_bridge.payloads(),
            timeout_s=10,
            what="the site still working",
        )


def test_an_oversized_put_through_an_open_router_never_reaches_a_service(
    spawn: Callable[..., Proc], tmp_path: Path
) -> None:
    # BlueOS's router has zenoh's defaults: it forwards a 100 MB put. A capsd session (here
    # `capsd tap`, opened by the same code as every service) refuses it on arrival.
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", f'["{endpoint}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(conf):
        tap = spawn("tap", "cap/**", "--connect", endpoint)
        time.sleep(2.0)
        before_mb = _peak_rss_mb(tap.popen.pid)
        with _attacker(endpoint, None) as attacker:
            attacker.put("cap/tank/asv/sonar/frame", bytes(100 * 1024 * 1024))
            time.sleep(2.0)
            attacker.put("cap/tank/asv/sonar/frame", b"after")
            wait_for(lambda: "cap/tank/asv/sonar/frame" in tap.output(), timeout_s=10, what="tap")
        assert _peak_rss_mb(tap.popen.pid) - before_mb < 30.0
        assert tap.popen.poll() is None
        assert tap.output().count("cap/tank/asv/sonar/frame") == 1  # the small one only
