"""The simulator in real time: publishes every stream on the keys real drivers use.

Paced by the wall clock: an event is published when its sim time comes. Each stream's count,
CPU time (generation and publishing, on this thread) and worst lateness are reported in the
service's Health counters, which `capsd bench sim` reads.
"""

from __future__ import annotations

import time
from collections import defaultdict
from typing import Any

from capsd.payloads import Payload, SonarFrame
from capsd.runner import Publisher, ServiceRunner
from simulator.config import Config
from simulator.sim import Event, Simulation

__all__ = ["Config", "main"]


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
        events = simulation.events(start_ns=start_ns)
        cpu = time.thread_time_ns()
        pending: Event = next(events)
        pending_cpu = time.thread_time_ns() - cpu

        def step() -> None:
            nonlocal pending, pending_cpu
            while pending.t_s <= time.monotonic() - start:
                cpu0 = time.thread_time_ns()
                stream = f"{pending.topic.subject.value}@{pending.vehicle}"
                publisher = publishers.get(stream)
                if publisher is None:
                    publisher = publishers[stream] = runner.publisher(
                        pending.topic, vehicle=pending.vehicle
                    )
                payload: Payload = pending.payload
                publisher.put(payload)
                if isinstance(payload, SonarFrame):
                    sonar_lag.record_ns(time.time_ns() - payload.stamp_ns)
                late = time.monotonic() - start - pending.t_s
                accounting.add(stream, pending_cpu + time.thread_time_ns() - cpu0, late)
                cpu1 = time.thread_time_ns()
                pending = next(events)
                pending_cpu = time.thread_time_ns() - cpu1

        runner.run(step, period_s=0.002)
    return 0
