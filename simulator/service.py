"""Real-time simulator service at detection level: publishes what the real services would.

Streams (each stamped at its measurement instant): ASV pose and sonar detections (`asv`), ROV
depth and attitude (`rov`), ground truth (own vehicle, default `sim`). Noise models: pose
position N(0, pose_sigma_m) per axis; detection range N(0, range_sigma_m) and azimuth
N(0, azimuth_sigma_deg); depth N(0, depth_sigma_m) on the pressure sensor, which sits at the
configured lever arm from the ROV centre. The image-forming sonar simulator is issue 3.
"""

from __future__ import annotations

import time
from typing import Any

from capsd.payloads import Payload
from capsd.runner import Publisher, ServiceRunner
from simulator.config import Config
from simulator.sim import Simulation

__all__ = ["Config", "main"]


def main(config: Config) -> int:
    """Run the simulator in real time until stopped."""
    simulation = Simulation(config)
    with ServiceRunner("sim", config) as runner:
        publishers: dict[str, Publisher[Any]] = {}
        start_ns = time.time_ns()
        start = time.monotonic()
        events = simulation.events(start_ns=start_ns)
        pending = next(events)

        def step() -> None:
            nonlocal pending
            elapsed = time.monotonic() - start
            while pending.t_s <= elapsed:
                key = pending.topic.key(config.site, pending.vehicle)
                publisher = publishers.get(key)
                if publisher is None:
                    publisher = publishers[key] = runner.publisher(
                        pending.topic, vehicle=pending.vehicle
                    )
                payload: Payload = pending.payload
                publisher.put(payload)
                pending = next(events)

        runner.run(step, period_s=0.005)
    return 0
