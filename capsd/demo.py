"""`capsd demo`: the whole system on the simulated tank, each part its own process, and a report.

Started on 127.0.0.1 (free ports unless given): a Zenoh router, the simulator (sonar images,
LiDAR, IMU, ROV depth/attitude, truth labels), asv_pose, sonar_detect, locator, mav_bridge and
an ArduSub stand-in for the bridge (MAVLink over TCP). Nothing is taken from truth: the
simulator's stand-in streams are off, the pose service gets only a heading prior. While it runs
a line every 2 s shows the fix error against truth, the rates and each service's health; after
`duration_s` (or Ctrl-C) everything is stopped with SIGTERM and the report folder is written:
summary.md (the accuracy table, services, what reached the autopilot), figures.json, the
3D / per-axis / error PNGs and every process's log.
"""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import zenoh

from capsd import topics
from capsd.accuracy import HEADER, Accuracy, LivePairing, row
from capsd.bus import open_session
from capsd.codec import Codec
from capsd.config import BusConfig
from capsd.errors import PayloadError
from capsd.health import query_health
from capsd.keys import is_concrete
from capsd.payloads import Health, RovFix, SonarLabel
from capsd.simulator.world import TankName, TrajectoryName

SERVICES = (
    ("sim", "sim"),
    ("asv", "asv_pose"),
    ("asv", "sonar_detect"),
    ("topside", "locator"),
    ("rov_ap", "mav_bridge"),
)


SIM_NICENESS = 10


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@dataclass
class Child:
    name: str
    popen: subprocess.Popen[bytes]
    log: Path


class Processes:
    """Children started with their logs in the report folder; stopped in reverse order."""

    def __init__(self, logs: Path):
        self.logs = logs
        self.children: list[Child] = []

    def start(self, name: str, args: list[str], *, niceness: int = 0) -> Child:
        """Start `python ARGS`; `niceness` > 0 lets it have only what the others leave."""
        log = self.logs / f"{name}.log"
        command = [sys.executable, *args]
        if niceness:
            command = ["nice", "-n", str(niceness), *command]
        with log.open("wb") as out:
            # A session of its own: Ctrl-C in the terminal reaches only the demo, which then
            # stops every child cleanly (SIGTERM, exit 0) in order.
            popen = subprocess.Popen(
                command,
                stdout=out,
                stderr=subprocess.STDOUT,
                cwd=os.getcwd(),
                start_new_session=True,
            )
        child = Child(name, popen, log)
        self.children.append(child)
        return child

    def stop(self) -> dict[str, int | None]:
        codes: dict[str, int | None] = {}
        for child in reversed(self.children):
            if child.popen.poll() is None:
                child.popen.send_signal(signal.SIGTERM)
        for child in reversed(self.children):
            try:
                codes[child.name] = child.popen.wait(timeout=10)
            except subprocess.TimeoutExpired:
                child.popen.kill()
                codes[child.name] = child.popen.wait()
        return codes

    def dead(self) -> list[str]:
        return [c.name for c in self.children if c.popen.poll() is not None]


def _write_configs(
    folder: Path,
    endpoint: str,
    *,
    trajectory: TrajectoryName,
    tank: TankName,
    seed: int,
    mav_port: int,
    sonar_hz: float = 20.0,
) -> dict[str, Path]:
    import msgspec
    import yaml

    from capsd.geometry import matrix_to_euler_zyx
    from capsd.signing import SiteKey, write_key
    from capsd.simulator.config import Config as SimConfig
    from capsd.simulator.sim import Simulation
    from capsd.simulator.world import tank_bounds

    bus = {"connect": [endpoint]}
    # The site's fix key: the locator signs, the bridge checks (as deployed).
    fix_key = folder / "fix.key"
    if not fix_key.exists():
        write_key(fix_key, SiteKey.generate())
    sim = {
        "bus": bus,
        "tank": tank,
        "trajectory": trajectory,
        "seed": seed,
        "streams": {"detections_truth_noise": "off", "asv_pose_truth_noise": "off"},
        "rates": {"sonar_hz": sonar_hz},
    }
    run = SimConfig(tank=tank, trajectory=trajectory, seed=seed)
    start = Simulation(run, horizon_s=10)
    # The person putting the ASV in the water knows roughly which way it points: 20 deg off.
    heading = math.degrees(matrix_to_euler_zyx(start.asv_pose(0.0).rotation)[0]) + 20.0
    t = run.world_tank()
    tank_box = {"length_m": t.length_m, "width_m": t.width_m}
    configs = {
        "sim": sim,
        "asv_pose": {
            "bus": bus,
            "heading_prior_deg": round(heading, 1),
            "tank_length_m": t.length_m,
            "tank_width_m": t.width_m,
        },
        "sonar_detect": {"bus": bus},
        "locator": {
            "bus": bus,
            # The tank as a site would describe it: its box and fixtures (the view draws them).
            "tank": msgspec.to_builtins(tank_bounds(t)),
            "fix_key": str(fix_key),
        },
        "mav_bridge": {
            "vehicle": "rov_ap",
            "bus": bus,
            "mavlink": {"connect": f"tcp:127.0.0.1:{mav_port}"},
            "fix_key": str(fix_key),
            "tank": {**tank_box, "depth_m": t.depth_m},
        },
    }
    paths = {}
    for name, body in configs.items():
        path = folder / f"{name}.yaml"
        path.write_text(yaml.safe_dump(body, sort_keys=False))
        paths[name] = path
    return paths


def decoder(
    codec: Codec[Any],
    sink: Callable[[Any], None],
    *,
    on_error: Callable[[], None] = lambda: None,
) -> Callable[[zenoh.Sample], None]:
    """A Zenoh callback that decodes each concrete-keyed sample into `sink` (bad ones: on_error)."""

    def on_sample(sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        if not is_concrete(key):
            return
        try:
            value = codec.decode(
                sample.payload.to_bytes(), encoding=str(sample.encoding), key_expr=key
            )
        except PayloadError:
            on_error()
            return
        sink(value)

    return on_sample


def start_service(procs: Processes, name: str, config: Path) -> Child:
    """`capsd run NAME --config CONFIG` as a child; the simulator niced.

    It stands in for sensors with processors of their own: it renders ahead and yields the CPU
    to the system it feeds (its lateness is measured).
    """
    return procs.start(
        name,
        ["-m", "capsd", "run", name, "--config", str(config)],
        niceness=SIM_NICENESS if name == "sim" else 0,
    )


class Watch:
    """The demo's own Zenoh client: fixes and labels paired, health polled."""

    def __init__(self, session: zenoh.Session):
        self.session = session
        self.accuracy = Accuracy()
        self.pairing = LivePairing(self.accuracy)
        self.decode_errors = 0
        self._subs = [
            session.declare_subscriber(
                topics.ROV_FIX.key("tank", "topside"), self._decoder(Codec(RovFix), self._on_fix)
            ),
            session.declare_subscriber(
                topics.SIM_LABEL.key("tank", "sim"),
                self._decoder(Codec(SonarLabel), self.pairing.add_label),
            ),
        ]

    def _decoder(self, codec: Codec[Any], sink: Any) -> Any:
        def on_error() -> None:
            self.decode_errors += 1  # reported in the summary; the services count theirs

        return decoder(codec, sink, on_error=on_error)

    def _on_fix(self, fix: RovFix) -> None:
        self.pairing.add_fix(fix)

    def health(self) -> dict[str, Health | None]:
        return {
            service: query_health(
                self.session, site="tank", vehicle=vehicle, service=service, timeout_s=0.5
            )
            for vehicle, service in SERVICES
        }

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()


def _line(elapsed: float, watch: Watch, health: dict[str, Health | None]) -> str:
    s = watch.accuracy.summary()
    med = f"{s['med_mm']:.1f} mm" if "med_mm" in s else "-"
    avail = f"{100 * s['availability']:.1f}%" if s.get("availability") is not None else "-"
    states = " ".join(f"{name}:{h.state if h else 'silent'}" for name, h in health.items())
    bridge = health.get("mav_bridge")
    sent = bridge.counters.get("gate_sent", 0) if bridge else 0
    return (
        f"[{elapsed:5.0f} s] pings {s['pings']:5d} good {avail:>6} MED {med:>9}  "
        f"VPE sent {sent:5d}  {states}"
    )


def main(
    *,
    duration_s: float,
    out: Path,
    trajectory: TrajectoryName,
    tank: TankName,
    seed: int,
    port: int | None,
    record: Path | None = None,
    stream: TextIO = sys.stdout,
) -> int:
    """Run the demo; returns 0 when every service ran to the end and fixes were good."""
    from capsd import plots

    out.mkdir(parents=True, exist_ok=True)
    logs = out / "logs"
    logs.mkdir(exist_ok=True)
    router_port = port or _free_port()
    mav_port = _free_port()
    endpoint = f"tcp/127.0.0.1:{router_port}"
    configs = _write_configs(
        logs, endpoint, trajectory=trajectory, tank=tank, seed=seed, mav_port=mav_port
    )
    procs = Processes(logs)
    started = time.monotonic()
    health: dict[str, Health | None] = {}
    interrupted = False
    watch: Watch | None = None
    print(
        f"capsd demo: {tank}/{trajectory}, {duration_s:g} s, router {endpoint}, report {out}",
        file=stream,
        flush=True,
    )
    try:
        procs.start("router", ["-m", "capsd", "router", "--listen", endpoint])
        procs.start("autopilot", ["-m", "capsd.simulator.autopilot", "--port", str(mav_port)])
        if record is not None:
            # Started first and stopped last: the recording holds each service's whole life.
            args = ["cap/**", "-o", str(record), "--exclude", "cap/*/*/sonar/frame",
                    "--locator-config", str(configs["locator"])]  # fmt: skip
            procs.start("recorder", ["-m", "capsd", "record", *args, "--connect", endpoint])
        time.sleep(1.0)
        for _, name in SERVICES:
            start_service(procs, name, configs[name])
        with open_session(BusConfig(connect=(endpoint,))) as session:
            watch = Watch(session)
            t0 = time.monotonic()
            try:
                while time.monotonic() - t0 < duration_s:
                    time.sleep(2.0)
                    health = watch.health()
                    print(_line(time.monotonic() - t0, watch, health), file=stream, flush=True)
                    if dead := [d for d in procs.dead() if d not in ("autopilot", "recorder")]:
                        print(f"capsd demo: stopped early, exited: {dead}", file=stream)
                        break
            except KeyboardInterrupt:
                interrupted = True
            health = watch.health()
            watch.close()
    finally:
        codes = procs.stop()
    elapsed = time.monotonic() - started
    autopilot = (logs / "autopilot.log").read_text(errors="replace").strip()
    accuracy = watch.accuracy if watch is not None else Accuracy()
    summary = accuracy.summary()
    figures = {
        "tank": tank,
        "trajectory": trajectory,
        "seed": seed,
        "duration_s": duration_s,
        "wall_s": round(elapsed, 1),
        "interrupted": interrupted,
        "accuracy": summary,
        "exit_codes": codes,
        "health": {
            k: (None if h is None else json.loads(Codec(Health).encode(h)))
            for k, h in health.items()
        },
        "autopilot": autopilot,
        "watch_decode_errors": watch.decode_errors if watch is not None else 0,
    }
    (out / "figures.json").write_text(json.dumps(figures, indent=1, sort_keys=True) + "\n")
    runs = {"CAP-SD (live)": accuracy}
    title = f"{tank}/{trajectory} live demo"
    plots.trajectory_3d(runs, out / "trajectory_3d.png", title=title)
    plots.per_axis(runs, out / "position_axes.png", title=title)
    plots.error_histograms(runs, out / "errors.png", title=title)
    lines = [
        f"# CAP-SD demo: {tank}/{trajectory}, {duration_s:g} s",
        "",
        "Every service its own process on 127.0.0.1 over Zenoh; errors against the simulator's "
        "truth of what the autopilot is sent.",
        "",
        HEADER,
        row(f"{tank}/{trajectory} live", summary),
        "",
        "## Services at the end",
        "",
        "| service | state | exit code | last error (when) |",
        "|---|---|---:|---|",
    ]
    for name, h in health.items():
        lines.append(f"| {name} | {h.state if h else '-'} | {codes.get(name)} | {_last_error(h)} |")
    lines += ["", "## Autopilot stand-in", "", "```", autopilot, "```", ""]
    lines += [
        "![trajectory](trajectory_3d.png)",
        "",
        "![axes](position_axes.png)",
        "",
        "![errors](errors.png)",
        "",
    ]
    (out / "summary.md").write_text("\n".join(lines))
    print("", file=stream)
    print(HEADER, file=stream)
    print(row(f"{tank}/{trajectory} live", summary), file=stream)
    print(autopilot, file=stream)
    print(f"report: {out}/summary.md (figures.json, 3 PNGs, logs/)", file=stream, flush=True)
    services_ok = all(
        codes.get(name) == 0
        for name in ("sim", "asv_pose", "sonar_detect", "locator", "mav_bridge")
    )
    if record is not None and codes.get("recorder") != 0:
        # A recording that failed is no recording: say so, and fail (its log says why).
        print(f"capsd demo: the recorder exited {codes.get('recorder')}: see "
              f"{logs}/recorder.log", file=stream, flush=True)  # fmt: skip
        services_ok = False
    if interrupted:
        print("capsd demo: stopped by user", file=stream, flush=True)
        return 0 if services_ok else 1
    return 0 if services_ok and summary.get("good", 0) > 0 else 1


def _last_error(health: Health | None) -> str:
    """The last error, whole words only, and how long before the end it was."""
    if health is None:
        return "no answer"
    if not health.last_error:
        return ""
    text = health.last_error
    if len(text) > 90:
        text = text[:90].rsplit(" ", 1)[0] + " ..."
    if health.last_error_stamp_ns is not None:
        ago = max(0.0, (health.stamp_ns - health.last_error_stamp_ns) / 1e9)
        text += f" ({ago:.0f} s before the end)"
    return text.replace("|", "/")
