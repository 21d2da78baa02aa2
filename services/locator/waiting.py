"""Pings wait for the ASV pose that covers them: a late pose is not a refused fix.

The ASV's pose comes from another process, often another computer, and can arrive after the
ping it must be matched with (a busy CPU, a slow link); located at once such a ping is refused
(`asv_pose_too_new`) and the mission pauses for nothing. So a ping whose stamp lies past the
newest pose (beyond the extrapolation allowed) waits, up to `wait_s` after it arrived, for a
pose that covers it. Pings leave in the order they came (the tracker needs time in order): one
behind a waiting ping waits with it. Past its deadline a ping is located as it is, and refused
as before.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable

from capsd.payloads import SonarDetections


class PoseWait:
    """Pings in, pings out in order once their pose is in (or their wait is over).

    `offer` each ping as it arrives and `poll` on every pose and now and then; `release` gets
    each ping once, with the wall-clock time (ns) it was received.
    """

    def __init__(
        self,
        *,
        wait_s: float,
        covered: Callable[[int], bool],
        release: Callable[[SonarDetections, int], None],
    ):
        self.wait_s = wait_s
        self._covered = covered
        self._release = release
        self._queue: deque[tuple[float, int, SonarDetections]] = deque()
        self._lock = threading.Lock()
        self.waited = 0  # pings that waited and then had their pose
        self.expired = 0  # pings that waited in vain (located without it)

    def offer(self, detections: SonarDetections, *, now_s: float, received_ns: int) -> None:
        with self._lock:
            self._queue.append((now_s, received_ns, detections))
            self._flush(now_s)

    def poll(self, now_s: float) -> None:
        with self._lock:
            self._flush(now_s)

    def _flush(self, now_s: float) -> None:
        while self._queue:
            arrived_s, received_ns, detections = self._queue[0]
            ready = self._covered(detections.stamp_ns)
            late = now_s - arrived_s >= self.wait_s
            if not (ready or late):
                return
            self._queue.popleft()
            if now_s > arrived_s:  # it did wait
                if ready:
                    self.waited += 1
                else:
                    self.expired += 1
            self._release(detections, received_ns)
