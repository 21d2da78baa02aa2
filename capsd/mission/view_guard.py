"""How far inside the sonar's vertical aperture the ROV is, now and a moment ahead.

The sonar sees the ROV only within its vertical aperture (20 deg). A ROV flying a leg towards
or away from the ASV changes its elevation in the sonar fast when it is near (on a mockup lane
1 m from the sonar, about 4 deg a second at 0.1 m/s): it leaves the aperture before the ASV
can re-station, then has no fix and holds where the ASV cannot see it. The mission therefore
waits (capsd.mission.controller) while the margin, here, is small: the aperture's half-width
less the ROV's elevation, from the newest good fix and the ASV's pose, the smaller of now and
`lookahead_s` ahead at the fix's tracked velocity. Negative: outside the aperture. A sonar on a
tilt servo (the mount's `tilt`) is judged at the servo's reported angle (the ROV waits while
the servo catches up, as it waits for the hull: `capsd bench follow --sonar-tilt servo` in the
mockup 94.7 % in view, against 91.3 % judging the servo at its best angle, README session 42);
with no report yet, at the angle that centres the ROV within its range (an elevation shifts by
the tilt: exact in a conical beam).
"""

from __future__ import annotations

import math

import numpy as np

from capsd.geometry import Array, Transform
from capsd.mounts import SonarMountConfig
from capsd.sonar_geometry import to_polar


def elevation_margin_rad(
    *, asv: Transform, mount: SonarMountConfig, rov_m: Array, tilt_rad: float | None = None
) -> float:
    """Half the vertical aperture less the ROV's |elevation| in the sonar (negative: outside).

    A sonar on a tilt servo: `tilt_rad` its reported angle; None, the servo at its best.
    """
    sonar = asv.compose(mount.transform(tilt_rad=tilt_rad or 0.0))
    p_s = sonar.inverse().apply(np.asarray(rov_m, dtype=np.float64))
    try:
        _, _, elevation = to_polar(mount.beam_model, p_s)
    except ValueError:  # at the sonar's acoustic centre: no direction, not in view
        return -math.pi
    if mount.tilt is not None and tilt_rad is None:
        elevation += mount.tilt.clamp_rad(-elevation)
    return math.radians(mount.vertical_aperture_deg) / 2.0 - abs(elevation)


def view_margin_rad(
    *,
    asv: Transform,
    mount: SonarMountConfig,
    rov_m: Array,
    velocity_m_s: Array | None,
    lookahead_s: float,
    tilt_rad: float | None = None,
) -> float:
    """The smaller elevation margin of now and `lookahead_s` ahead (the ASV and servo as now)."""
    now = elevation_margin_rad(asv=asv, mount=mount, rov_m=rov_m, tilt_rad=tilt_rad)
    if velocity_m_s is None or lookahead_s <= 0.0:
        return now
    ahead = np.asarray(rov_m, dtype=np.float64) + np.asarray(velocity_m_s) * lookahead_s
    return min(now, elevation_margin_rad(asv=asv, mount=mount, rov_m=ahead, tilt_rad=tilt_rad))
