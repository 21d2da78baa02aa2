"""The simulator makes its world only a little ahead of time: commands reach the next pings."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

from capsd import topics
from capsd.payloads import RovDepth
from capsd.simulator.service import AHEAD_S, _Lookahead
from capsd.simulator.sim import Event


def test_each_event_is_made_no_earlier_than_ahead_s_before_the_one_before_is_due() -> None:
    start = time.monotonic()

    def now_s() -> float:
        return time.monotonic() - start

    made_at: list[tuple[float, float]] = []  # (due, made)

    def events() -> Iterator[Event]:
        k = 0
        while True:
            t = 0.01 * k
            made_at.append((t, now_s()))
            depth = RovDepth(stamp_ns=k, seq=k, depth_m=1.0, pressure_pa=1e5, sigma_m=0.01)
            yield Event(t, topics.ROV_DEPTH, "rov", depth)
            k += 1

    stop = threading.Event()
    ahead = _Lookahead(events(), stop, now_s=now_s, ahead_s=0.05)
    ahead.start()
    put = 0
    while put < 40:  # 0.4 s of events, taken as they fall due
        if ahead.due(now_s()) is not None:
            put += 1
        else:
            time.sleep(0.001)
    stop.set()
    ahead.join(timeout=2.0)
    assert not ahead.is_alive()
    # From the second on (the first is made at once): never more than 50 ms plus the 10 ms
    # between events ahead (a 64-event queue alone would have made them 0.64 s ahead).
    leads = [due - made for due, made in made_at[1:]]
    assert max(leads) <= 0.05 + 0.01 + 0.005
    assert len(made_at) < 40 + 64
    assert 0.0 < AHEAD_S < 0.05  # ahead of a render, within a 20 Hz sonar's period
