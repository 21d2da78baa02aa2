from __future__ import annotations

from capsd.payloads import SonarFrame, SonarLabel
from capsd.simulator.config import OFFLINE_START_NS, Config, Rates, Streams
from capsd.simulator.sim import Simulation


def test_pings_too_late_to_render_are_skipped_not_sent_late() -> None:
    config = Config(
        rates=Rates(sonar_hz=10.0),
        streams=Streams(
            lidar="off", imu="off", asv_pose_truth_noise="off", detections_truth_noise="off"
        ),
    )
    sim = Simulation(config, horizon_s=10.0)
    # The world falls behind after 1 s of sim time (as a busy machine would make it).
    sim.too_late = lambda t_s: t_s > 1.0
    events = list(sim.events(start_ns=OFFLINE_START_NS, duration_s=3.0))
    frames = [e for e in events if isinstance(e.payload, SonarFrame)]
    labels = [e for e in events if isinstance(e.payload, SonarLabel)]
    assert frames
    assert all(e.t_s <= 1.0 for e in frames + labels)
    assert sim.skipped_pings == 20  # 1.1 .. 3.0 s at 10 Hz
    # The other streams go on: the ROV's depth is still published after 1 s.
    assert any(e.t_s > 2.0 for e in events if e.topic.subject.value == "rov/depth")
