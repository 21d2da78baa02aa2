"""`capsd live-view`: a Foxglove WebSocket server a person opens to watch the site live.

Channels (open ws://HOST:PORT in Foxglove; `deploy/foxglove/capsd-layout.json` arranges them):
- every CAP-SD JSON payload on the site's keys, one channel per key, with its JSON Schema in
  the dialect viewers accept (fixes, poses, detections, depth, Health of every service...);
- the operator's scene (capsd.scene, the same derivation `capsd record` writes): transforms,
  the tank with its fixtures, the vehicles, the sonar's field of view, the fix with its
  covariance, trails, the LiDAR scan, the services' logs, the sonar fan as JPEG (at most
  `fan_hz`, so a 40 Hz sonar does not flood a laptop's link) and the tank from above (1 Hz).
The tank and the sonar mount come from the locator's config: the services' own description.
Bad payloads are counted (and shown in the console), never forwarded.
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import zenoh

from capsd import foxglove_messages as fm
from capsd.codec import decode_any, to_builtins
from capsd.errors import PayloadError
from capsd.keys import is_concrete
from capsd.payloads import SonarDetections, SonarFrame
from capsd.scene import TOPIC_TYPES, ImageFormat, SceneView, ViewSettings
from capsd.tank import TankBounds
from capsd.viewer_schema import viewer_schema, without_nulls


def view_settings(
    locator_config: Path | None,
    *,
    asv_pose_config: Path | None = None,
    images: ImageFormat = "jpeg",
    jpeg_quality: int = 75,
    fan_hz: float = 2.0,
) -> ViewSettings:
    """The view of the site the services are configured for (their config files)."""
    from capsd.config import load_config
    from capsd.services.asv_pose.service import Config as AsvPoseConfig
    from capsd.services.locator.service import Config as LocatorConfig

    locator = load_config(locator_config, LocatorConfig) if locator_config else LocatorConfig()
    lidar_xy = (0.0, 0.0)
    if asv_pose_config is not None:
        lidar_xy = load_config(asv_pose_config, AsvPoseConfig).lidar_xy_m
    return ViewSettings(
        tank=locator.tank or TankBounds(),
        sonar=locator.sonar,
        lidar_xy_m=lidar_xy,
        images=images,
        jpeg_quality=jpeg_quality,
        fan_hz=fan_hz,
    )


def make_view(settings: ViewSettings) -> SceneView:
    """The scene derivation with the sonar fan drawn as the detector's tools draw it."""

    def fan(frame: SonarFrame, detections: SonarDetections | None) -> Any:
        from capsd.fan import fan_with_overlays

        return fan_with_overlays(frame, None, detections)

    def tank_map(tank: TankBounds, asv: list[fm.Pose], rov: list[fm.Pose]) -> Any:
        from capsd.simulator.render import top_view
        from capsd.simulator.world import Box, Tank

        site = Tank(
            "site", tank.length_m, tank.width_m, tank.depth_m, 1.0,
            boxes=tuple(Box(f.lo_m, f.hi_m, f.name) for f in tank.fixtures),
        )  # fmt: skip

        def xy(poses: list[fm.Pose]) -> np.ndarray:
            points = [(p.position.x, p.position.y) for p in reversed(poses)]  # newest marked
            return np.array(points) if points else np.full((1, 2), -1000.0)

        return top_view(site, xy(rov), xy(asv), px_per_m=20.0)

    return SceneView(settings, fan=fan, tank_map=tank_map)


class LiveView:
    """Zenoh samples in, Foxglove channels out."""

    def __init__(self, *, site: str, settings: ViewSettings):
        import foxglove

        self.foxglove = foxglove
        self.site = site
        self.settings = settings
        self.scene = make_view(settings)
        self.channels: dict[str, Any] = {}
        self.lock = threading.Lock()
        self.counts: Counter[str] = Counter()
        self.frame: SonarFrame | None = None
        self.last_error = ""
        # The view's own channels exist before any client connects: a channel created while a
        # client is connected is advertised to it in a race with the server's own bookkeeping
        # (foxglove-sdk 0.30: a subscribe sent at once can get "Unknown channel ID").
        for topic, cls in TOPIC_TYPES.items():
            self._channel(topic, cls, fm.SCHEMA_NAMES[cls])

    def on_sample(self, sample: zenoh.Sample) -> None:
        key, encoding = str(sample.key_expr), str(sample.encoding)
        if not is_concrete(key):
            self.counts["wildcard_keys"] += 1
            return
        try:
            payload = decode_any(sample.payload.to_bytes(), encoding=encoding, key_expr=key)
        except PayloadError:
            self.counts["bad_payloads"] += 1
            return
        try:
            self._forward(key, payload)
        except Exception as exc:  # a viewer must never take the bus callback down
            self.counts["forward_errors"] += 1
            self.last_error = f"{key}: {exc}"

    def _forward(self, key: str, payload: Any) -> None:
        with self.lock:
            self.counts["samples"] += 1
            if isinstance(payload, SonarFrame):
                self.frame = payload  # drawn from the main loop, not on the bus's thread
            else:
                self._json(key, payload)
                self._view(self.scene.on_payload(key, payload))

    def _channel(self, topic: str, cls: type[Any], schema_name: str) -> Any:
        """The topic's channel, advertised with its viewer schema on first use."""
        channel = self.channels.get(topic)
        if channel is None:
            schema = self.foxglove.Schema(
                name=schema_name,
                encoding="jsonschema",
                data=msgspec.json.encode(viewer_schema(cls)),
            )
            channel = self.foxglove.Channel(topic, schema=schema, message_encoding="json")
            self.channels[topic] = channel
        return channel

    def _json(self, key: str, payload: Any) -> None:
        cls = type(payload)
        channel = self._channel(key, cls, getattr(cls, "SCHEMA_NAME", cls.__name__))
        channel.log(without_nulls(to_builtins(payload)), log_time=payload.stamp_ns)

    def _view(self, messages: list[tuple[str, Any]]) -> None:
        for topic, message in messages:
            channel = self._channel(topic, type(message), fm.SCHEMA_NAMES[type(message)])
            channel.log(msgspec.to_builtins(message))
            self.counts[topic] += 1

    def tick(self) -> None:
        """Draw the fan and the map when due (called from the main loop)."""
        with self.lock:
            frame, self.frame = self.frame, None
        if frame is not None:
            messages = self.scene.on_payload("", frame)
            with self.lock:
                self._view(messages)


def serve(
    session: zenoh.Session,
    *,
    site: str,
    host: str,
    port: int,
    settings: ViewSettings,
    stop: threading.Event,
    on_status: Any = None,
) -> Counter[str]:
    """Serve until `stop`; returns what was forwarded."""
    import foxglove

    view = LiveView(site=site, settings=settings)
    server = foxglove.start_server(name=f"capsd {site}", host=host, port=port)
    subscribers = [
        session.declare_subscriber(f"cap/{site}/**", view.on_sample),
        session.declare_subscriber(f"services/capsd-{site}-$*/log", view.on_sample),
    ]
    last_status = time.monotonic()
    try:
        while not stop.wait(0.05):
            view.tick()
            if on_status is not None and time.monotonic() - last_status >= 10.0:
                last_status = time.monotonic()
                on_status(
                    {**view.counts, **({"last_error": view.last_error} if view.last_error else {})}
                )
    finally:
        for subscriber in subscribers:
            subscriber.undeclare()
        server.stop()
    return view.counts
