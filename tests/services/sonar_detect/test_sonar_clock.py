"""The sonar's ping counter mapped onto our clock: units learnt, wraps, stalls, bad counters."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from capsd.services.sonar_detect.sonar_clock import LATE_S, SonarClock

U32 = 2.0**32


def _stream(
    *,
    period_s: float,
    tick_ns: float,
    latency_s: float,
    jitter_s: float,
    stall_at_s: float,
    stall_s: float,
    duration_s: float,
    seed: int,
) -> list[tuple[float, int, int, bool]]:
    """(raw ticks, true taken_ns, arrival_ns, alone) for each ping, a u32 counter.

    Pings taken between `stall_at_s` and `stall_at_s + stall_s` all arrive at its end, in
    one read (a backlog).
    """
    rng = np.random.default_rng(seed)
    start_ns = 1_800_000_000_000_000_000
    out = []
    for k in range(int(duration_s / period_s)):
        t = k * period_s
        taken = start_ns + int(t * 1e9)
        arrival = taken + int((latency_s + rng.uniform(0.0, jitter_s)) * 1e9)
        stalled = stall_at_s <= t < stall_at_s + stall_s
        if stalled:
            arrival = start_ns + int((stall_at_s + stall_s + latency_s) * 1e9)
        ticks = float(int(t * 1e9 / tick_ns + 12345.0) % int(U32))
        out.append((ticks, taken, arrival, not stalled))
    return out


@settings(max_examples=60, deadline=None)
@given(
    period_s=st.floats(0.025, 0.2),
    tick_ns=st.sampled_from([1.0, 1000.0, 1e6]),
    latency_s=st.floats(0.001, 0.05),
    stall_s=st.floats(0.5, 2.0),
    seed=st.integers(0, 1000),
)
def test_after_learning_every_ping_is_stamped_when_taken_even_after_a_stall(
    period_s: float, tick_ns: float, latency_s: float, stall_s: float, seed: int
) -> None:
    jitter_s = 0.004
    pings = _stream(
        period_s=period_s,
        tick_ns=tick_ns,
        latency_s=latency_s,
        jitter_s=jitter_s,
        stall_at_s=8.0,
        stall_s=stall_s,
        duration_s=14.0,
        seed=seed,
    )
    clock = SonarClock(modulus=U32)
    late = 0
    for ticks, taken, arrival, alone in pings:
        stamp = clock.stamp(ticks, arrival, alone=alone)
        if not clock.learnt:
            assert stamp.taken_ns == arrival
            assert not stamp.from_sonar_clock
            continue
        assert stamp.from_sonar_clock
        # The quickest pings define the mapping: the true instant plus the smallest latency,
        # within the jitter and what 3 s of learning leave in the rate (a few ms), never later
        # than the arrival. (Milliseconds: 1.5 mm of a ROV at 0.3 m/s.)
        error_s = (stamp.taken_ns - taken) / 1e9 - latency_s
        assert -0.005 <= error_s <= jitter_s + 0.005, (error_s, arrival - taken)
        assert stamp.taken_ns <= arrival
        late += stamp.late_s > LATE_S
    assert clock.learnt
    # A silence longer than half the counter's wrap (2.1 s for a nanosecond u32) may hide a
    # wrap: the clock drops its mapping there by design and learns it again, so the backlog
    # is stamped on arrival, not flagged late (hypothesis found it: 0.16 s pings, a 2 s stall).
    first_stalled = next(k for k, ping in enumerate(pings) if not ping[3])
    silence_s = (pings[first_stalled][2] - pings[first_stalled - 1][2]) / 1e9
    if silence_s > 0.5 * U32 * tick_ns / 1e9:
        assert clock.resets == 1
        return
    # Pings in the stall were late by up to stall_s: some are flagged (not all: the last ones
    # taken just before the stall ended are on time).
    assert late >= int((stall_s - LATE_S) / period_s) - 1
    assert clock.resets == 0  # 14 s of a nanosecond u32 wraps 3 times: all unwrapped


def test_a_replayed_counter_is_never_learnt() -> None:
    # A recording played in a loop: three counter values over and over.
    clock = SonarClock(modulus=U32)
    values = [3103899264.0, 3166401394.0, 3228903491.0]
    arrival = 1_800_000_000_000_000_000
    for k in range(400):
        arrival += 25_000_000
        stamp = clock.stamp(values[k % 3], arrival, alone=True)
        assert stamp.taken_ns == arrival
    assert not clock.learnt


def test_a_double_counter_that_goes_back_resets_and_is_learnt_again() -> None:
    clock = SonarClock(modulus=None, learn_s=2.0)
    arrival = 1_800_000_000_000_000_000
    t = 100.0
    for _ in range(120):  # 3 s at 40 Hz
        t += 0.025
        arrival += 25_000_000
        clock.stamp(t, arrival, alone=True)
    assert clock.learnt
    t = 5.0  # the sonar restarted its counter
    arrival += 25_000_000
    stamp = clock.stamp(t, arrival, alone=True)
    assert (clock.resets, clock.learnt) == (1, False)
    assert stamp.taken_ns == arrival
    for _ in range(120):
        t += 0.025
        arrival += 25_000_000
        stamp = clock.stamp(t, arrival, alone=True)
    assert (clock.resets, clock.learnt) == (1, True)
    assert abs(stamp.taken_ns - arrival) < 1_000_000


def test_a_gap_longer_than_the_wrap_voids_the_mapping() -> None:
    clock = SonarClock(modulus=U32, learn_s=2.0)
    arrival = 1_800_000_000_000_000_000
    ticks = 0
    for _ in range(120):
        ticks = (ticks + 25_000_000) % int(U32)
        arrival += 25_000_000
        clock.stamp(float(ticks), arrival, alone=True)
    assert clock.learnt
    # 5 s with nothing: a nanosecond u32 wrapped once, unseen.
    ticks = (ticks + 5_000_000_000) % int(U32)
    arrival += 5_000_000_000
    stamp = clock.stamp(float(ticks), arrival, alone=True)
    assert clock.resets == 1
    assert stamp.taken_ns == arrival
