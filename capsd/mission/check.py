"""`capsd mission check PLAN.yaml`: can the follower keep a plan in view, with how many stops.

Reads the plan and the follower's config (the site's `asv_follow.yaml`: tank, sonar mount,
station rules) or a simulated tank's demo settings, and prints, per leg, the share of the
ROV's path some ASV place sees (and sees with no fixture in the ROV's range cell), the points
no place sees, the fewest stops the ASV needs and the least blind route (capsd.mission.coverage);
`--png` draws them, `--json` writes them (the route's station for every point of the path).
Exit 0 when every point of the path is seen from somewhere, 1 when some is not.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from capsd.launch import EXIT_FAILURE, EXIT_OK
from capsd.mission.coverage import Coverage, coverage
from capsd.mission.plan import Waypoint, load_plan, path_length_m
from capsd.progress import Progress
from capsd.services.asv_follow.service import Config as FollowConfig
from capsd.services.asv_follow.station import StationPlanner


def steps_for(config: FollowConfig) -> tuple[float, float]:
    """(path step, place step) in metres: about 250 places across the tank's shorter side."""
    place = min(max(min(config.tank.length_m, config.tank.width_m) / 64.0, 0.05), 0.5)
    return 2.0 * place, place


def main(
    config: FollowConfig,
    *,
    plan_path: Path,
    png: Path | None,
    stream: TextIO,
    source: str,
    json_out: Path | None = None,
) -> int:
    """Check the plan against the follower's config; see the module docstring."""
    plan, points = load_plan(plan_path, tank=config.tank)
    planner = StationPlanner(
        config.sonar, config.tank, config.motion.drive_settings(config.station.settings())
    )
    path_step, place_step = steps_for(config)
    bars: list[Progress] = []  # made at the first point, when the count is known

    def on_point(done: int, total: int) -> None:
        if not bars:
            bars.append(Progress(total, label="mission check", unit=" points"))
        bars[0].update(done)

    found = coverage(
        planner, points, path_step_m=path_step, place_step_m=place_step, on_point=on_point
    )
    for bar in bars:
        bar.close()
    title = f"{plan.name} ({plan_path})"
    for line in report(found, points, config, title=title, source=source, path_step_m=path_step):
        print(line, file=stream)
    if png is not None:
        draw(found, points, planner, png, title=f"{plan.name}: where the ASV can watch from")
        print(f"figure: {png}", file=stream)
    if json_out is not None:
        json_out.write_text(json.dumps(figures(found, plan.name, source=source), indent=1) + "\n")
        print(f"figures: {json_out}", file=stream)
    return EXIT_OK if bool(found.seen_any.all()) else EXIT_FAILURE


def _rounded(a: np.ndarray) -> list[Any]:
    return np.round(a, 3).tolist()  # type: ignore[no-any-return]


def figures(found: Coverage, name: str, *, source: str) -> dict[str, Any]:
    """The check as JSON: the sampled path, per point what sees it, the stops, the route."""
    route = found.route
    return {
        "plan": name,
        "follower_settings": source,
        "path_m": _rounded(found.path_m),
        "leg": found.leg.tolist(),
        "along_m": _rounded(found.along_m),
        "places_tried": len(found.places_xy),
        "seen": found.seen_any.tolist(),
        "clear": found.clear_any.tolist(),
        "stops": [
            {
                "first": s.first,
                "last": s.last,
                "station_xy_m": list(s.station_xy),
                "masked": s.masked,
                "move_m": round(s.move_m, 3),
                "blind_s": round(s.blind_s, 2),
            }
            for s in found.stretches
        ],
        "route": None
        if route is None
        else {
            "station_xy_m": _rounded(found.places_xy[route.places]),
            "moves": route.moves,
            "blind_s": round(route.blind_s, 2),
            "blind_moves": [{"at": i, "blind_s": round(t, 2)} for i, t in route.blind],
        },
    }


def _xy(p: np.ndarray | tuple[float, ...]) -> str:
    return f"({p[0]:.2f}, {p[1]:.2f})"


def _at(found: Coverage, i: int) -> str:
    """Where path sample `i` lies: on which leg, how far along it."""
    if found.leg[i] == 0:
        return "the first waypoint"
    return f"leg {found.leg[i]} at {found.along_m[i]:.1f} m"


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) of each run of True in `flags`."""
    out: list[tuple[int, int]] = []
    start: int | None = None
    for i, flag in enumerate(flags):
        if flag and start is None:
            start = i
        if not flag and start is not None:
            out.append((start, i - 1))
            start = None
    if start is not None:
        out.append((start, len(flags) - 1))
    return out


def report(
    found: Coverage,
    points: list[Waypoint],
    config: FollowConfig,
    *,
    title: str,
    source: str,
    path_step_m: float,
) -> list[str]:
    """The check's text: the setting, each leg, what no place sees, the fewest stops."""
    sonar = config.sonar
    s = config.station
    clearance = s.wall_clearance_m + s.hull_radius_m + s.tracking_margin_m
    seen, clear = found.seen_any, found.clear_any
    preferred = (
        ""
        if s.preferred_min_range_m is None
        else f" ({s.preferred_min_range_m:g} m or more where a station can keep it)"
    )
    lines = [
        f"mission check: {title}, {len(points)} waypoints, {path_length_m(points):.1f} m of path "
        f"(looked at every {path_step_m:.2f} m or less)",
        f"  follower settings: {source}; sonar {sonar.pitch_deg:g} deg down, "
        f"{sonar.position_m[0]:.2f} m ahead of the ASV's origin, "
        f"{sonar.vertical_aperture_deg:g} deg aperture less {s.elevation_margin_deg:g} deg "
        f"either side, range {s.min_range_m:g}-{s.max_range_m:g} m{preferred}; ASV origin at least "
        f"{clearance:.2f} m off the walls: {len(found.places_xy)} places tried",
        "  leg  from -> to                      length   seen  clear",
    ]
    if len(found.places_xy) == 0:
        lines.insert(
            2,
            f"  NO place in this {config.tank.length_m:g} x {config.tank.width_m:g} m tank is "
            f"{clearance:.2f} m off every wall and clear of keep-out boxes: the ASV has nowhere "
            f"to be",
        )
    for k in range(1, len(points)):
        on = found.leg == k
        a, b = points[k - 1].position_m, points[k].position_m
        lines.append(
            f"  {k:3d}  {_xy(a):>13} -> {_xy(b):<13}  {math.dist(a, b):6.1f} m"
            f"  {100 * seen[on].mean():4.0f} %  {100 * clear[on].mean():4.0f} %"
        )
    lines.append(
        f"  the whole path: seen from some place {100 * seen.mean():.1f} %, with nothing in "
        f"the ROV's range cell {100 * clear.mean():.1f} %"
    )
    unseen = _runs(~seen)
    if unseen:
        lines.append("  NOT seen from any place the ASV may be:")
        lines += [f"    {_at(found, a)} to {_at(found, b)}" for a, b in unseen]
    stops = found.stretches
    lines.append(
        f"  fewest ASV stops: {len(stops)} (the ROV kept in view between moves by turning "
        f"the hull alone; each move between stops a steered hull makes blind unless it runs "
        f"along the line of sight)"
    )
    for n, stretch in enumerate(stops, 1):
        count = stretch.last - stretch.first + 1
        moved = (
            f"; moved {stretch.move_m:.2f} m, about {stretch.blind_s:.0f} s blind" if n > 1 else ""
        )
        lines.append(
            f"    {n:2d}. at {_xy(stretch.station_xy)}: {_at(found, stretch.first)} to "
            f"{_at(found, stretch.last)} ({count} points, {stretch.masked} masked from there"
            f"{moved})"
        )
    if len(stops) > 1:
        blind = sum(stretch.blind_s for stretch in stops)
        lines.append(
            f"  these stops' moves: {len(stops) - 1}, {sum(s.move_m for s in stops):.1f} m, "
            f"about {blind:.0f} s with the ROV out of view while it waits, by the follower's "
            f"model of a {config.motion.drive} hull ({config.motion.max_yaw_rate_deg_s:g} deg/s, "
            f"{config.motion.max_speed_m_s:g} m/s); the follower itself also moves along the "
            f"line of sight, in view, and may do better"
        )
    route = found.route
    if route is not None:
        lines.append(
            f"  the least blind route (a place for every point, moving between them, the ROV "
            f"waiting while the ASV moves; the same model): {route.moves} moves, about "
            f"{route.blind_s:.0f} s with the sonar off the ROV"
        )
        for i, seconds in route.blind:
            a = found.places_xy[route.places[i - 1]]
            b = found.places_xy[route.places[i]]
            lines.append(
                f"    the ROV waiting at {_at(found, i)}: {_xy(a)} -> {_xy(b)}, about "
                f"{seconds:.0f} s blind"
            )
    return lines


def draw(
    found: Coverage, points: list[Waypoint], planner: StationPlanner, png: Path, *, title: str
) -> None:
    """The tank, where the ASV may be, the path coloured by what sees it, the stops."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    tank = planner.tank
    fig, ax = plt.subplots(figsize=(12, 8 * tank.width_m / max(tank.length_m, 1e-9) + 1.5))
    ax.add_patch(Rectangle((0, 0), tank.length_m, tank.width_m, fill=False, color="k"))
    for f in tank.fixtures:
        ax.add_patch(
            Rectangle(
                (f.lo_m[0], f.lo_m[1]),
                f.hi_m[0] - f.lo_m[0],
                f.hi_m[1] - f.lo_m[1],
                color="0.8",
                zorder=0,
            )
        )
    xy = found.places_xy
    ax.scatter(xy[:, 0], xy[:, 1], s=2, color="0.85", label="places the ASV may be")
    path = found.path_m
    colour = np.where(found.clear_any, "tab:green", np.where(found.seen_any, "tab:orange", "r"))
    ax.scatter(path[:, 0], path[:, 1], s=9, c=list(colour), zorder=3)
    plan = np.array([w.position_m for w in points])
    ax.plot(plan[:, 0], plan[:, 1], "--", color="0.4", lw=0.8, label="the ROV's plan")
    for n, stretch in enumerate(found.stretches, 1):
        sx, sy = stretch.station_xy
        ax.plot(sx, sy, "s", color="tab:blue", ms=7, zorder=4)
        ax.annotate(str(n), (sx, sy), textcoords="offset points", xytext=(5, 5), color="tab:blue")
        mid = path[(stretch.first + stretch.last) // 2]
        ax.plot([sx, mid[0]], [sy, mid[1]], ":", color="tab:blue", lw=0.8)
    if found.route is not None:
        way = xy[found.route.places]
        ax.plot(way[:, 0], way[:, 1], "-", color="tab:purple", lw=1, zorder=2)
        ax.plot([], [], "-", color="tab:purple", label="the least blind route (the ASV)")
    ax.plot([], [], "s", color="tab:blue", label="fewest stops (numbered)")
    ax.scatter([], [], s=9, color="tab:green", label="seen, nothing in its range cell")
    ax.scatter([], [], s=9, color="tab:orange", label="seen, a fixture in its range cell")
    ax.scatter([], [], s=9, color="r", label="seen from nowhere")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, tank frame)")
    ax.set_ylabel("y (m)")
    ax.set_title(title)
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
    fig.tight_layout()
    fig.savefig(png, dpi=100)
    plt.close(fig)
