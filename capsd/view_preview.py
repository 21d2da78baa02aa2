"""`capsd render view`: the layout's panels drawn from a recording's `/capsd/...` messages.

Not a screenshot of a viewer (none runs here): a PNG drawn by capsd from the very messages a
viewer would get, through their transform chain, so what the 3D panel would show (tank and
fixtures, trails, the fix's covariance, the sonar's field of view placed by tank -> asv ->
sonar, the LiDAR scan) can be looked at, with the fan image and the fix's x/y/z plots beside it.
"""

from __future__ import annotations

import base64
import json
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np

from capsd.errors import CapsdError
from capsd.geometry import quat_to_matrix
from capsd.recording import read
from capsd.scene import ASV_TRAIL, FIX, LIDAR, ROV_TRAIL, SONAR_FAN, SONAR_FOV, TANK, TF


def _pose(pose: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    p, q = pose["position"], pose["orientation"]
    return quat_to_matrix(np.array([q["x"], q["y"], q["z"], q["w"]])), np.array(
        [p["x"], p["y"], p["z"]]
    )


def _points(items: list[dict[str, float]]) -> np.ndarray:
    return np.array([[v["x"], v["y"], v["z"]] for v in items]).reshape(-1, 3)


def _at(stamp: dict[str, int]) -> int:
    return int(stamp["sec"]) * 1_000_000_000 + int(stamp["nsec"])


def render(recording: Path, out: Path, *, fix_key: str | None = None) -> dict[str, int]:
    """Draw the recording's view at its last fix; returns how many messages of each it used."""
    tf: dict[str, tuple[str, np.ndarray, np.ndarray]] = {}
    entities: dict[str, dict[str, Any]] = {}
    trails: dict[str, list[dict[str, Any]]] = {}
    scan: dict[str, Any] | None = None
    fan: bytes | None = None
    fixes: list[tuple[int, list[float]]] = []
    used: dict[str, int] = {}
    for m in read(recording):
        if m.key.startswith("/capsd/"):
            used[m.key] = used.get(m.key, 0) + 1
            body = json.loads(m.data)
            if m.key == TF:
                for t in body["transforms"]:
                    r = quat_to_matrix(np.array([t["rotation"][k] for k in "xyzw"]))
                    p = np.array([t["translation"][k] for k in "xyz"])
                    tf[t["child_frame_id"]] = (t["parent_frame_id"], r, p)
            elif m.key in (TANK, FIX, SONAR_FOV):
                for e in body["entities"]:
                    entities[e["id"]] = e
            elif m.key in (ASV_TRAIL, ROV_TRAIL):
                trails[m.key] = body["poses"]
            elif m.key == LIDAR:
                scan = body
            elif m.key == SONAR_FAN:
                fan = base64.b64decode(body["data"])
        elif m.key.endswith("/locator/fix") and (fix_key is None or m.key == fix_key):
            fix = json.loads(m.data)
            position = fix.get("position_m") or fix.get("raw_position_m")
            if fix.get("quality") == "good" and position:
                fixes.append((fix["stamp_ns"], position))
    if "tank" not in entities:
        raise CapsdError(f"{recording}: no /capsd/tank (recorded without --view on?)")

    def to_tank(frame: str, points: np.ndarray) -> np.ndarray:
        while frame != "tank":
            if frame not in tf:
                return np.full_like(points, np.nan)
            parent, r, p = tf[frame]
            points = points @ r.T + p
            frame = parent
        return points

    fig = plt.figure(figsize=(16, 9))
    grid = fig.add_gridspec(3, 3, width_ratios=(2.2, 1.2, 1.2))
    ax = fig.add_subplot(grid[:, 0], projection="3d")
    for entity in entities.values():
        frame = entity["frame_id"]
        for line in entity["lines"]:
            r, p = _pose(line["pose"])
            pts = to_tank(frame, _points(line["points"]) @ r.T + p)
            c = line["color"]
            for a, b in zip(pts[0::2], pts[1::2], strict=False):
                ax.plot(*zip(a, b, strict=True), color=(c["r"], c["g"], c["b"]), lw=0.8)
        for cube in entity["cubes"]:
            r, p = _pose(cube["pose"])
            s = cube["size"]
            corners = np.array(
                [[sx * s["x"], sy * s["y"], sz * s["z"]] for sx in (-0.5, 0.5)
                 for sy in (-0.5, 0.5) for sz in (-0.5, 0.5)]
            )  # fmt: skip
            pts = to_tank(frame, corners @ r.T + p)
            c = cube["color"]
            for i in range(8):
                for j in range(i + 1, 8):
                    if bin(i ^ j).count("1") == 1:
                        ax.plot(*zip(pts[i], pts[j], strict=True), lw=0.6,
                                color=(c["r"], c["g"], c["b"]))  # fmt: skip
        for sphere in entity["spheres"]:
            r, p = _pose(sphere["pose"])
            s = sphere["size"]
            u, v = np.mgrid[0 : 2 * np.pi : 16j, 0 : np.pi : 8j]
            unit = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], -1)
            pts = (unit * [s["x"] / 2, s["y"] / 2, s["z"] / 2]).reshape(-1, 3) @ r.T + p
            pts = to_tank(frame, pts)
            ax.plot(pts[:, 0], pts[:, 1], pts[:, 2], color="green", lw=0.4)
    for topic, colour in ((ASV_TRAIL, "red"), (ROV_TRAIL, "blue")):
        pts = _points([p["position"] for p in trails.get(topic, [])])
        if len(pts):
            ax.plot(pts[:, 0], pts[:, 1], pts[:, 2], color=colour, lw=1.5, label=topic)
    if scan is not None:
        ranges = np.array(scan["ranges"])
        angles = np.linspace(scan["start_angle"], scan["end_angle"], len(ranges))
        local = np.column_stack([ranges * np.cos(angles), ranges * np.sin(angles),
                                 np.zeros_like(ranges)])[ranges > 0]  # fmt: skip
        pts = to_tank(scan["frame_id"], local)
        ax.scatter(pts[:, 0], pts[:, 1], pts[:, 2], s=1, color="orange", label=LIDAR)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.set_title(
        "3D panel: /capsd/tank, /capsd/fix, /capsd/sonar_fov, /capsd/tf, trails, /capsd/lidar"
    )
    ax.legend(loc="upper left", fontsize=7)
    ax.set_box_aspect((2.0, 1.2, 0.6))
    ax.view_init(elev=35, azim=-60)
    image_ax = fig.add_subplot(grid[:, 1])
    if fan is not None:
        import cv2

        decoded = cv2.imdecode(np.frombuffer(fan, np.uint8), cv2.IMREAD_COLOR)
        if decoded is not None:
            image_ax.imshow(decoded[:, :, ::-1])
    image_ax.set_title("Image panel: /capsd/sonar_fan")
    image_ax.axis("off")
    if fixes:
        t0 = fixes[0][0]
        t = np.array([(s - t0) / 1e9 for s, _ in fixes])
        xyz = np.array([p for _, p in fixes])
        for k in range(3):
            plot = fig.add_subplot(grid[k, 2])
            plot.plot(t, xyz[:, k], lw=0.8)
            plot.set_ylabel(f"fix {'xyz'[k]} (m)")
            plot.grid(alpha=0.3)
        plot.set_xlabel("time (s)")
    fig.suptitle(f"{recording.name}: the layout's panels, drawn by capsd from the recording "
                 "(not a viewer's screenshot)")  # fmt: skip
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return used


__all__ = ["render"]
