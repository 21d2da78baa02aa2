"""Key expressions: the one place that spells a key (`cap/<site>/<vehicle>/<subject>`)."""

from __future__ import annotations

import re
from enum import StrEnum

from capsd.errors import KeyExprError

ROOT = "cap"
_NAME = re.compile(r"^[a-z0-9][a-z0-9_]{0,31}$")
_WILDCARD_CHUNKS = {"*", "**"}


class Subject(StrEnum):
    """What a key carries, relative to its vehicle's namespace."""

    ASV_POSE = "asv/pose"
    ASV_POSE_EXTERNAL = "asv/pose_external"  # an existing SLAM's pose, for asv_pose to use
    ASV_IMU = "asv/imu"
    ASV_SCAN = "asv/scan"
    SONAR_FRAME = "sonar/frame"
    SONAR_DETECTIONS = "sonar/detections"
    SONAR_TILT = "sonar/tilt"  # the sonar's tilt servo, from the ASV's bridge
    ROV_DEPTH = "rov/depth"
    ROV_ATTITUDE = "rov/attitude"
    ROV_VELOCITY = "rov/velocity"
    ROV_STATUS = "rov/status"
    ROV_FIX = "locator/fix"
    ROV_COMMAND = "mission/command"  # a mission's GUIDED targets and holds, for the bridge
    ASV_COMMAND = "follow/command"  # the follower's GUIDED targets for the ASV's bridge
    ASV_AUTOPILOT = "asv/autopilot"  # the ASV autopilot's state, from its bridge
    SIM_TRUTH = "sim/truth"
    SIM_LABEL = "sim/label"
    # The simulator's stand-ins made from truth plus noise (an ASV pose, detections): on keys
    # of their own, never on the services' keys, so no service can mistake them for a sensor.
    SIM_ASV_POSE = "sim/asv_pose"
    SIM_DETECTIONS = "sim/detections"
    SIM_CONTROL = "sim/control"  # fault injection into the simulator (tests, benches)
    # A reference system's pose of the vehicle (motion capture): what fixes are scored against.
    REFERENCE_POSE = "ref/pose"


# What only benches, taps, recordings and evaluation may read: no service subscribes to these
# (the simulator's truth and a reference system's poses are what fixes are scored against).
TRUTH_SUBJECTS = frozenset(
    {
        Subject.SIM_TRUTH,
        Subject.SIM_LABEL,
        Subject.SIM_ASV_POSE,
        Subject.SIM_DETECTIONS,
        Subject.REFERENCE_POSE,
    }
)


def subject_of(key_expr: str) -> str:
    """The subject of a data key: 'cap/site/vehicle/sonar/frame' -> 'sonar/frame' ('' if none)."""
    parts = key_expr.split("/")
    return "/".join(parts[3:]) if len(parts) > 3 else ""


def check_name(kind: str, name: str) -> str:
    """Validate a site, vehicle or service name: lower case, digits and '_', 1-32 characters."""
    if not _NAME.fullmatch(name):
        raise KeyExprError(
            f"{kind} name '{name}' is invalid: use 1-32 characters of a-z, 0-9 and '_', "
            "starting with a letter or digit"
        )
    return name


def is_concrete(key_expr: str) -> bool:
    """True when `key_expr` names exactly one key: no `*`, `**` or `$*` anywhere."""
    return "$*" not in key_expr and not any(
        chunk in _WILDCARD_CHUNKS for chunk in key_expr.split("/")
    )


def require_concrete(key_expr: str) -> str:
    """Return `key_expr`, or raise KeyExprError if it is a wildcard expression."""
    if not is_concrete(key_expr):
        raise KeyExprError(
            f"wildcard key expression '{key_expr}' refused: a concrete key is required"
        )
    return key_expr


def data_key(site: str, vehicle: str, subject: Subject) -> str:
    """The key of a data stream, e.g. `cap/tank1/asv/sonar/frame`."""
    return f"{ROOT}/{check_name('site', site)}/{check_name('vehicle', vehicle)}/{subject.value}"


def health_key(site: str, vehicle: str, service: str) -> str:
    """Where a service publishes (and answers queries for) its Health."""
    return f"{ROOT}/{check_name('site', site)}/{check_name('vehicle', vehicle)}/health/" + (
        check_name("service", service)
    )


def alive_key(site: str, vehicle: str, service: str) -> str:
    """The liveliness token a running service holds."""
    return f"{ROOT}/{check_name('site', site)}/{check_name('vehicle', vehicle)}/alive/" + (
        check_name("service", service)
    )


def log_key(site: str, vehicle: str, service: str) -> str:
    """Log lines in the BlueOS convention `services/<name>/log` (name unique per service)."""
    return "services/capsd-{}-{}-{}/log".format(
        check_name("site", site), check_name("vehicle", vehicle), check_name("service", service)
    )


def all_alive(site: str | None = None) -> str:
    """Wildcard selecting every liveliness token (of one site, or of all)."""
    return f"{ROOT}/{check_name('site', site) if site else '*'}/*/alive/*"


def all_health(site: str | None = None) -> str:
    """Wildcard selecting every Health key (of one site, or of all)."""
    return f"{ROOT}/{check_name('site', site) if site else '*'}/*/health/*"


def parse_service_key(key_expr: str) -> tuple[str, str, str]:
    """Split a health or alive key into (site, vehicle, service)."""
    parts = key_expr.split("/")
    if len(parts) != 5 or parts[0] != ROOT or parts[3] not in ("health", "alive"):
        raise KeyExprError(f"'{key_expr}' is not a health or alive key")
    return parts[1], parts[2], parts[4]
