"""`capsd bench search`: the loss model and what counts as seen."""

from __future__ import annotations

import numpy as np

from capsd.bench.search import planner, seen_after


def test_a_rov_still_where_it_was_lost_is_seen_at_once() -> None:
    stations = planner()
    assert stations.keep_out  # the mockup's post reaches the surface: the ASV keeps off it
    # No offset: the first station looks at it (the first step that counts is 0.1 s in).
    assert seen_after(stations, np.array([3.0, 1.8, -1.0]), 0.0, 0.0) == 0.1
