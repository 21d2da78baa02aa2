"""The pipeline harness: the system's processes on 127.0.0.1, their configs, a watching client.

Shared by `capsd demo`, the latency and fault benches and `capsd replay-check`: a router, the
simulator and the four services each started as `capsd run NAME --config FILE` (as systemd does),
children stopped with SIGTERM on every path, and a Zenoh client that pairs fixes with truth
labels and polls each service's Health.
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import socket
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import zenoh

from capsd import topics
from capsd.accuracy import Accuracy, LivePairing
from capsd.codec import Codec
from capsd.errors import PayloadError
from capsd.health import query_health
from capsd.keys import is_concrete
from capsd.mounts import AsvDrive, SonarMountConfig
from capsd.payloads import GroundTruth, Health, RovFix, SonarLabel
from capsd.simulator.world import TankName, TrajectoryName

if TYPE_CHECKING:
    from capsd.services.asv_follow.service import Config as FollowConfig

SERVICES = (
    ("sim", "sim"),
    ("asv", "asv_pose"),
    ("asv", "sonar_detect"),
    ("topside", "locator"),
    ("rov_ap", "mav_bridge"),
)


# With the ASV following (`--asv follow`): its bridge and the follower, besides SERVICES.
FOLLOW_SERVICES = (
    ("asv", "asv_bridge", "mav_bridge"),
    ("topside", "asv_follow", "asv_follow"),
)
AsvMode = Literal["station", "follow"]

SIM_NICENESS = 10


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Meanwhile SIGTERM raises KeyboardInterrupt: a harness stopped by a kill stops its children.

    They run in sessions of their own (Ctrl-C reaches only the harness) and would be left.
    """

    def interrupt(_signum: int, _frame: object) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@dataclass
class Child:
    name: str
    popen: subprocess.Popen[bytes]
    log: Path
    stop_grace_s: float = 10.0  # after SIGTERM, this long to exit before it is killed


class Processes:
    """Children started with their logs in the report folder; stopped in reverse order."""

    def __init__(self, logs: Path):
        self.logs = logs
        self.children: list[Child] = []

    def start(
        self, name: str, args: list[str], *, niceness: int = 0, stop_grace_s: float = 10.0
    ) -> Child:
        """Start `python ARGS`; `niceness` > 0 lets it have only what the others leave.

        `stop_grace_s`: how long `stop` waits for it after SIGTERM before killing it (a
        recorder finishing its file needs longer than a service).
        """
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
        child = Child(name, popen, log, stop_grace_s)
        self.children.append(child)
        return child

    def stop(self) -> dict[str, int | None]:
        codes: dict[str, int | None] = {}
        for child in reversed(self.children):
            if child.popen.poll() is None:
                child.popen.send_signal(signal.SIGTERM)
        for child in reversed(self.children):
            try:
                codes[child.name] = child.popen.wait(timeout=child.stop_grace_s)
            except subprocess.TimeoutExpired:
                child.popen.kill()
                codes[child.name] = child.popen.wait()
        return codes

    def dead(self) -> list[str]:
        return [c.name for c in self.children if c.popen.poll() is not None]


# The follower's stations where the defaults (a 1.2 m ASV, ROV 2-15 m off, on the boresight)
# do not fit: the mockup (4.8 x 3.6 m) takes a small ASV (0.6 m across) and near ranges. In the
# nfp tank the ROV 4 m deep sits on the boresight 8.4 m off, and a ROV flying away from the
# ASV rises above it (p90 +2.4 deg, `capsd bench follow`) to 8-9 m, where the detector misses
# most (docs/JOURNAL.md, session 40): aimed 3 deg below the boresight, 7.7 m off, the upward
# tail stays below the boresight (p90 -1 deg), 3 deg of margin still to the lower edge.
FOLLOW_STATION: dict[str, dict[str, float]] = {
    "nfp": {"target_elevation_deg": -3.0},
    "mockup": {
        "min_range_m": 1.0,
        "max_range_m": 6.0,
        "hull_radius_m": 0.3,
        "tracking_margin_m": 0.2,
    },
}


# The sonar's mount where the default (30 deg down) does not fit the tank: in the mockup a ROV
# 1 m deep sits mid aperture 1.4 m off, further than the ASV can keep from it 1.5 m off the
# walls; pitched 45 deg down, 0.8 m.
SONAR_PITCH_DEG: dict[str, float] = {"mockup": 45.0}

# fixed: the sonar bolted to the hull; servo: on a tilt servo the follower drives (the mount's
# `tilt`, its default range and rate: capsd.mounts.SonarTiltConfig); pan-tilt: that servo on a
# pan servo too (the mount's `pan`: capsd.mounts.SonarPanConfig).
SonarTilt = Literal["fixed", "servo", "pan-tilt"]


# With the sonar on a pan and a tilt servo, what changes from FOLLOW_STATION. In the mockup the
# detector misses a ROV nearer than about 1 m (docs/JOURNAL.md, session 45: 25 % of pings missed at
# 0.90-0.95 m, 67 % under 0.9 m), so stations keep it 1.2 m off where any can, 1.1 m where none can
# (`preferred_min_range_m`: on the plan's middle lanes, through the ASV's box, a hull facing the ROV
# is at most 1.13 m off; held to 1.2 m there, the follower kept a station from before, 0.9 m off,
# and a demo lost the ROV for 70 s; 1.1 m rather than 1.0 since session 47: the follower also leaves
# a ROV nearer than that the quickest way, and `capsd bench follow --sonar-tilt pan-tilt`, 20 seeds,
# with 0b8447a's follower gave 100.0 % in view against 99.9 % with 1.0 m, 92.7 against 90.4 % with
# `--detect-from 1.05`), the hull facing it (`pan_abeam_deg` 0). Turned 60 deg off it (the service's
# default) the sonar, 0.3 m ahead of the hull's origin, stays 0.15 m further off, and `capsd bench
# follow --sonar-tilt pan-tilt --detect-from 0.95` prefers it (97.2 % in view against 95.4 %), but
# the demo does not: seeds 0-4, 95.0 % good fixes a run facing against 88.9 % turned (53.4 % on seed
# 4, the hull swinging between its two sides through facing), and the ROV waited for the ASV 42-81 s
# a run against 137-233 s (docs/JOURNAL.md, session 46). A tilt servo alone loses more with stations
# further off (the hull turns to face, the tilt cannot: `--sonar-tilt servo`, 90.3 % with 1.2 m
# stations against 94.5 %).
PAN_TILT_STATION: dict[str, dict[str, float]] = {
    "mockup": {"preferred_min_range_m": 1.2, "min_range_m": 1.1}
}
PAN_TILT_MOTION: dict[str, dict[str, float]] = {"mockup": {"pan_abeam_deg": 0.0}}


def follow_station(tank: TankName, *, tilt: SonarTilt) -> dict[str, float]:
    """The follower's station rules the demo uses in this tank with this mount."""
    rules = dict(FOLLOW_STATION.get(tank, {}))
    if tilt == "pan-tilt":
        rules.update(PAN_TILT_STATION.get(tank, {}))
    return rules


def follow_motion(tank: TankName, *, tilt: SonarTilt) -> dict[str, float]:
    """The follower's motion settings (besides the drive) the demo uses with this mount."""
    return dict(PAN_TILT_MOTION.get(tank, {})) if tilt == "pan-tilt" else {}


def sonar_mount(tank: TankName, *, tilt: SonarTilt = "fixed") -> dict[str, Any]:
    """The demo's sonar mount changes for this tank (simulator and services alike)."""
    out: dict[str, Any] = {"pitch_deg": SONAR_PITCH_DEG[tank]} if tank in SONAR_PITCH_DEG else {}
    if tilt in ("servo", "pan-tilt"):
        out["tilt"] = {}
    if tilt == "pan-tilt":
        out["pan"] = {}
    return out


def follow_config(
    tank: TankName, *, drive: AsvDrive = "steered", tilt: SonarTilt = "fixed"
) -> FollowConfig:
    """The follower's config as the demo runs it in a simulated tank (fix signing off).

    (An `asv_follow` service Config: the tank with its fixtures, the demo's sonar mount and
    station rules for the tank, the ASV's drive.)
    """
    import msgspec

    from capsd.services.asv_follow.service import Config, MotionConfig, StationConfig
    from capsd.simulator.world import make_tank, tank_bounds

    return Config(
        tank=tank_bounds(make_tank(tank)),
        sonar=msgspec.convert(sonar_mount(tank, tilt=tilt), SonarMountConfig),
        station=StationConfig(**follow_station(tank, tilt=tilt)),  # type: ignore[arg-type]
        motion=MotionConfig(drive=drive, **follow_motion(tank, tilt=tilt)),
        fix_auth="off",
    )


def start_station(
    tank: TankName, rov_m: tuple[float, float, float], *, tilt: SonarTilt = "fixed"
) -> tuple[tuple[float, float], float] | None:
    """Where the pilot would put the ASV to see the ROV at `rov_m`: the follower's own choice.

    (origin xy, heading in degrees), or None when no station in this tank sees that point.
    """
    import numpy as np

    from capsd.services.asv_follow.station import StationPlanner

    config = follow_config(tank, tilt=tilt)
    planner = StationPlanner(config.sonar, config.tank, config.station.settings())
    centre = np.array([config.tank.length_m / 2.0, config.tank.width_m / 2.0])
    chosen = planner.choose(np.array(rov_m), centre, 0.0)
    if chosen is None:
        return None
    xy = (float(chosen.position_xy[0]), float(chosen.position_xy[1]))
    return xy, math.degrees(chosen.heading_rad)


# The keys of a sonar_detect config that say how it detects (`capsd demo --detector-config`);
# the rest (bus, site, names, the depth gate's mount) is the demo's to set.
DETECTOR_KEYS = ("detector", "cnn", "classical", "min_confidence")
# The depth gate's own settings a detector config carries into the demo; not its vehicles or
# its sonar mount (where it listens and what it looks through: the demo's).
GATE_KEYS = ("mode", "tolerance_m", "aperture_margin_deg", "max_age_s")


def detector_settings_of(path: Path) -> dict[str, Any]:
    """The detector's settings in the sonar_detect config at `path`, validated as the service's.

    Raises ConfigError naming the file and key, as the service would at start.
    """
    import msgspec

    from capsd.config import load_config
    from capsd.services.sonar_detect.service import Config as SonarDetectConfig

    config = msgspec.to_builtins(load_config(path, SonarDetectConfig))
    gate = {k: config["depth_gate"][k] for k in GATE_KEYS}
    return {**{k: config[k] for k in DETECTOR_KEYS}, "depth_gate": gate}


def write_configs(
    folder: Path,
    endpoint: str,
    *,
    trajectory: TrajectoryName,
    tank: TankName,
    seed: int,
    mav_port: int,
    sonar_hz: float = 20.0,
    rov_start_m: tuple[float, float, float] | None = None,
    asv_station_xy: tuple[float, float] | None = None,
    asv_station_heading_deg: float | None = None,
    asv: AsvMode = "station",
    asv_mav_port: int | None = None,
    asv_drive: AsvDrive = "steered",
    sonar_tilt: SonarTilt = "fixed",
    install_errors: Literal["realistic", "off"] = "realistic",
    calibration: Literal["off", "dive"] = "off",
    calibration_s: float = 120.0,
    detector_settings: dict[str, Any] | None = None,
) -> dict[str, Path]:
    """Every process's config in `folder`, by name.

    `detector_settings` (`detector_settings_of`: the detector's keys of a sonar_detect config)
    replace the detection service's defaults; its bus, names and mount stay the demo's.

    With `calibration` "dive" the realistic installation is first calibrated as a field team
    would, from a calibration dive of it (capsd calibrate's code on the simulator's two
    manoeuvres, capsd.bench.accuracy.self_calibrate), and the services get the calibrated
    mount, ROV and installation sigmas; what it found goes to `folder`/calibration.json.

    With `rov_start_m` the ROV is flown live from there by the ArduSub stand-in the simulator
    hosts on `mav_port` (missions); the ASV then starts where the sonar sees that point best,
    and the bridge accepts mission commands. With `asv` "follow" the ASV is driven live by the
    ArduRover stand-in the simulator hosts on `asv_mav_port` (left in GUIDED by its pilot),
    through the ASV's bridge, on the follower's targets; `asv_drive` says how it moves.
    """
    import msgspec
    import yaml

    from capsd.calibrate import tape_prior
    from capsd.geometry import matrix_to_euler_zyx
    from capsd.signing import SiteKey, write_key
    from capsd.simulator.config import Config as SimConfig
    from capsd.simulator.install_errors import InstallErrorsConfig
    from capsd.simulator.sim import Simulation
    from capsd.simulator.world import tank_bounds

    bus = {"connect": [endpoint]}
    # The site's fix key: the locator signs, the bridge checks (as deployed).
    fix_key = folder / "fix.key"
    if not fix_key.exists():
        write_key(fix_key, SiteKey.generate())
    sim: dict[str, Any] = {
        "bus": bus,
        "tank": tank,
        "trajectory": trajectory,
        "seed": seed,
        "streams": {"detections_truth_noise": "off", "asv_pose_truth_noise": "off"},
        "rates": {"sonar_hz": sonar_hz},
        # What the tape got wrong, drawn from the seed; the services keep the nominal mounts.
        "install_errors": {"mode": install_errors},
    }
    # The same sonar for the simulator and the services (on a servo: the stand-in drives it).
    mount = sonar_mount(tank, tilt=sonar_tilt)
    if mount:
        sim["sonar"] = mount
    if rov_start_m is not None:
        # The ASV keeps station (given, or on the near side of the ROV's start, where the
        # sonar's boresight, pitched 30 deg down, meets it), facing the start.
        if asv_station_xy is None:
            standoff = (-rov_start_m[2] - 0.2) / math.tan(math.radians(30.0))
            asv_station_xy = (max(1.0, rov_start_m[0] - standoff), rov_start_m[1])
        sim["guided"] = {"port": mav_port, "start_m": list(rov_start_m)}
        sim["asv_mode"] = "stationary"
        sim["asv_start_xy"] = list(asv_station_xy)
    if asv == "follow":
        if asv_mav_port is None or rov_start_m is None:
            raise ValueError("a following ASV needs its autopilot's port and a ROV flown live")
        sim["asv_mode"] = "guided"
        sim["asv_guided"] = {
            "port": asv_mav_port,
            "mode": "GUIDED",
            "max_speed_m_s": 0.5,
            "start_heading_deg": asv_station_heading_deg,
            "drive": asv_drive,
        }
    run = msgspec.convert({k: v for k, v in sim.items() if k != "bus"}, SimConfig)
    if calibration == "dive" and install_errors != "realistic":
        raise ValueError("calibration 'dive' calibrates a realistic installation (install_errors)")
    mounts = _calibrated(run, folder, duration_s=calibration_s) if calibration == "dive" else {}
    # What every service that looks through the sonar is told: the tape's, or the dive's fit.
    told = {"sonar": mounts.get("sonar", mount)} if mount or mounts else {}
    for servo in ("tilt", "pan"):  # the dive calibrates the servos' zeros; they are the site's
        if servo in mount:
            told["sonar"] = {**told["sonar"], servo: mount[servo]}
    start = Simulation(run, horizon_s=10)
    # The person putting the ASV in the water knows roughly which way it points: 20 deg off.
    heading = math.degrees(matrix_to_euler_zyx(start.asv_pose(0.0).rotation)[0]) + 20.0
    t = run.world_tank()
    tank_box = {"length_m": t.length_m, "width_m": t.width_m}
    gate = {**(detector_settings or {}).get("depth_gate", {}), **told}
    configs = {
        "sim": sim,
        "asv_pose": {
            "bus": bus,
            "heading_prior_deg": round(heading, 1),
            "tank_length_m": t.length_m,
            "tank_width_m": t.width_m,
            # The scanner where the simulated ASV carries it (on its mast), as a team measures it.
            "lidar_xy_m": list(run.lidar.position_m[:2]),
            "lidar_height_m": run.lidar.position_m[2],
        },
        # The depth gate looks through the same mount as the locator (the mockup's sonar is
        # pitched 45 deg; the gate had the default 30 deg), its other settings the detector
        # config's.
        "sonar_detect": {
            **(detector_settings or {}),
            "bus": bus,
            **({"depth_gate": gate} if gate else {}),
        },
        "locator": {
            "bus": bus,
            # The tank as a site would describe it: its box and fixtures (the view draws them).
            "tank": msgspec.to_builtins(tank_bounds(t)),
            "fix_key": str(fix_key),
            **told,
            # Uncalibrated: its covariances allow for what a tape-measured installation may be.
            **(
                {"installation": msgspec.to_builtins(tape_prior(InstallErrorsConfig()))}
                if install_errors == "realistic"
                else {}
            ),
            **{k: v for k, v in mounts.items() if k != "sonar"},
        },
        "mav_bridge": {
            "vehicle": "rov_ap",
            "bus": bus,
            "mavlink": {"connect": f"tcp:127.0.0.1:{mav_port}"},
            "fix_key": str(fix_key),
            "tank": {**tank_box, "depth_m": t.depth_m},
            "mission_commands": "accept" if rov_start_m is not None else "refuse",
        },
        # `capsd mission run --config`: the demo's bridge reports as rov_ap.
        "mission": {"bus": bus, "rov_vehicle": "rov_ap"},
    }
    if asv == "follow":
        configs["asv_bridge"] = {
            "vehicle": "asv",
            "role": "asv",
            "bus": bus,
            "mavlink": {"connect": f"tcp:127.0.0.1:{asv_mav_port}"},
            "fix_key": str(fix_key),
            "tank": {**tank_box, "depth_m": t.depth_m},
            "mission_commands": "accept",
            "geofence_clearance_m": 1.0,
            # ArduRover's GUIDED takes targets only once its EKF has an origin.
            "ekf_origin": {"lat_deg": 54.42, "lon_deg": -3.5, "alt_m": 0.0},
            # asv_pose runs at the IMU's rate; ArduRover's EKF takes 20 Hz of poses at most.
            "gate": {"max_rate_hz": 20.0},
        }
        if "tilt" in mount:
            # The stand-in's mount reports the sonar's nominal pitch at the servo's zero.
            nominal = msgspec.convert(mount, SonarMountConfig).pitch_deg
            configs["asv_bridge"]["sonar_tilt"] = {
                "zero_pitch_deg": -nominal,
                "pan": "servo" if "pan" in mount else "none",
            }
        configs["asv_follow"] = {
            "bus": bus,
            "tank": msgspec.to_builtins(tank_bounds(t)),
            "fix_key": str(fix_key),
            "station": follow_station(tank, tilt=sonar_tilt),
            # The follower is told how the simulated autopilot moves the hull, as a site is.
            "motion": {"drive": asv_drive, **follow_motion(tank, tilt=sonar_tilt)},
            **told,
        }
    paths = {}
    for name, body in configs.items():
        path = folder / f"{name}.yaml"
        path.write_text(yaml.safe_dump(body, sort_keys=False))
        paths[name] = path
    return paths


def _calibrated(run: Any, folder: Path, *, duration_s: float) -> dict[str, Any]:
    """The locator's sonar, rov and installation sections after a calibration dive of `run`.

    The dive is another of the same installation (its own seed, the errors shared), run
    offline before the services start, as a team calibrates on its first dive.
    """
    import json

    import msgspec

    from capsd.bench.accuracy import self_calibrate
    from capsd.bench.calibrate import profile_standoffs_m
    from capsd.progress import Progress

    # The dive is its own run: no live autopilots (the demo's ports), the ASV turns on the spot,
    # the servos held at their zeros (no one drives them: the sonar is then a fixed one).
    offline = msgspec.structs.replace(
        run,
        guided=None,
        asv_guided=None,
        asv_mode="spin",
        sonar=msgspec.structs.replace(run.sonar, tilt=None, pan=None),
    )
    manoeuvres = 2 + len(profile_standoffs_m(offline, offline.sonar))
    print(
        f"calibrating the installation: a simulated calibration dive ({manoeuvres} x "
        f"{duration_s:g} s, offline), fitted by capsd calibrate's code",
        flush=True,
    )
    progress = Progress(manoeuvres * duration_s, label="calibration dive", unit=" s")
    sonar, rov, installation, summary = self_calibrate(
        offline, duration_s=duration_s, progress=progress
    )
    progress.close()
    (folder / "calibration.json").write_text(json.dumps(summary, indent=1, sort_keys=True) + "\n")
    return {
        "sonar": msgspec.to_builtins(sonar),
        "rov": msgspec.to_builtins(rov),
        "installation": msgspec.to_builtins(installation),
    }


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


def start_service(
    procs: Processes, name: str, config: Path, *, service: str | None = None
) -> Child:
    """`capsd run SERVICE --config CONFIG` as a child called `name`; the simulator niced.

    It stands in for sensors with processors of their own: it renders ahead and yields the CPU
    to the system it feeds (its lateness is measured).
    """
    return procs.start(
        name,
        ["-m", "capsd", "run", service or name, "--config", str(config)],
        niceness=SIM_NICENESS if name == "sim" else 0,
    )


class Watch:
    """The demo's own Zenoh client: fixes and labels paired, health polled."""

    def __init__(self, session: zenoh.Session, *, extra: tuple[tuple[str, str, str], ...] = ()):
        self.session = session
        # (vehicle, process name, service) of every process whose health is polled.
        self.services = tuple((v, name, name) for v, name in SERVICES) + extra
        self.accuracy = Accuracy()
        self.pairing = LivePairing(self.accuracy)
        self.decode_errors = 0
        # The ASV's true (x, y) over the run, from the simulator's truth (scoring only).
        self.asv_xy: list[tuple[float, float]] = []
        self._subs = [
            session.declare_subscriber(
                topics.ROV_FIX.key("tank", "topside"), self._decoder(Codec(RovFix), self._on_fix)
            ),
            session.declare_subscriber(
                topics.SIM_LABEL.key("tank", "sim"),
                self._decoder(Codec(SonarLabel), self.pairing.add_label),
            ),
            session.declare_subscriber(
                topics.SIM_TRUTH.key("tank", "sim"),
                self._decoder(Codec(GroundTruth), self._on_truth),
            ),
        ]

    def _decoder(self, codec: Codec[Any], sink: Any) -> Any:
        def on_error() -> None:
            self.decode_errors += 1  # reported in the summary; the services count theirs

        return decoder(codec, sink, on_error=on_error)

    def _on_fix(self, fix: RovFix) -> None:
        self.pairing.add_fix(fix)

    def _on_truth(self, truth: GroundTruth) -> None:
        self.asv_xy.append((truth.asv_position_m[0], truth.asv_position_m[1]))

    def health(self) -> dict[str, Health | None]:
        return {
            name: query_health(
                self.session, site="tank", vehicle=vehicle, service=service, timeout_s=0.5
            )
            for vehicle, name, service in self.services
        }

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()
