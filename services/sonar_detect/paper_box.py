"""The paper's detector as a baseline: the centre of a perfect fan-image box, back to (R, theta).

The paper runs YOLOv5 on the Cartesian fan image and takes the bounding box's centre; here the
box is perfect (the simulator's footprint of the ROV's echo), which flatters the baseline: what
remains is the error of the method itself (a box centre is not the ROV centre: the echo is the
ROV's near side, and a fan box's centre is not on the arc).
"""

from __future__ import annotations

import math

import numpy as np

from capsd.payloads import Detection, SonarLabel


def box_centre(label: SonarLabel, *, range_bias_m: float = 0.0) -> list[Detection]:
    """The paper's detector output given a perfect box: the fan-image box centre as (R, theta).

    `range_bias_m` is added to the range: the box is drawn around the ROV's near-side echo, so
    its centre is short by a roughly constant amount that training runs can measure
    (capsd.bench.baseline); 0 is the method as published.
    """
    footprint = label.footprint()
    if footprint is None:
        return []
    range_min, range_max, azimuth_min, azimuth_max = footprint
    xs, ys = [], []
    for r in (range_min, range_max):
        for a in np.linspace(azimuth_min, azimuth_max, 9):
            xs.append(r * math.cos(a))
            ys.append(r * math.sin(a))
    x, y = (min(xs) + max(xs)) / 2, (min(ys) + max(ys)) / 2
    return [
        Detection(
            range_m=math.hypot(x, y) + range_bias_m,
            azimuth_rad=math.atan2(y, x),
            range_sigma_m=0.05,
            azimuth_sigma_rad=math.radians(0.5),
            confidence=1.0,
        )
    ]
