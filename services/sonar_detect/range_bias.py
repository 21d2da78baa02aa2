"""The detector's range to a near ROV, corrected for how the sonar sees it.

Under 4 m a BlueROV2 spans a third of a 20 deg aperture or more, and the vertical beam lights
its parts unevenly: the echo's range moves with the ROV's elevation in the beam, which the
image cannot show (`capsd bench detect`, the rows by the ROV's place in the aperture: the CNN
+2.8 cm in the lower third against +0.2 in the middle). It moves as much with the angle the
sonar looks down at the ROV from (its depression): seen from the side the echo starts at the
ROV's end, seen from above at its top, and a network trained on sonars 8-30 deg down puts a
ROV seen 60-80 deg down 6-10 cm too far (`capsd train range-bias`, session 43). The
depth-aware search knows both: the ROV's depth plane and the sonar's pose put a candidate at
(range, azimuth) at one elevation, and the height between them over the range is the
depression. A table of the detector's median signed range error by depression band and
elevation (as a share of the half aperture), measured on training runs by `capsd train
range-bias`, is taken off its range. Weights with a near refiner (polar_net; ROVs under about
1.5 m) get a second grid for its detections: the two refiners err differently (session 55: one
grid over both put the main refiner's ROVs 1.5-4 m off 4 cm long).
"""

from __future__ import annotations

import bisect
import math
from pathlib import Path
from typing import Annotated

import msgspec

from capsd.errors import CapsdError
from capsd.payloads import Detection
from capsd.services.sonar_detect.depth_gate import DepthGate

DEFAULT_TABLE = Path(__file__).with_name("weights") / "range_bias.json"


class RangeBias(msgspec.Struct, frozen=True, kw_only=True):
    """Median signed range error (detected less true, metres) by depression and elevation."""

    # Bin edges of elevation / half aperture, ascending; one bias per bin between two edges.
    share_edges: Annotated[tuple[float, ...], msgspec.Meta(min_length=2, max_length=64)]
    # Bands of the line of sight's depression below the horizontal (degrees), ascending. The
    # default, one band for every depression, is a table by elevation alone (before session 43).
    depression_edges_deg: Annotated[
        tuple[float, ...], msgspec.Meta(min_length=2, max_length=64)
    ] = (-90.0, 90.0)
    # One bias per (band, bin), band by band (row-major).
    bias_m: tuple[float, ...]
    # Matched detections per (band, bin); a cell with too few took the bias of its band's
    # nearest measured cell (a band with none has bias 0): `capsd train range-bias`.
    samples: tuple[int, ...]
    within_m: Annotated[float, msgspec.Meta(gt=0.0, le=100.0)]  # nearer ROVs only
    half_aperture_deg: Annotated[float, msgspec.Meta(gt=0.0, le=90.0)]
    # Detections nearer than this (the near refiner's, polar_net) take the near grid below,
    # laid out as `bias_m`; 0: no near grid (weights without a near refiner).
    near_within_m: Annotated[float, msgspec.Meta(ge=0.0, le=100.0)] = 0.0
    near_bias_m: tuple[float, ...] = ()
    near_samples: tuple[int, ...] = ()
    # How it was measured: command, runs, weights, looks.
    provenance: dict[str, str | int | float] = {}

    def __post_init__(self) -> None:
        cells = (len(self.share_edges) - 1) * (len(self.depression_edges_deg) - 1)
        if len(self.bias_m) != cells or len(self.samples) != cells:
            raise ValueError(f"{cells} cells (bands x bins) need as many biases and sample counts")
        near_cells = cells if self.near_within_m > 0.0 else 0
        if len(self.near_bias_m) != near_cells or len(self.near_samples) != near_cells:
            raise ValueError(
                f"`near_within_m` {self.near_within_m}: {near_cells} near biases and sample "
                "counts wanted"
            )
        if self.near_within_m > self.within_m:
            raise ValueError("`near_within_m` must not exceed `within_m`")
        if list(self.share_edges) != sorted(self.share_edges):
            raise ValueError("`share_edges` must ascend")
        if list(self.depression_edges_deg) != sorted(self.depression_edges_deg):
            raise ValueError("`depression_edges_deg` must ascend")
        if any(not math.isfinite(b) or abs(b) > 0.5 for b in self.bias_m + self.near_bias_m):
            raise ValueError("a bias must be finite and within 0.5 m")

    def at(self, elevation_rad: float, range_m: float, depression_rad: float) -> float:
        """The bias to take off a detection seen so (0 outside the table)."""
        if range_m >= self.within_m:
            return 0.0
        bins = len(self.share_edges) - 1
        share = math.degrees(elevation_rad) / self.half_aperture_deg
        k = bisect.bisect_right(self.share_edges, share) - 1
        band = bisect.bisect_right(self.depression_edges_deg, math.degrees(depression_rad)) - 1
        if not (0 <= k < bins and 0 <= band < len(self.depression_edges_deg) - 1):
            return 0.0
        grid = self.near_bias_m if range_m < self.near_within_m else self.bias_m
        return grid[band * bins + k]

    def corrected(self, detection: Detection, gate: DepthGate) -> Detection:
        """The detection with its range corrected for how the gate places it."""
        elevation = gate.elevation_at(detection.range_m, detection.azimuth_rad)
        if elevation is None:
            return detection
        bias = self.at(elevation, detection.range_m, depression_rad(gate, detection.range_m))
        if bias == 0.0 or detection.range_m - bias <= 0.0:
            return detection
        return msgspec.structs.replace(detection, range_m=detection.range_m - bias)


def depression_rad(gate: DepthGate, range_m: float) -> float:
    """The angle below the horizontal at which the sonar sees the ROV's plane at this range."""
    height = float(gate.sonar_in_world.translation[2]) - gate.rov_z_m
    return math.asin(max(-1.0, min(1.0, height / max(range_m, 1e-6))))


def load(path: Path) -> RangeBias:
    """The table at `path`; a missing or malformed file is an error naming it."""
    try:
        return msgspec.json.decode(path.read_bytes(), type=RangeBias)
    except FileNotFoundError:
        raise CapsdError(f"{path}: no range bias table (capsd train range-bias)") from None
    except (msgspec.ValidationError, msgspec.DecodeError) as exc:
        raise CapsdError(f"{path}: not a range bias table: {exc}") from None


def save(table: RangeBias, path: Path) -> None:
    """Write `table` as indented JSON."""
    path.write_bytes(msgspec.json.format(msgspec.json.encode(table), indent=1) + b"\n")


__all__ = ["DEFAULT_TABLE", "RangeBias", "depression_rad", "load", "save"]
