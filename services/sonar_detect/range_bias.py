"""The detector's range to a near ROV, corrected for where the ROV lies in the vertical aperture.

Under 4 m a BlueROV2 spans a third of a 20 deg aperture or more, and the vertical beam lights
its parts unevenly: the echo's range moves with the ROV's elevation in the beam, which the
image cannot show (`capsd bench detect`, the rows by the ROV's place in the aperture: the CNN
+2.8 cm in the lower third against +0.2 in the middle). The depth-aware search knows it: the
ROV's depth plane and the sonar's pose put a candidate at (range, azimuth) at one elevation.
A table of the detector's median signed range error by that elevation (as a share of the half
aperture), measured on training runs by `capsd train range-bias`, is taken off its range.
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
    """Median signed range error (detected less true, metres) by elevation share, near ROVs."""

    # Bin edges of elevation / half aperture, ascending; one bias per bin between two edges.
    share_edges: Annotated[tuple[float, ...], msgspec.Meta(min_length=2, max_length=64)]
    bias_m: tuple[float, ...]
    samples: tuple[int, ...]  # matched detections per bin (a bin with too few has bias 0)
    within_m: Annotated[float, msgspec.Meta(gt=0.0, le=100.0)]  # nearer ROVs only
    half_aperture_deg: Annotated[float, msgspec.Meta(gt=0.0, le=90.0)]
    # How it was measured: command, runs, weights, looks.
    provenance: dict[str, str | int | float] = {}

    def __post_init__(self) -> None:
        bins = len(self.share_edges) - 1
        if len(self.bias_m) != bins or len(self.samples) != bins:
            raise ValueError(f"{bins} bins need as many biases and sample counts")
        if list(self.share_edges) != sorted(self.share_edges):
            raise ValueError("`share_edges` must ascend")
        if any(not math.isfinite(b) or abs(b) > 0.5 for b in self.bias_m):
            raise ValueError("a bias must be finite and within 0.5 m")

    def at(self, elevation_rad: float, range_m: float) -> float:
        """The bias to take off a detection at this elevation and range (0 outside the table)."""
        if range_m >= self.within_m:
            return 0.0
        share = math.degrees(elevation_rad) / self.half_aperture_deg
        k = bisect.bisect_right(self.share_edges, share) - 1
        if k < 0 or k >= len(self.bias_m):
            return 0.0
        return self.bias_m[k]

    def corrected(self, detection: Detection, gate: DepthGate) -> Detection:
        """The detection with its range corrected where the gate places it in the aperture."""
        elevation = gate.elevation_at(detection.range_m, detection.azimuth_rad)
        if elevation is None:
            return detection
        bias = self.at(elevation, detection.range_m)
        if bias == 0.0 or detection.range_m - bias <= 0.0:
            return detection
        return msgspec.structs.replace(detection, range_m=detection.range_m - bias)


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


__all__ = ["DEFAULT_TABLE", "RangeBias", "load", "save"]
