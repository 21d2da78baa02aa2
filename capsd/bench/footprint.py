"""`capsd bench footprint`: start-up time and resident memory of a service process.

Start-up is measured from `exec` to the service's READY=1 on a real sd_notify socket, the way
systemd sees it. Memory is VmRSS (and the peak VmHWM) from /proc after it has run a while. The
shared libraries the process has mapped show whether torch, scipy or OpenCV were loaded.
"""

from __future__ import annotations

import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

HEAVY = ("torch", "scipy", "cv2", "opencv")


@dataclass(frozen=True)
class Footprint:
    startup_s: float
    rss_mb: float
    peak_rss_mb: float
    heavy_libraries: tuple[str, ...]


def status_kb(pid: int, field: str) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return float(line.split()[1])
    raise KeyError(field)


def _heavy_mapped(pid: int) -> tuple[str, ...]:
    found = set()
    for line in Path(f"/proc/{pid}/maps").read_text().splitlines():
        path = line.split()[-1] if len(line.split()) >= 6 else ""
        for name in HEAVY:
            if f"/{name}" in path or f"{name}." in Path(path).name:
                found.add(name)
    return tuple(sorted(found))


def measure(args: list[str], *, settle_s: float, env: dict[str, str] | None = None) -> Footprint:
    """Run `python -m capsd ARGS`, time it to READY=1, then read its memory and mappings."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "notify.sock")
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as server:
            server.bind(path)
            server.settimeout(30.0)
            start = time.monotonic()
            proc = subprocess.Popen(
                [sys.executable, "-m", "capsd", *args],
                env={**os.environ, **(env or {}), "NOTIFY_SOCKET": path},
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            try:
                while b"READY=1" not in server.recv(4096):
                    pass
                startup = time.monotonic() - start
                time.sleep(settle_s)
                rss = status_kb(proc.pid, "VmRSS") / 1024
                peak = status_kb(proc.pid, "VmHWM") / 1024
                heavy = _heavy_mapped(proc.pid)
            finally:
                proc.terminate()
                proc.wait(timeout=10)
    return Footprint(startup, rss, peak, heavy)


def bridge(*, runs: int, settle_s: float) -> int:
    """Footprint of the MAVLink bridge against the autopilot stand-in and a local router."""
    from capsd.bus import open_session
    from capsd.config import BusConfig
    from capsd.signing import SiteKey, write_key
    from capsd.simulator.autopilot import CONFIGURED_PARAMS, AutopilotStandIn

    def free_port() -> int:
        with socket.socket() as sock:
            sock.bind(("127.0.0.1", 0))
            return int(sock.getsockname()[1])

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router_bus = BusConfig(mode="router", connect=(), listen=(endpoint,))
    results = []
    with (
        open_session(router_bus),
        AutopilotStandIn(free_port(), params=CONFIGURED_PARAMS) as autopilot,
        tempfile.TemporaryDirectory() as tmp,
    ):
        config = Path(tmp) / "bridge.yaml"
        key = Path(tmp) / "fix.key"
        write_key(key, SiteKey.generate())
        config.write_text(
            f"bus:\n  connect: [{endpoint}]\nmavlink:\n  connect: tcp:127.0.0.1:{autopilot.port}\n"
            f"fix_key: {key}\n"
        )
        for i in range(runs):
            result = measure(["run", "mav_bridge", "--config", str(config)], settle_s=settle_s)
            results.append(result)
            print(
                f"run {i + 1}/{runs}: start-up {result.startup_s * 1000:.0f} ms, "
                f"RSS {result.rss_mb:.1f} MB (peak {result.peak_rss_mb:.1f} MB), "
                f"heavy libraries: {', '.join(result.heavy_libraries) or 'none'}",
                flush=True,
            )
    startup = statistics.median(r.startup_s for r in results)
    rss = statistics.median(r.rss_mb for r in results)
    peak = max(r.peak_rss_mb for r in results)
    heavy = sorted({name for r in results for name in r.heavy_libraries})
    print()
    print(f"{'mav_bridge':<12} {'measured':>12} {'target':>10}")
    print(f"{'start-up':<12} {startup * 1000:>9.0f} ms {'< 1000 ms':>10}  (median of {runs})")
    print(f"{'RSS':<12} {rss:>9.1f} MB {'<= 80 MB':>10}  (median; peak {peak:.1f} MB)")
    print(f"{'torch/scipy/cv2':<12} {', '.join(heavy) or 'none':>12} {'none':>10}")
    ok = startup < 1.0 and rss <= 80.0 and not heavy
    print("all targets met" if ok else "TARGET MISSED")
    return 0 if ok else 1
