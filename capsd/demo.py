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
import sys
import time
from pathlib import Path
from typing import Any, Literal, TextIO

import numpy as np

from capsd.accuracy import HEADER, Accuracy, row
from capsd.bus import open_session
from capsd.codec import Codec
from capsd.config import BusConfig
from capsd.errors import CapsdError
from capsd.harness import (
    FOLLOW_SERVICES,
    SERVICES,
    AsvMode,
    Processes,
    SonarTilt,
    Watch,
    detector_settings_of,
    free_port,
    sigterm_as_interrupt,
    start_service,
    start_station,
    write_configs,
)
from capsd.mission.plan import Waypoint
from capsd.mounts import AsvDrive
from capsd.payloads import Health
from capsd.simulator.world import TankName, TrajectoryName

# How long the recorder may take to write its backlog and finish the file once stopped.
RECORDER_STOP_GRACE_S = 120.0


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


def _drawn_errors(sim_config: Path) -> dict[str, float]:
    """The installation errors the demo's simulator drew (as the accuracy bench reports them)."""
    import msgspec
    import yaml

    from capsd.simulator.config import Config as SimConfig
    from capsd.simulator.sim import Simulation

    data = yaml.safe_load(sim_config.read_text()) or {}
    config = msgspec.convert({k: v for k, v in data.items() if k != "bus"}, SimConfig)
    return Simulation(config, horizon_s=10.0).errors.summary()


def main(
    *,
    duration_s: float,
    out: Path,
    trajectory: TrajectoryName,
    tank: TankName,
    seed: int,
    port: int | None,
    record: Path | None = None,
    record_view: Literal["on", "off"] = "on",
    mission: Path | None = None,
    asv: AsvMode = "station",
    asv_drive: AsvDrive = "steered",
    sonar_tilt: SonarTilt = "fixed",
    install_errors: Literal["realistic", "off"] = "realistic",
    calibration: Literal["off", "dive"] = "off",
    detector_config: Path | None = None,
    stream: TextIO = sys.stdout,
) -> int:
    """Run the demo; returns 0 when every service ran to the end and fixes were good.

    With `mission` (a plan file) the loop is closed: the ROV starts at the plan's first
    waypoint and is flown by the ArduSub stand-in the simulator hosts, `capsd mission run`
    commands it through the bridge, and the demo ends when the mission does. With `asv`
    "follow" the ASV is driven too: the follower's targets through the ASV's bridge to the
    ArduRover stand-in the simulator hosts (`asv_drive`: how it moves, AsvDrive; `sonar_tilt`
    "servo": the sonar on a tilt servo the follower drives through it, "pan-tilt": on a pan
    servo too); "station" keeps it where it starts. With
    `install_errors` "realistic" (the default) the simulated installation is what a tape
    measured (docs/INSTALL-ERRORS.md), uncalibrated unless `calibration` is "dive" (first a
    simulated calibration dive fitted by capsd calibrate's code, as a field team starts);
    "off" a perfect one. `detector_config`: a sonar_detect config whose detector settings
    (harness.DETECTOR_KEYS, the depth gate's GATE_KEYS) the detection service runs with
    instead of its defaults. `record_view`: whether the recording also holds the operator's
    scene (capsd record --view).
    """
    from capsd import plots

    out.mkdir(parents=True, exist_ok=True)
    logs = out / "logs"
    logs.mkdir(exist_ok=True)
    router_port = port or free_port()
    mav_port = free_port()
    endpoint = f"tcp/127.0.0.1:{router_port}"
    if sonar_tilt != "fixed" and asv != "follow":
        raise CapsdError(
            f"--sonar-tilt {sonar_tilt} needs --asv follow: the follower drives the servo"
        )
    if asv == "follow" and mission is None:
        raise CapsdError("--asv follow needs --mission: the ASV follows a ROV flown live")
    if calibration == "dive" and install_errors != "realistic":
        raise CapsdError(
            "--calibration dive calibrates a realistic installation: not with --install-errors off"
        )
    detector_settings = None if detector_config is None else detector_settings_of(detector_config)
    points = None if mission is None else _plan_points(mission, tank)
    rov_start, station, heading = (
        (None, None, None) if points is None else _mission_start(points, tank, asv)
    )
    configs = write_configs(
        logs,
        endpoint,
        trajectory=trajectory,
        tank=tank,
        seed=seed,
        mav_port=mav_port,
        rov_start_m=rov_start,
        asv_station_xy=station,
        asv_station_heading_deg=heading,
        asv=asv,
        asv_mav_port=free_port() if asv == "follow" else None,
        asv_drive=asv_drive,
        sonar_tilt=sonar_tilt,
        install_errors=install_errors,
        calibration=calibration,
        detector_settings=detector_settings,
    )
    calibrated = (
        json.loads((logs / "calibration.json").read_text()) if calibration == "dive" else None
    )
    follow = FOLLOW_SERVICES if asv == "follow" else ()
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
    with sigterm_as_interrupt():  # a kill stops the children as Ctrl-C does
        try:
            procs.start("router", ["-m", "capsd", "router", "--listen", endpoint])
            if mission is None:  # with a mission the simulator hosts the stand-in (it flies it)
                stand_in = ["-m", "capsd.simulator.autopilot", "--port", str(mav_port)]
                procs.start("autopilot", stand_in)
            if record is not None:
                # Started first and stopped last: the recording holds each service's whole life.
                args = ["cap/**", "-o", str(record), "--exclude", "cap/*/*/sonar/frame",
                        "--locator-config", str(configs["locator"]),
                        "--view", record_view]  # fmt: skip
                # Its backlog (the scene's, on a busy machine) is written and the file
                # finished before it exits: a killed recorder leaves no summary.
                procs.start("recorder", ["-m", "capsd", "record", *args, "--connect", endpoint],
                            stop_grace_s=RECORDER_STOP_GRACE_S)  # fmt: skip
            time.sleep(1.0)
            for _, name in SERVICES:
                start_service(procs, name, configs[name])
            for _, name, service in follow:
                start_service(procs, name, configs[name], service=service)
            if mission is not None:
                procs.start(
                    "mission",
                    ["-m", "capsd", "mission", "run", str(mission), "--config",
                     str(configs["mission"]), "--locator-config", str(configs["locator"]),
                     "--out", str(out / "mission")],
                )  # fmt: skip
            with open_session(BusConfig(connect=(endpoint,))) as session:
                watch = Watch(session, extra=follow)
                t0 = time.monotonic()
                try:
                    while time.monotonic() - t0 < duration_s:
                        time.sleep(2.0)
                        health = watch.health()
                        print(_line(time.monotonic() - t0, watch, health), file=stream, flush=True)
                        dead = [d for d in procs.dead() if d not in ("autopilot", "recorder")]
                        if dead == ["mission"]:
                            print("capsd demo: the mission ended", file=stream)
                            break
                        if dead:
                            print(f"capsd demo: stopped early, exited: {dead}", file=stream)
                            break
                except KeyboardInterrupt:
                    interrupted = True
                health = watch.health()
                watch.close()
        finally:
            codes = procs.stop()
    elapsed = time.monotonic() - started
    autopilot_log = logs / "autopilot.log"
    autopilot = (
        autopilot_log.read_text(errors="replace").strip()
        if autopilot_log.exists()
        else "(hosted by the simulator: it flies the ROV)"
    )
    mission_json = out / "mission" / "mission.json"
    mission_figures = json.loads(mission_json.read_text()) if mission_json.exists() else None
    if points is not None and watch is not None and mission_figures is not None:
        mission_figures["truth"] = _flown_against_plan(points, watch.accuracy)
        mission_figures["asv"] = {"mode": asv, **_asv_against_walls(watch.asv_xy, tank)}
    accuracy = watch.accuracy if watch is not None else Accuracy()
    summary = accuracy.summary()
    installation = _drawn_errors(configs["sim"]) if install_errors == "realistic" else {}
    figures = {
        "tank": tank,
        "trajectory": trajectory,
        "seed": seed,
        "install_errors": installation,
        "calibration": calibrated,
        "detector_settings": detector_settings,
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
        "mission": mission_figures,
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
        f"Installation errors: {install_errors}"
        + (
            " (drawn from the seed, unknown to the services, "
            + ("calibrated by a simulated dive" if calibrated else "uncalibrated")
            + ": "
            + ", ".join(f"{k} {v}" for k, v in installation.items())
            + ")"
            if installation
            else ""
        ),
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
    if mission_figures is not None:
        lines += ["## Mission", "", "```", json.dumps(mission_figures, indent=1), "```", ""]
        lines += ["![mission](mission/mission.png)", ""]
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
    if mission_figures is not None:
        truth = mission_figures["truth"]
        print(
            f"mission {mission_figures['mission']}: {mission_figures['state']}, "
            f"{mission_figures['waypoint_reached']} of {mission_figures['waypoints']} "
            f"waypoints, pauses {mission_figures['pauses']}; the true path against the plan: "
            f"cross-track rms {truth['cross_track_rms_m']} m, p95 {truth['cross_track_p95_m']} "
            f"m, good fixes {truth['availability']} of pings while flying",
            file=stream,
        )
        walls = mission_figures["asv"]
        print(
            f"ASV ({asv}): moved {walls['travelled_m']} m, nearest a wall "
            f"{walls['min_wall_distance_m']} m (its origin)",
            file=stream,
        )
    print(f"report: {out}/summary.md (figures.json, 3 PNGs, logs/)", file=stream, flush=True)
    expected = ["sim", "asv_pose", "sonar_detect", "locator", "mav_bridge"]
    expected += [name for _, name, _ in follow]
    services_ok = all(codes.get(name) == 0 for name in expected)
    if record is not None and codes.get("recorder") != 0:
        # A recording that failed is no recording: say so, and fail (its log says why).
        print(f"capsd demo: the recorder exited {codes.get('recorder')}: see "
              f"{logs}/recorder.log", file=stream, flush=True)  # fmt: skip
        services_ok = False
    if mission is not None and codes.get("mission") != 0:
        print(f"capsd demo: the mission exited {codes.get('mission')}: see {logs}/mission.log",
              file=stream, flush=True)  # fmt: skip
        services_ok = False
    if interrupted:
        print("capsd demo: stopped by user", file=stream, flush=True)
        return 0 if services_ok else 1
    return 0 if services_ok and summary.get("good", 0) > 0 else 1


def _plan_points(plan_path: Path, tank: TankName) -> list[Waypoint]:
    """The plan's waypoints, checked against the simulated tank's walls."""
    from capsd.mission.plan import load_plan
    from capsd.simulator.world import make_tank, tank_bounds

    return load_plan(plan_path, tank=tank_bounds(make_tank(tank)))[1]


def _mission_start(
    points: list[Waypoint], tank: TankName, asv: AsvMode
) -> tuple[tuple[float, float, float], tuple[float, float], float | None]:
    """Where the ROV starts (the plan's first waypoint) and where the ASV starts (and faces).

    As a pilot would place it to see the ROV's start, with the follower's station planner
    (walls, hull, aperture). A stationary ASV stays there, turned toward the start (the
    simulator's rule); a following one starts on the planner's heading.
    """
    start = points[0].position_m
    chosen = start_station(tank, start)
    if chosen is None:
        raise CapsdError(f"no ASV station in the {tank} tank sees the plan's start {start}")
    xy, heading = chosen
    return start, xy, heading if asv == "follow" else None


def _flown_against_plan(points: list[Waypoint], accuracy: Accuracy) -> dict[str, Any]:
    """The simulator's truth against the plan, from when the ROV first left its start.

    Cross-track is the distance to the nearest leg of the plan (the truth does not know which
    leg the mission was on); availability is the share of pings with a good fix meanwhile.
    """
    from capsd.mission.plan import cross_track_m

    legs = np.array([w.position_m for w in points])
    pings = sorted(accuracy.pings, key=lambda p: p.stamp_ns)
    start = legs[0]
    left = next(
        (i for i, p in enumerate(pings) if np.linalg.norm(np.subtract(p.truth_m, start)) > 0.05),
        len(pings),
    )
    flying = pings[left:]

    def to_plan(position: np.ndarray) -> float:
        if len(legs) == 1:
            return float(np.linalg.norm(position - start))
        return min(cross_track_m(position, legs[k], legs[k + 1]) for k in range(len(legs) - 1))

    distances = np.array([to_plan(np.array(p.truth_m)) for p in flying])
    good = sum(1 for p in flying if p.estimate_m is not None)
    return {
        "pings": len(flying),
        "availability": round(good / len(flying), 4) if flying else None,
        "cross_track_rms_m": round(float(np.sqrt(np.mean(distances**2))), 4)
        if len(flying)
        else None,
        "cross_track_p95_m": round(float(np.percentile(distances, 95)), 4) if len(flying) else None,
        "cross_track_max_m": round(float(distances.max()), 4) if len(flying) else None,
    }


def _asv_against_walls(asv_xy: list[tuple[float, float]], tank: TankName) -> dict[str, Any]:
    """How close the ASV's true position came to a wall, and how far it went."""
    from capsd.simulator.world import make_tank

    if not asv_xy:
        return {"min_wall_distance_m": None, "travelled_m": None}
    t = make_tank(tank)
    xy = np.array(asv_xy)
    walls = np.minimum.reduce([xy[:, 0], t.length_m - xy[:, 0], xy[:, 1], t.width_m - xy[:, 1]])
    steps = np.linalg.norm(np.diff(xy, axis=0), axis=1) if len(xy) > 1 else np.zeros(1)
    return {
        "min_wall_distance_m": round(float(walls.min()), 3),
        "travelled_m": round(float(steps.sum()), 2),
    }


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
