"""The safety gate's decisions and the boot-clock mapping."""

from __future__ import annotations

from capsd.payloads import RovFix
from capsd.services.mav_bridge.clock import BootClock
from capsd.services.mav_bridge.gate import GateSettings, Passed, SafetyGate

NOW = 1_800_000_000_000_000_000
MS = 1_000_000
COV = (0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.01)


def _fix(stamp_ns: int, **changes: object) -> RovFix:
    fields: dict[str, object] = dict(
        stamp_ns=stamp_ns,
        seq=0,
        method="capsd",
        quality="good",
        position_m=(1.0, 2.0, -3.0),
        velocity_m_s=(0.0, 0.0, 0.0),
        covariance_m2=COV,
        track_state="tracking",
    )
    fields.update(changes)
    return RovFix(**fields)  # type: ignore[arg-type]


def test_passes_a_fresh_good_estimate() -> None:
    gate = SafetyGate(GateSettings())
    decision = gate.check(_fix(NOW - 50 * MS, track_resets=4), now_ns=NOW)
    assert isinstance(decision, Passed)
    assert decision.usec == (NOW - 50 * MS) // 1000
    assert decision.reset_counter == 4
    assert gate.counts["sent"] == 1


def test_refusals() -> None:
    gate = SafetyGate(GateSettings(max_age_s=0.3, max_sigma_m=0.5))
    assert gate.check(_fix(NOW - 301 * MS), now_ns=NOW) == "stale"
    assert gate.check(_fix(NOW + 500 * MS), now_ns=NOW) == "from_future"
    assert gate.check(_fix(NOW, quality="unsure"), now_ns=NOW) == "not_good"
    assert (
        gate.check(
            _fix(
                NOW,
                quality="invalid",
                position_m=None,
                covariance_m2=None,
                velocity_m_s=None,
                track_state="lost",
            ),
            now_ns=NOW,
        )
        == "not_good"
    )
    wide = (0.36, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.01)  # 0.6 m sigma in x
    assert gate.check(_fix(NOW, covariance_m2=wide), now_ns=NOW) == "uncertain"
    assert set(gate.counts) == {"stale", "from_future", "not_good", "uncertain"}


def test_rate_limit_by_measurement_stamps_and_monotonic_usec() -> None:
    gate = SafetyGate(GateSettings(max_rate_hz=50.0))
    assert isinstance(gate.check(_fix(NOW - 30 * MS), now_ns=NOW), Passed)
    # Measured 15 ms after the last one sent: faster than 50 Hz, however it arrives.
    assert gate.check(_fix(NOW - 15 * MS), now_ns=NOW + 40 * MS) == "rate_limited"
    # Measured 25 ms after it (a 40 Hz sonar) but arriving 5 ms after it: sent.
    assert isinstance(gate.check(_fix(NOW - 5 * MS), now_ns=NOW + 5 * MS), Passed)
    # An older measurement arriving later would move usec backwards: refused.
    assert gate.check(_fix(NOW - 6 * MS), now_ns=NOW + 50 * MS) == "not_monotonic"


def test_raw_fix_is_used_when_there_is_no_track() -> None:
    gate = SafetyGate(GateSettings())
    fix = _fix(
        NOW,
        position_m=None,
        velocity_m_s=None,
        covariance_m2=None,
        track_state="none",
        raw_position_m=(1.0, 1.0, -1.0),
        raw_covariance_m2=COV,
    )
    decision = gate.check(fix, now_ns=NOW)
    assert isinstance(decision, Passed)
    assert list(decision.position_w) == [1.0, 1.0, -1.0]


def test_boot_clock_takes_the_minimum_latency_and_detects_reboots() -> None:
    clock = BootClock()
    offset = NOW - 5_000 * MS
    for boot_ms, latency_ms in ((5000, 12), (5100, 3), (5200, 40)):
        assert not clock.observe(boot_ms, offset + boot_ms * MS + latency_ms * MS)
    assert clock.to_unix_ns(5300) == offset + 5300 * MS + 3 * MS
    assert clock.boots == 1
    assert clock.observe(200, NOW + 10_000 * MS)  # boot time went back: a reboot
    assert clock.boots == 2
    assert clock.to_unix_ns(200) == NOW + 10_000 * MS


def test_serial_link_writes_mavlink2_to_a_pseudo_terminal() -> None:
    import os

    from capsd.protocols.mavlink import MavLink

    master, slave = os.openpty()
    try:
        with MavLink(f"serial:{os.ttyname(slave)}:115200", system_id=1, component_id=197) as link:
            link.send_heartbeat_onboard()
            data = os.read(master, 1024)
        assert data[:1] == b"\xfd"  # MAVLink 2 start byte
        assert data[7:10] == b"\x00\x00\x00"  # message id 0: HEARTBEAT
    finally:
        os.close(master)
        os.close(slave)
