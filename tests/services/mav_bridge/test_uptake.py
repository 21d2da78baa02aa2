"""EstimateUptake: estimates sent a while, SYS_STATUS never healthy: the autopilot drops them."""

from __future__ import annotations

from capsd.services.mav_bridge.uptake import EstimateUptake


def _run(states: list[str], *, send: bool = True) -> list[bool]:
    """One tick per 0.1 s: an estimate (if `send`), the SYS_STATUS state of the tick."""
    uptake = EstimateUptake()
    verdicts = []
    for k, state in enumerate(states):
        now = k * 0.1
        if send:
            uptake.sent(now)
        uptake.status(state, now)  # type: ignore[arg-type]
        verdicts.append(uptake.ignored(now))
    return verdicts


def test_ignored_only_when_sent_for_a_while_and_never_healthy() -> None:
    unhealthy = _run(["unhealthy"] * 50)
    assert not any(unhealthy[:30])  # 3 s of grace
    assert all(unhealthy[31:])
    assert not any(_run(["healthy"] * 50))
    assert not any(_run(["unhealthy"] * 50, send=False))  # nothing sent: nothing to say
    # One healthy report in the last 3 s is enough (a slow estimate rate flickers).
    flicker = _run((["unhealthy"] * 9 + ["healthy"]) * 5)
    assert not any(flicker)


def test_no_status_and_a_reset_say_nothing() -> None:
    uptake = EstimateUptake()
    for k in range(50):
        uptake.sent(k * 0.1)
    assert not uptake.ignored(4.9)  # the autopilot sends no SYS_STATUS: no claim
    uptake.status("absent", 4.9)
    assert uptake.ignored(4.9)
    uptake.reset()
    assert not uptake.ignored(4.9)
