"""How far inside the sonar's vertical aperture the ROV is, now and a moment ahead.

The sonar sees the ROV only within its vertical aperture (20 deg). A ROV flying a leg towards
or away from the ASV changes its elevation in the sonar fast when it is near (on a mockup lane
1 m from the sonar, about 4 deg a second at 0.1 m/s): it leaves the aperture before the ASV
can re-station, then has no fix and holds where the ASV cannot see it. The mission therefore
waits (capsd.mission.controller) while the margin, here, is small: the aperture's half-width
less the ROV's elevation, from the newest good fix and the ASV's pose, the smaller of now and
`lookahead_s` ahead at the fix's tracked velocity. Negative: outside the aperture.

A sonar on a tilt servo (the mount's `tilt`) is judged at the servo's zero, as a fixed one: the
ROV keeps to where the follower's stations see it, and the servo covers the hull's turns and
lags. Judged at the servo's reported angle, the ROV flew on while the servo followed it, to
0.2 m from the sonar, steeper than the servo reaches, and was lost there for 60 s (the mockup
demo, docs/JOURNAL.md session 42); `capsd bench follow --sonar-tilt servo` gives 94.7 % in view
either way (perfect fixes, no lag). A pan servo under it (the mount's `pan`) is judged where it
is (the newest reported pan): it turns the sonar's look off the hull's bow, which a tilt does not.
"""

from __future__ import annotations

import math

import numpy as np

from capsd.geometry import Array, Transform
from capsd.mounts import SonarMountConfig
from capsd.sonar_geometry import to_polar


def elevation_margin_rad(
    *, asv: Transform, mount: SonarMountConfig, rov_m: Array, pan_rad: float = 0.0
) -> float:
    """Half the vertical aperture less the ROV's |elevation| in the sonar (negative: outside).

    At a tilt servo's zero, a pan servo at `pan_rad` (see the module).
    """
    sonar = asv.compose(mount.transform(pan_rad=pan_rad))
    p_s = sonar.inverse().apply(np.asarray(rov_m, dtype=np.float64))
    try:
        _, _, elevation = to_polar(mount.beam_model, p_s)
    except ValueError:  # at the sonar's acoustic centre: no direction, not in view
        return -math.pi
    return math.radians(mount.vertical_aperture_deg) / 2.0 - abs(elevation)


def view_margin_rad(
    *,
    asv: Transform,
    mount: SonarMountConfig,
    rov_m: Array,
    velocity_m_s: Array | None,
    lookahead_s: float,
    pan_rad: float = 0.0,
) -> float:
    """The smaller elevation margin of now and `lookahead_s` ahead (the ASV where it is)."""
    now = elevation_margin_rad(asv=asv, mount=mount, rov_m=rov_m, pan_rad=pan_rad)
    if velocity_m_s is None or lookahead_s <= 0.0:
        return now
    ahead = np.asarray(rov_m, dtype=np.float64) + np.asarray(velocity_m_s) * lookahead_s
    return min(now, elevation_margin_rad(asv=asv, mount=mount, rov_m=ahead, pan_rad=pan_rad))
