"""`capsd live-view`: a Foxglove WebSocket server a person opens to watch the site live.

Channels (open ws://HOST:PORT in Foxglove):
- every CAP-SD JSON payload on the site's keys, one channel per key, with its JSON Schema
  (fixes, poses, detections, depth, Health of every service...);
- `/capsd/sonar_fan`: the newest sonar frame as a fan with that ping's detections (PNG,
  at most `fan_hz`, so a 40 Hz sonar does not flood a laptop's link);
- `/capsd/tank_map`: the tank from above with the ASV (red) and the ROV's estimate (green),
  at 1 Hz.
Bad payloads are counted (and shown in the console), never forwarded.
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from typing import Any

import cv2
import msgspec
import numpy as np
import zenoh

from capsd.codec import SCHEMAS, decode_any, split_encoding, to_builtins
from capsd.errors import PayloadError
from capsd.keys import is_concrete
from capsd.payloads import AsvPose, RovFix, SonarDetections, SonarFrame


class LiveView:
    """Zenoh samples in, Foxglove channels out."""

    def __init__(self, *, site: str, tank_length_m: float, tank_width_m: float, fan_hz: float):
        import foxglove
        from foxglove.channels import CompressedImageChannel

        self.foxglove = foxglove
        self.site = site
        self.tank = (tank_length_m, tank_width_m)
        self.fan_period_s = 1.0 / fan_hz
        self.channels: dict[str, Any] = {}
        self.fan = CompressedImageChannel("/capsd/sonar_fan")
        self.map = CompressedImageChannel("/capsd/tank_map")
        self.lock = threading.Lock()
        self.counts: Counter[str] = Counter()
        self.frame: SonarFrame | None = None
        self.detections: dict[int, SonarDetections] = {}
        self.asv: AsvPose | None = None
        self.rov: RovFix | None = None
        self._last_fan = 0.0
        self._last_map = 0.0
        self.last_error = ""

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
            self._forward(key, encoding, payload)
        except Exception as exc:  # a viewer must never take the bus callback down
            self.counts["forward_errors"] += 1
            self.last_error = f"{key}: {exc}"

    def _forward(self, key: str, encoding: str, payload: Any) -> None:
        with self.lock:
            self.counts["samples"] += 1
            if isinstance(payload, SonarFrame):
                self.frame = payload
            else:
                if isinstance(payload, SonarDetections):
                    self.detections[payload.ping_id] = payload
                    if len(self.detections) > 50:
                        del self.detections[min(self.detections)]
                elif isinstance(payload, AsvPose):
                    self.asv = payload
                elif isinstance(payload, RovFix) and payload.quality == "good":
                    self.rov = payload
                self._json(key, encoding, payload)

    def _json(self, key: str, encoding: str, payload: Any) -> None:
        channel = self.channels.get(key)
        if channel is None:
            _, schema_name = split_encoding(encoding)
            cls = SCHEMAS[schema_name or ""]
            schema = self.foxglove.Schema(
                name=cls.__name__,
                encoding="jsonschema",
                data=msgspec.json.encode(msgspec.json.schema(cls)),
            )
            channel = self.foxglove.Channel(key, schema=schema, message_encoding="json")
            self.channels[key] = channel
        channel.log(to_builtins(payload), log_time=payload.stamp_ns)

    def tick(self) -> None:
        """Draw the fan and the map when due (called from the main loop)."""
        from foxglove.schemas import CompressedImage, Timestamp

        now = time.monotonic()
        with self.lock:
            frame = self.frame
            detections = self.detections.get(frame.ping_id) if frame is not None else None
            asv, rov = self.asv, self.rov
        if frame is not None and now - self._last_fan >= self.fan_period_s:
            from services.sonar_detect.fan import fan_with_overlays

            self._last_fan = now
            image = fan_with_overlays(frame, None, detections)
            self.fan.log(
                CompressedImage(
                    timestamp=Timestamp.from_epoch_secs(frame.stamp_ns / 1e9),
                    frame_id="sonar",
                    data=_png(image),
                    format="png",
                )
            )
            self.counts["fan_images"] += 1
        if now - self._last_map >= 1.0:
            self._last_map = now
            self.map.log(
                CompressedImage(
                    timestamp=Timestamp.from_epoch_secs(time.time()),
                    frame_id="tank",
                    data=_png(self._map_image(asv, rov)),
                    format="png",
                )
            )
            self.counts["map_images"] += 1

    def _map_image(self, asv: AsvPose | None, rov: RovFix | None) -> Any:
        from simulator.render import top_view
        from simulator.world import Tank

        length, width = self.tank
        tank = Tank("site", length, width, 8.0, 1.0)
        asv_xy = np.array([asv.position_m[:2]]) if asv is not None else np.zeros((1, 2))
        position = (rov.position_m or rov.raw_position_m) if rov is not None else None
        rov_xy = np.array([position[:2]]) if position is not None else np.zeros((1, 2))
        return top_view(tank, rov_xy, asv_xy, px_per_m=20.0)


def _png(image: Any) -> bytes:
    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise ValueError("PNG encoding failed")
    return bytes(data.tobytes())


def serve(
    session: zenoh.Session,
    *,
    site: str,
    host: str,
    port: int,
    tank_length_m: float,
    tank_width_m: float,
    fan_hz: float,
    stop: threading.Event,
    on_status: Any = None,
) -> Counter[str]:
    """Serve until `stop`; returns what was forwarded."""
    import foxglove

    view = LiveView(
        site=site, tank_length_m=tank_length_m, tank_width_m=tank_width_m, fan_hz=fan_hz
    )
    server = foxglove.start_server(name=f"capsd {site}", host=host, port=port)
    subscriber = session.declare_subscriber(f"cap/{site}/**", view.on_sample)
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
        subscriber.undeclare()
        server.stop()
    return view.counts
