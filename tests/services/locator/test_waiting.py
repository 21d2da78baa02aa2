"""PoseWait: pings wait for their pose, leave in order, and never wait past their deadline."""

from __future__ import annotations

from capsd.payloads import SonarDetections
from capsd.services.locator.waiting import PoseWait


def _ping(stamp_ns: int) -> SonarDetections:
    return SonarDetections(stamp_ns=stamp_ns, seq=0, ping_id=stamp_ns, detector="test")


def test_a_ping_waits_for_its_pose_and_those_behind_it_wait_with_it() -> None:
    newest_pose = [100]
    out: list[int] = []
    wait = PoseWait(
        wait_s=0.3,
        covered=lambda stamp: stamp <= newest_pose[0],
        release=lambda d, _received: out.append(d.stamp_ns),
    )
    wait.offer(_ping(90), now_s=0.0, received_ns=0)  # its pose is in: at once
    assert out == [90]
    wait.offer(_ping(200), now_s=0.0, received_ns=0)
    wait.offer(_ping(150), now_s=0.01, received_ns=0)  # covered sooner, but behind 200
    assert out == [90]
    newest_pose[0] = 160
    wait.poll(0.05)
    assert out == [90]  # 200 still waits, 150 behind it
    newest_pose[0] = 210
    wait.poll(0.1)
    assert out == [90, 200, 150]
    assert (wait.waited, wait.expired) == (2, 0)


def test_a_pose_that_never_comes_releases_the_ping_at_its_deadline() -> None:
    out: list[int] = []
    wait = PoseWait(wait_s=0.3, covered=lambda _s: False,
                    release=lambda d, _r: out.append(d.stamp_ns))  # fmt: skip
    wait.offer(_ping(1), now_s=0.0, received_ns=0)
    wait.poll(0.29)
    assert out == []
    wait.poll(0.3)
    assert out == [1]
    assert wait.expired == 1
    # No wait at all (0 s): located at once, as before this module.
    at_once = PoseWait(wait_s=0.0, covered=lambda _s: False,
                       release=lambda d, _r: out.append(d.stamp_ns))  # fmt: skip
    at_once.offer(_ping(2), now_s=5.0, received_ns=0)
    assert out == [1, 2]
