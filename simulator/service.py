"""The simulator in real time: publishes every stream on the keys real drivers use.

Paced by the wall clock: an event is generated ahead on its own thread and published when its
sim time comes. Each stream's count, CPU time (generation on the look-ahead thread and
publishing) and worst lateness are reported in the service's Health counters, which
`capsd bench sim` reads. With `guided` set, the simulator also hosts the ArduSub stand-in the
bridge connects to: the stand-in reports the simulated ROV's attitude and depth, and its GUIDED
targets, modes and the estimates it receives fly the ROV (capsd.simulator.guided). With
`asv_mode: guided`, likewise an ArduRover stand-in for the ASV's bridge drives the ASV.
"""

from __future__ import annotations

import contextlib
import logging
import math
import queue
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from capsd import topics
from capsd.logs import log_fields
from capsd.ned import TankToNed
from capsd.payloads import Payload, SimControl, SonarFrame
from capsd.protocols.mavlink import PositionTarget, VisionPositionEstimate
from capsd.runner import Publisher, ServiceRunner
from capsd.simulator.autopilot import (
    CONFIGURED_PARAMS,
    ROVER_CONFIGURED_PARAMS,
    AutopilotStandIn,
    VehicleState,
)
from capsd.simulator.config import Config
from capsd.simulator.guided import GuidedAsv, GuidedRov
from capsd.simulator.sim import Event, Simulation
from capsd.simulator.tilt_servo import TiltServo

__all__ = ["Config", "main"]

logger = logging.getLogger(__name__)


class _Accounting:
    """Per-stream counters: messages, CPU microseconds, worst lateness (ms)."""

    def __init__(self) -> None:
        self.counts: dict[str, int] = defaultdict(int)
        self.cpu_us: dict[str, int] = defaultdict(int)
        self.late_ms: dict[str, int] = defaultdict(int)

    def add(self, stream: str, cpu_ns: int, late_s: float) -> None:
        self.counts[stream] += 1
        self.cpu_us[stream] += cpu_ns // 1000
        self.late_ms[stream] = max(self.late_ms[stream], int(late_s * 1000))

    def counters(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for stream, count in self.counts.items():
            out[f"{stream}:count"] = count
            out[f"{stream}:cpu_us"] = self.cpu_us[stream]
            out[f"{stream}:late_max_ms"] = self.late_ms[stream]
        return out


# How far ahead of its time the world is made. A sonar ping takes ~10 ms to render (more on
# a busy machine): made ahead, it is put when it is due, not a render late. But what the
# vehicles are told reaches only the world not made yet: made 64 events ahead (about 200 ms
# of the mockup's streams), a pan servo commanded to turn was still in the pings 200 ms later
# while its autopilot reported the new angle at once (a mockup demo: the sonar's look stepped
# 4-9 deg at each of the follower's commands, 5 Hz; its fixes refused off the track, 4.5 % of
# pings). A real mount turns a servo period or two after the command (20-40 ms).
AHEAD_S = 0.03


class _Lookahead(threading.Thread):
    """Events generated ahead of their time on a thread of their own (see AHEAD_S).

    At most `depth` events and `ahead_s` ahead of `now_s()` (sim seconds).
    """

    def __init__(
        self,
        events: Iterator[Event],
        stop: threading.Event,
        *,
        now_s: Callable[[], float],
        ahead_s: float = AHEAD_S,
        depth: int = 64,
    ):
        super().__init__(name="sim-lookahead", daemon=True)
        self._events = events
        self._stop_event = stop
        self._now_s = now_s
        self._ahead_s = ahead_s
        self._queue: queue.Queue[tuple[Event, int]] = queue.Queue(maxsize=depth)
        self._head: tuple[Event, int] | None = None
        self.failure: BaseException | None = None

    def run(self) -> None:
        try:
            while not self._stop_event.is_set():
                cpu = time.thread_time_ns()
                event = next(self._events)
                item = (event, time.thread_time_ns() - cpu)
                while not self._stop_event.is_set():
                    try:
                        self._queue.put(item, timeout=0.1)
                        break
                    except queue.Full:
                        continue
                # The next event is made no earlier than `ahead_s` before this one is due.
                early_s = event.t_s - self._ahead_s - self._now_s()
                if early_s > 0.0:
                    self._stop_event.wait(early_s)
        except BaseException as exc:  # handed to the publishing loop, which reports it
            self.failure = exc

    def due(self, now_s: float) -> tuple[Event, int] | None:
        """The next event if its time has come (with its generation CPU ns), else None."""
        if self._head is None:
            try:
                self._head = self._queue.get_nowait()
            except queue.Empty:
                if self.failure is not None:
                    raise RuntimeError(f"the simulation stopped: {self.failure}") from None
                return None
        if self._head[0].t_s > now_s:
            return None
        item, self._head = self._head, None
        return item


def _sim_clock(start_ns: int) -> Callable[[float], float]:
    """Sim time of a Unix time (s): sim time 0 is wall time `start_ns`."""
    return lambda unix_s: max(0.0, unix_s - start_ns / 1e9)


def hosted_autopilot(config: Config, rov: GuidedRov, start_ns: int) -> AutopilotStandIn:
    """The ArduSub stand-in that flies `rov` (sim time 0 is wall time `start_ns`)."""
    assert config.guided is not None
    g = config.guided
    ned = TankToNed(math.radians(g.ned_heading_deg), np.array(g.ned_origin_m))
    sim_time = _sim_clock(start_ns)

    def vehicle(unix_s: float) -> VehicleState:
        state = rov.state(sim_time(unix_s))
        roll, pitch, yaw = ned.attitude_to_ned(state.rotation)
        north, east, _ = ned.position(state.position_m)
        depth = -float(state.position_m[2])
        return VehicleState(roll, pitch, yaw, depth, float(north), float(east))

    def on_target(target: PositionTarget) -> None:
        rov.set_target(
            ned.position_to_tank(np.array([target.north_m, target.east_m, target.down_m]))
        )

    def on_estimate(estimate: VisionPositionEstimate) -> None:
        measured_s = sim_time(estimate.usec / 1e6)
        rov.on_estimate(
            measured_s, ned.position_to_tank(np.array([estimate.x, estimate.y, estimate.z]))
        )

    return AutopilotStandIn(
        g.port,
        state=vehicle,
        params=CONFIGURED_PARAMS,
        mode="MANUAL",
        water_temperature_c=config.water_temperature_c,
        on_mode=rov.set_mode,
        on_target=on_target,
        on_estimate=on_estimate,
    )


def hosted_asv_autopilot(
    config: Config, asv: GuidedAsv, start_ns: int, *, servo: TiltServo | None = None
) -> AutopilotStandIn:
    """The ArduRover stand-in that drives `asv` and the sonar's tilt `servo` (if any).

    Sim time 0 is wall time `start_ns`.
    """
    assert config.asv_guided is not None
    g = config.asv_guided
    ned = TankToNed(math.radians(g.ned_heading_deg), np.array(g.ned_origin_m))
    sim_time = _sim_clock(start_ns)

    def vehicle(unix_s: float) -> VehicleState:
        rotation, position = asv.pose(sim_time(unix_s))
        roll, pitch, yaw = ned.attitude_to_ned(rotation)
        north, east, _ = ned.position(position)
        return VehicleState(roll, pitch, yaw, 0.0, float(north), float(east))

    def on_target(target: PositionTarget) -> None:
        if target.position_ignored:
            if target.yaw_rad is not None:
                r_w_b = ned.attitude_to_tank(0.0, 0.0, target.yaw_rad)
                asv.set_heading(math.atan2(float(r_w_b[1, 0]), float(r_w_b[0, 0])))
            return
        ned_m = np.array([target.north_m, target.east_m, target.down_m])
        asv.set_target(ned.position_to_tank(ned_m))

    def on_estimate(estimate: VisionPositionEstimate) -> None:
        asv.on_estimate(
            sim_time(estimate.usec / 1e6),
            ned.position_to_tank(np.array([estimate.x, estimate.y, estimate.z])),
        )

    return AutopilotStandIn(
        g.port,
        state=vehicle,
        params=ROVER_CONFIGURED_PARAMS,
        mode=g.mode,
        autopilot="ardurover",
        on_mode=asv.set_mode,
        on_target=on_target,
        on_estimate=on_estimate,
        on_direction=asv.set_direction,
        on_gimbal_pitch=(
            None
            if servo is None
            else lambda pitch_deg, yaw_deg: servo.command(sim_time(time.time()), pitch_deg, yaw_deg)
        ),
        gimbal_pitch_rad=None if servo is None else servo.reported_pitch_rad,
        gimbal_yaw_rad=None if servo is None else servo.reported_yaw_rad,
    )


def main(config: Config) -> int:
    """Run the simulator in real time until stopped."""
    simulation = Simulation(config)
    accounting = _Accounting()
    with ServiceRunner("sim", config) as runner:
        runner.add_counters(accounting.counters)
        # The stand-in sonar's own latency, ping to frame put (a real one adds echo travel).
        sonar_lag = runner.latency("sonar frame put after ping")
        publishers: dict[str, Publisher[Any]] = {}
        start_ns = time.time_ns()
        start = time.monotonic()
        # A ping whose time has passed by more than one period when its turn to render comes
        # is skipped (counted, warned), so the world holds real time instead of lagging.
        period_s = 1.0 / config.rates.sonar_hz
        simulation.too_late = lambda t_s: time.monotonic() - start - t_s > period_s
        runner.add_counters(lambda: {"skipped_late_pings": simulation.skipped_pings})
        warned = {"skipped": 0}

        def warn_skips() -> None:
            if simulation.skipped_pings > warned["skipped"]:
                runner.report_error(
                    f"the world is late: {simulation.skipped_pings} sonar pings skipped so far "
                    "(rendering cannot keep up at this rate on this machine)",
                    kind="late pings",
                )
                warned["skipped"] = simulation.skipped_pings

        ahead = _Lookahead(
            simulation.events(start_ns=start_ns),
            runner.stop_event,
            now_s=lambda: time.monotonic() - start,
        )
        ahead.start()
        autopilot = contextlib.ExitStack()
        guided = simulation.guided
        if guided is not None:
            autopilot.enter_context(hosted_autopilot(config, guided, start_ns))
            runner.add_counters(lambda: {"rov_in_guided": int(guided.mode == "GUIDED")})
        guided_asv = simulation.guided_asv
        if guided_asv is not None:
            autopilot.enter_context(
                hosted_asv_autopilot(config, guided_asv, start_ns, servo=simulation.tilt_servo)
            )
            runner.add_counters(lambda: {"asv_in_guided": int(guided_asv.mode == "GUIDED")})
        muted_until: dict[str, float] = {}  # stream -> monotonic time its dropout ends

        def on_control(control: SimControl) -> None:
            until = time.monotonic() + control.for_s
            for stream in control.mute:
                muted_until[stream] = until
            logger.warning(
                "dropout injected",
                extra=log_fields(streams=",".join(control.mute), s=control.for_s),
            )

        runner.subscribe(topics.SIM_CONTROL, on_control)
        muted = {"count": 0}
        runner.add_counters(lambda: {"muted_messages": muted["count"]})

        def step() -> None:
            warn_skips()
            while (item := ahead.due(time.monotonic() - start)) is not None:
                event, event_cpu_ns = item
                cpu0 = time.thread_time_ns()
                stream = f"{event.topic.subject.value}@{event.vehicle}"
                if muted_until.get(stream, 0.0) > time.monotonic():
                    muted["count"] += 1
                    continue
                publisher = publishers.get(stream)
                if publisher is None:
                    publisher = publishers[stream] = runner.publisher(
                        event.topic, vehicle=event.vehicle
                    )
                payload: Payload = event.payload
                publisher.put(payload)
                if isinstance(payload, SonarFrame):
                    sonar_lag.record_ns(time.time_ns() - payload.stamp_ns)
                late = time.monotonic() - start - event.t_s
                accounting.add(stream, event_cpu_ns + time.thread_time_ns() - cpu0, late)

        try:
            with autopilot:
                runner.run(step, period_s=0.002)
        finally:
            runner.stop_event.set()
            ahead.join(timeout=2.0)
    return 0
