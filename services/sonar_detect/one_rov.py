"""One ROV in the tank: each candidate's confidence as the probability that it is the ROV.

A detector scores each candidate alone, by how much it looks like a ROV. A frame holds one
ROV at most, so two confident candidates cannot both be it, and reporting both as sure
reports at least one false alarm as sure. Given the independent scores p_i of a frame's
candidates (those the depth gate leaves) and that at most one of them is the ROV, the
probability that candidate i is the ROV is

    w_i / (w_0 + sum_k w_k),   w_i = p_i / (1 - p_i) * w_0,   w_0 = prod_j (1 - p_j)

(w_0: none of them is). A lone candidate keeps its score. A ROV at 0.95 beside clutter at 0.6
becomes 0.88 and the clutter 0.07; two candidates at 0.9 become 0.47 each: the frame is
ambiguous and neither is sent as sure (the locator's tracker, which knows where the ROV was,
is not told a guess). The detector's own track prior (a candidate continuing the last ping's
ROV) is in p_i already, so a tracked ROV keeps its lead over new clutter.

"exclusive" does this; "independent" reports each candidate's own score (before session 64).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import msgspec

from capsd.payloads import Detection

Confidence = Literal["exclusive", "independent"]
DEFAULT_CONFIDENCE: Confidence = "exclusive"  # the service's `cnn.confidence` unless configured
_EDGE = 1e-9  # scores of exactly 0 or 1 kept finite in the odds


def exclusive(detections: Sequence[Detection]) -> list[Detection]:
    """`detections` with each confidence the probability that it is the one ROV."""
    if len(detections) < 2:
        return list(detections)
    scores = [min(max(d.confidence, _EDGE), 1.0 - _EDGE) for d in detections]
    # In log space: w_0 underflows for many candidates, and only the ratios matter.
    log_none = sum(math.log1p(-p) for p in scores)
    logs = [math.log(p) - math.log1p(-p) + log_none for p in scores]
    top = max([log_none, *logs])
    total = math.exp(log_none - top) + sum(math.exp(v - top) for v in logs)
    return [
        msgspec.structs.replace(d, confidence=math.exp(v - top) / total)
        for d, v in zip(detections, logs, strict=True)
    ]


def scored(detections: Sequence[Detection], confidence: Confidence) -> list[Detection]:
    """The candidates' confidences as `confidence` says (see the module docstring)."""
    return exclusive(detections) if confidence == "exclusive" else list(detections)
