"""The live view serves Foxglove's WebSocket protocol; a client sees and receives the channels."""

from __future__ import annotations

import asyncio
import base64
import json
import struct
from collections.abc import Callable

import pytest
import websockets

from capsd.viewer_schema import viewer_rules
from tests.conftest import Proc, free_port

pytestmark = pytest.mark.integration


async def _client(port: int) -> tuple[dict[str, dict[str, object]], bytes]:
    url = f"ws://127.0.0.1:{port}"
    for _ in range(50):  # the server starts after the process joins the bus
        try:
            ws = await websockets.connect(
                url,
                subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"],  # type: ignore[list-item]
            )
            break
        except OSError:
            await asyncio.sleep(0.2)
    else:
        raise AssertionError("the live view never listened")
    channels: dict[str, dict[str, object]] = {}
    async with ws:
        deadline = asyncio.get_running_loop().time() + 30
        subscribed = False
        while asyncio.get_running_loop().time() < deadline:
            message = await asyncio.wait_for(ws.recv(), timeout=30)
            if isinstance(message, str):
                body = json.loads(message)
                if body.get("op") == "advertise":
                    for channel in body["channels"]:
                        channels[channel["topic"]] = channel
                wanted = {"/capsd/sonar_fan", "/capsd/tank_map", "cap/tank/sim/health/sim",
                          "/capsd/tank", "/capsd/lidar"}  # fmt: skip
                if not subscribed and wanted <= set(channels):
                    fan = channels["/capsd/sonar_fan"]["id"]
                    await ws.send(
                        json.dumps(
                            {"op": "subscribe", "subscriptions": [{"id": 7, "channelId": fan}]}
                        )
                    )
                    subscribed = True
            elif subscribed and message[0] == 1:  # message data: op, subscription id, time
                (subscription,) = struct.unpack_from("<I", message, 1)
                assert subscription == 7
                return channels, bytes(message[13:])
    raise AssertionError(f"no fan image; channels seen: {sorted(channels)}")


def test_live_view_serves_the_channels(
    spawn: Callable[..., Proc], router: Proc, endpoint: str
) -> None:
    spawn("run", "sim", "--config", "deploy/config/sim.yaml", "--connect", endpoint)
    port = free_port()
    spawn("live-view", "--port", str(port), "--connect", endpoint)
    channels, payload = asyncio.run(_client(port))
    assert channels["cap/tank/rov/rov/depth"]["encoding"] == "json"
    assert channels["cap/tank/rov/rov/depth"]["schemaName"]
    # Every JSON channel's schema is one viewers accept (Lichtblick's parser's rules).
    for topic, channel in channels.items():
        if channel["encoding"] == "json":
            assert viewer_rules(json.loads(str(channel["schema"]))) == [], topic
    # The operator's scene, in Foxglove's own schemas (its 3D and Image panels take them).
    for scene in ("/capsd/tank", "/capsd/fix", "/capsd/sonar_fov"):
        assert channels[scene]["schemaName"] == "foxglove.SceneUpdate", scene
    assert channels["/capsd/lidar"]["schemaName"] == "foxglove.LaserScan"
    assert channels["/capsd/sonar_fan"]["schemaName"] == "foxglove.CompressedImage"
    # A CompressedImage carrying a JPEG (JSON: the bytes in base64).
    image = json.loads(payload)
    assert image["format"] == "jpeg"
    assert base64.b64decode(image["data"])[:3] == b"\xff\xd8\xff"
