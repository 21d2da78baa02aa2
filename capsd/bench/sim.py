"""`capsd bench sim`: the simulator in real time, as its own process, stream by stream.

Starts a router and `capsd sim` (one process: its sensor work runs on one thread), lets it
warm up, then reads its Health counters twice `duration` seconds apart: the achieved rate and
the CPU share of each stream come from the differences, the process's total CPU from /proc.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import zenoh

from capsd.bus import open_session
from capsd.config import BusConfig
from capsd.health import query_health
from capsd.payloads import Health

_TICKS = os.sysconf("SC_CLK_TCK")


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / _TICKS


def _health(session: zenoh.Session) -> Health:
    health = query_health(session, site="tank", vehicle="sim", service="sim")
    if health is None:
        raise RuntimeError("the simulator did not answer its health query")
    return health


def run(*, tank: str, trajectory: str, duration_s: float, warmup_s: float) -> int:
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{sock.getsockname()[1]}"
    router = BusConfig(mode="router", connect=(), listen=(endpoint,))
    targets = {
        "sonar/frame": 20.0,
        "asv/imu": 200.0,
        "asv/scan": 15.0,
        "asv/pose": 50.0,
        "rov/depth": 10.0,
        "rov/attitude": 20.0,
        "sim/label": 20.0,
        "sim/truth": 20.0,
        "sonar/detections": 20.0,
    }
    with open_session(router) as session:
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "capsd",
                "sim",
                "--tank",
                tank,
                "--trajectory",
                trajectory,
                "--connect",
                endpoint,
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            print(
                f"simulating {tank}/{trajectory}: warming up {warmup_s:g} s, then measuring "
                f"{duration_s:g} s",
                flush=True,
            )
            time.sleep(warmup_s)
            first, cpu0, t0 = _health(session), _cpu_s(proc.pid), time.monotonic()
            for left in range(int(duration_s), 0, -5):
                time.sleep(min(5, left))
                print(f"  measuring... {max(left - 5, 0)} s left", flush=True)
            second, cpu1, t1 = _health(session), _cpu_s(proc.pid), time.monotonic()
        finally:
            proc.terminate()
            proc.wait(timeout=10)
    elapsed = t1 - t0
    before, after = first.counters, second.counters
    streams = sorted({k.split(":")[0] for k in after if k.endswith(":count")})
    print()
    print(f"{'stream':<24} {'target Hz':>9} {'achieved Hz':>11} {'CPU %':>7} {'late max ms':>11}")
    ok = True
    for stream in streams:
        count = after[f"{stream}:count"] - before.get(f"{stream}:count", 0)
        cpu = (after[f"{stream}:cpu_us"] - before.get(f"{stream}:cpu_us", 0)) / 1e6
        rate = count / elapsed
        target = targets.get(stream.split("@")[0], 0.0)
        ok &= target == 0.0 or rate >= 0.95 * target
        print(
            f"{stream:<24} {target:>9.0f} {rate:>11.1f} {100 * cpu / elapsed:>6.1f}% "
            f"{after.get(f'{stream}:late_max_ms', 0):>11}"
        )
    total = 100 * (cpu1 - cpu0) / elapsed
    print(f"{'process total':<24} {'':>9} {'':>11} {total:>6.1f}%   (target: one core, <= 100%)")
    ok &= total <= 100.0
    print("all streams at rate on one core" if ok else "TARGET MISSED")
    return 0 if ok else 1
