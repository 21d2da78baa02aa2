"""The runnable services by name, imported lazily so a light install never loads the rest."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, cast

from capsd.config import ServiceConfig


@dataclass(frozen=True)
class ServiceEntry:
    """Where a service lives: its module exposes `Config` (a ServiceConfig) and `main(config)`."""

    name: str
    module: str
    summary: str

    def load(self) -> tuple[type[ServiceConfig], Callable[[Any], int]]:
        module = importlib.import_module(self.module)
        return cast(type[ServiceConfig], module.Config), cast(Callable[[Any], int], module.main)


SERVICES: dict[str, ServiceEntry] = {
    entry.name: entry
    for entry in (
        ServiceEntry(
            "asv_pose",
            "capsd.services.asv_pose.service",
            "ASV pose from IMU and LiDAR (tilt filter, scan matching)",
        ),
        ServiceEntry(
            "tim5xx",
            "capsd.services.asv_pose.tim5xx",
            "SICK TiM5xx LiDAR client (CoLa-A): scans onto the bus",
        ),
        ServiceEntry(
            "ros_input",
            "capsd.services.asv_pose.ros_input",
            "ROS 2 LaserScan/Imu/pose over rmw_zenoh (CDR) onto the bus",
        ),
        ServiceEntry(
            "locator",
            "capsd.services.locator.service",
            "CAP-SD fix from detections, ASV pose and ROV depth",
        ),
        ServiceEntry(
            "mav_bridge",
            "capsd.services.mav_bridge.service",
            "ArduSub telemetry onto the bus, gated estimates into ArduSub",
        ),
        ServiceEntry(
            "asv_follow",
            "capsd.services.asv_follow.service",
            "ASV follower: GUIDED targets that keep the ROV in the sonar's view",
        ),
        ServiceEntry(
            "oculus",
            "capsd.services.sonar_detect.driver",
            "Oculus multibeam driver: sonar frames onto the bus",
        ),
        ServiceEntry(
            "sonar_detect",
            "capsd.services.sonar_detect.service",
            "ROV detection in sonar frames (polar CNN, or classical CFAR)",
        ),
        ServiceEntry(
            "sonar_replay",
            "capsd.sonar_replay",
            "recorded sonar frames (Oculus bytes or a dataset) onto the bus, paced",
        ),
        ServiceEntry(
            "sim",
            "capsd.simulator.service",
            "simulated tank: ASV pose, ROV depth/attitude, detections, truth",
        ),
    )
}

# Shipped configs named for their role rather than their service (deploy/config, deploy/roles).
CONFIG_SERVICE = {"asv_bridge": "mav_bridge"}


def service_of_config(stem: str) -> ServiceEntry:
    """The service a shipped config file (by its name without .yaml) configures."""
    return SERVICES[CONFIG_SERVICE.get(stem, stem)]
