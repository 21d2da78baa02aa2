"""Training samples for the polar network, rendered by the simulator from labelled pings.

Each simulated run (tank, trajectory, ASV mode and stand-off, seed, gain, ghost strength and
noise drawn per run; four runs in five also draw the sonar's whole look: capsd.simulator.sonar_look,
docs/SONAR-VARIETY.md) gives, per ping, in the normalised input (polar_input):
- the coarse grid (uint8) and the ROV centre in heatmap cells (or none when not visible);
- crops: positives around the true centre with the offset a proposal would have, and
  negatives on what a proposal might pick instead (the brightest cells away from the ROV,
  the multipath ghosts, a random place), each with its targets.
Runs are spread over worker processes; the same plan and seed give the same samples.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import ExitStack
from dataclasses import dataclass, field
from multiprocessing import get_context
from typing import Any, Literal

import msgspec
import numpy as np
import numpy.typing as npt

from capsd.mounts import SonarMountConfig
from capsd.payloads import SonarFrame, SonarLabel
from capsd.progress import Progress
from capsd.services.sonar_detect.polar_input import (
    DEFAULT_INPUTS,
    BeamTable,
    Grid,
    Inputs,
    coarse_input,
    crop_pair,
    normalised_image,
    to_u8,
    with_range_plane,
    with_range_rows,
)
from capsd.simulator.config import (
    OFFLINE_START_NS,
    Config,
    Noise,
    Rates,
    SonarImageConfig,
    Streams,
)
from capsd.simulator.install_errors import InstallErrorsConfig
from capsd.simulator.sim import Simulation
from capsd.simulator.sonar_look import Variety
from capsd.simulator.world import TUNING_TANKS, RackHeights, TankName, TrajectoryName
from capsd.sonar_geometry import FanPlace, fan_distance_m

TRAJECTORIES: tuple[TrajectoryName, ...] = (
    "square",
    "bouncing",
    "lawnmower",
    "random",
    "two_floor",
)
NEGATIVE_MIN_DISTANCE_M = 0.8
# Far runs (plan_runs' far_share): how far the ASV follows and how shallow its sonar looks.
FAR_STANDOFF_M = (11.0, 18.0)
FAR_PITCH_DEG = (8.0, 20.0)
# Near runs (plan_runs' near_share): the mockup, the ASV following this close, its sonar this
# steeply down, so that the ROV is 0.5-1.5 m from the sonar (a small tank's ASV with a tilt
# servo keeps it so: a BlueROV2 then fills up to 30 deg of the fan).
NEAR_STANDOFF_M = (0.3, 1.0)
NEAR_PITCH_DEG = (45.0, 75.0)
# ... and turned this far either way (since session 51), as a pan at its limit or a hull
# turning slower than the ROV passes leaves it: the ROV up to 45 deg off the boresight.
NEAR_YAW_DEG = 70.0
# Close runs (plan_runs' close_share, since session 59): the ASV CLOSE_STANDOFF_M behind the ROV
# with its sonar CLOSE_PITCH_DEG down, as usual, so that the ROV is 1-2.5 m from the sonar; in
# half of them the ASV stands still and the ROV goes down and up through the aperture, a round
# trip in CLOSE_PROFILE_PERIOD_S (the pitch calibration's near profile; a ROV passing under a
# parked ASV). The runs before put almost no ROV there: the proposal network put under 0.1 of
# heat on a ROV 1.25-2 m off in the aperture's middle (session 59, by hand).
CLOSE_STANDOFF_M = (0.8, 2.2)
CLOSE_PITCH_DEG = (20.0, 40.0)
CLOSE_PROFILE_PERIOD_S = (30.0, 60.0)


@dataclass(frozen=True)
class RunPlan:
    """One simulated run to render."""

    tank: TankName
    trajectory: TrajectoryName
    asv_mode: Literal["follow", "stationary"]
    standoff_m: float | None
    seed: int
    gain_percent: float
    ghost_gain: float
    noise_level: float
    duration_s: float
    sonar_hz: float
    variety: Variety = "train"
    sonar_pitch_deg: float | None = None  # None: the simulator's default mount (30 deg down)
    sonar_yaw_deg: float = 0.0  # the mount turned to port (near runs)
    start_s: float = 0.0  # where in the vehicles' paths the run starts (sim seconds)
    # profile: the ROV goes down and up through the aperture, the ASV still (close runs).
    rov_mode: Literal["trajectory", "profile"] = "trajectory"
    profile_period_s: float = 120.0
    # drawn: racks and skips of other heights, some just under the ROV (world.RackHeights).
    rack_heights: RackHeights = "preset"

    def config(self) -> Config:
        sonar = SonarMountConfig()
        if self.sonar_pitch_deg is not None:
            sonar = msgspec.structs.replace(sonar, pitch_deg=self.sonar_pitch_deg)
        if self.sonar_yaw_deg != 0.0:
            sonar = msgspec.structs.replace(sonar, yaw_deg=self.sonar_yaw_deg)
        return Config(
            tank=self.tank,
            trajectory=self.trajectory,
            seed=self.seed,
            asv_mode=self.asv_mode,
            asv_standoff_m=self.standoff_m,
            rov_mode=self.rov_mode,
            profile_period_s=self.profile_period_s,
            rack_heights=self.rack_heights,
            sonar=sonar,
            sonar_image=SonarImageConfig(
                gain_percent=self.gain_percent,
                ghost_gain=self.ghost_gain,
                noise_level=self.noise_level,
                variety=self.variety,
            ),
            rates=Rates(sonar_hz=self.sonar_hz),
            noise=Noise(),
            # Training data as the shipped weights were trained: a perfect installation.
            install_errors=InstallErrorsConfig(mode="off"),
            streams=Streams(
                lidar="off", imu="off", asv_pose_truth_noise="off", detections_truth_noise="off"
            ),
        )


def plan_runs(
    *,
    runs: int,
    seed: int,
    duration_s: float,
    sonar_hz: float,
    far_share: float = 0.0,
    near_share: float = 0.0,
    close_share: float = 0.0,
    start_spread_s: float = 0.0,
    near_standoff_m: tuple[float, float] = NEAR_STANDOFF_M,
    near_yaw_deg: float = NEAR_YAW_DEG,
    rack_heights: RackHeights = "preset",
) -> list[RunPlan]:
    """`runs` varied runs drawn from `seed` (both tanks, every trajectory, both ASV modes).

    Every run but each fifth draws the sonar's look (capsd.simulator.sonar_look, training region);
    each fifth keeps the simulator's fixed look with its gain and noise varied a little.
    A `far_share` of the runs (drawn from a stream of their own, so that 0 plans as before) is
    far instead: the nfp tank, the ASV following FAR_STANDOFF_M off with its sonar
    FAR_PITCH_DEG down, so that the ROV is in the aperture 10-20 m away.
    A `near_share` (a stream of its own too) is near: the mockup, the ASV following
    `near_standoff_m` off with its sonar NEAR_PITCH_DEG down and up to `near_yaw_deg` to either
    side, the ROV 0.5-1.5 m away with the defaults.
    A `close_share` (its own stream) is close: either tuning tank, the ASV CLOSE_STANDOFF_M
    off, the sonar CLOSE_PITCH_DEG down, half of them the ROV profiling (RunPlan.rov_mode).
    With `start_spread_s`, each run starts at a time drawn from 0 to that (a stream of its
    own again): short runs then see every part of the paths, not only their first seconds.
    `rack_heights` "drawn": every run's racks and skips of other heights (world.RackHeights).
    """
    rng = np.random.default_rng(seed)
    plans = []
    for k in range(runs):
        tank: TankName = TUNING_TANKS[k % 2]
        mode: Literal["follow", "stationary"] = "follow" if (k // 2) % 3 else "stationary"
        standoff = None
        if mode == "follow" and tank == "nfp" and rng.random() < 0.6:
            standoff = float(rng.uniform(1.0, 8.0))
        plans.append(
            RunPlan(
                tank=tank,
                trajectory=TRAJECTORIES[(k // 2) % len(TRAJECTORIES)],
                asv_mode=mode,
                standoff_m=standoff,
                seed=int(rng.integers(10_000, 1_000_000)),
                gain_percent=float(rng.uniform(40.0, 60.0)),
                ghost_gain=float(rng.uniform(0.05, 0.25)),
                noise_level=float(0.0004 * math.exp(rng.uniform(-0.7, 0.7))),
                duration_s=duration_s,
                sonar_hz=sonar_hz,
                variety="off" if k % 5 == 4 else "train",
            )
        )
    if far_share > 0.0:
        far = np.random.default_rng([seed, 0xFA4])
        plans = _placed(plans, far, far_share, "nfp", FAR_STANDOFF_M, FAR_PITCH_DEG)
    if near_share > 0.0:
        near = np.random.default_rng([seed, 0x9EA])
        plans = _placed(
            plans, near, near_share, "mockup", near_standoff_m, NEAR_PITCH_DEG, near_yaw_deg
        )
    if close_share > 0.0:
        plans = _close(plans, np.random.default_rng([seed, 0xC105E]), close_share)
    if start_spread_s > 0.0:
        start_rng = np.random.default_rng([seed, 0x57A7])
        plans = [
            dataclasses.replace(plan, start_s=float(start_rng.uniform(0.0, start_spread_s)))
            for plan in plans
        ]
    if rack_heights != "preset":
        plans = [dataclasses.replace(plan, rack_heights=rack_heights) for plan in plans]
    return plans


def _placed(
    plans: list[RunPlan],
    rng: np.random.Generator,
    share: float,
    tank: TankName,
    standoff_m: tuple[float, float],
    pitch_deg: tuple[float, float],
    yaw_deg: float = 0.0,
) -> list[RunPlan]:
    """`plans` with a `share` of them (drawn from `rng`) moved to `tank`, far or near.

    The ASV follows `standoff_m` off, its sonar `pitch_deg` down and turned up to `yaw_deg`
    either way. A draw for every run, so the plan is the same whatever came before; a run
    already moved (its pitch set) stays as it is.
    """
    out = []
    for plan in plans:
        if rng.random() < share and plan.sonar_pitch_deg is None:
            plan = dataclasses.replace(
                plan,
                tank=tank,
                asv_mode="follow",
                standoff_m=float(rng.uniform(*standoff_m)),
                sonar_pitch_deg=float(rng.uniform(*pitch_deg)),
            )
            if yaw_deg > 0.0:
                plan = dataclasses.replace(
                    plan, sonar_yaw_deg=float(rng.uniform(-yaw_deg, yaw_deg))
                )
        out.append(plan)
    return out


def _close(plans: list[RunPlan], rng: np.random.Generator, share: float) -> list[RunPlan]:
    """`plans` with a `share` of them (drawn from `rng`) made close runs (plan_runs).

    A draw for every run, so the plan is the same whatever came before; a run already moved
    (its pitch set) stays as it is. The tank stays the run's own (both tuning tanks).
    """
    out = []
    for plan in plans:
        draw = rng.random(5)
        if draw[0] < share and plan.sonar_pitch_deg is None:
            plan = dataclasses.replace(
                plan,
                asv_mode="follow",
                standoff_m=float(np.interp(draw[1], (0.0, 1.0), CLOSE_STANDOFF_M)),
                sonar_pitch_deg=float(np.interp(draw[2], (0.0, 1.0), CLOSE_PITCH_DEG)),
            )
            if draw[3] < 0.5:
                plan = dataclasses.replace(
                    plan,
                    rov_mode="profile",
                    profile_period_s=float(np.interp(draw[4], (0.0, 1.0), CLOSE_PROFILE_PERIOD_S)),
                )
        out.append(plan)
    return out


@dataclass
class Samples:
    """Samples of one or more runs, ready to stack."""

    grids: list[npt.NDArray[np.uint8]] = field(default_factory=list)  # 2 x rows x cols
    # Per grid: visible (0/1), centre row and col in heatmap cells, extent rows and cols.
    grid_targets: list[tuple[float, float, float, float, float]] = field(default_factory=list)
    crops: list[npt.NDArray[np.uint8]] = field(default_factory=list)  # 2 x N x N
    # Per crop: is ROV (0/1), d_range, d_cross (m), extent range, extent cross (m), overlap.
    crop_targets: list[tuple[float, float, float, float, float, float]] = field(
        default_factory=list
    )
    crop_ranges_m: list[float] = field(default_factory=list)  # per crop: its centre's range

    def extend(self, other: Samples) -> None:
        self.grids.extend(other.grids)
        self.grid_targets.extend(other.grid_targets)
        self.crops.extend(other.crops)
        self.crop_targets.extend(other.crop_targets)
        self.crop_ranges_m.extend(other.crop_ranges_m)

    def crops_within(self, range_m: float) -> Samples:
        """The crops centred nearer than `range_m` (no grids)."""
        keep = [k for k, r in enumerate(self.crop_ranges_m) if r < range_m]
        return Samples(
            crops=[self.crops[k] for k in keep],
            crop_targets=[self.crop_targets[k] for k in keep],
            crop_ranges_m=[self.crop_ranges_m[k] for k in keep],
        )


def heat_coordinates(
    frame: SonarFrame, grid: Grid, range_m: float, beam: float
) -> tuple[float, float]:
    """(row, col) in heatmap cells (stride 2 over the coarse grid) of a range and beam index."""
    bin_index = (range_m - frame.range_start_m) / frame.range_resolution_m
    return (
        bin_index / (2 * grid.range_factor) - 0.5,
        (beam + 0.5) / (2 * grid.beam_factor) - 0.5,
    )


def samples_of_ping(
    frame: SonarFrame,
    label: SonarLabel,
    rng: np.random.Generator,
    *,
    proposal: Any = None,
    inputs: Inputs = DEFAULT_INPUTS,
) -> Samples:
    """The grid and crops of one labelled ping.

    With a trained `proposal` network (hard-negative mining), its own peaks away from the ROV
    are added as negatives: the sandbags and rack corners it mistakes for an ROV. With
    `inputs` the grid's width and whether grids and crops carry the range plane.
    """
    out = Samples()
    image = normalised_image(frame)
    grid = Grid.of(frame, beams=inputs.coarse_beams)
    coarse = coarse_input(image, grid)
    ranged = inputs.range_input == "channel"
    out.grids.append(to_u8(with_range_rows(coarse, frame, grid) if ranged else coarse))
    table = BeamTable(frame.azimuths_rad)
    truth: SonarLabel | None = None
    if (
        label.visible
        and label.range_min_m is not None
        and label.range_max_m is not None
        and label.azimuth_min_rad is not None
        and label.azimuth_max_rad is not None
    ):
        truth = label
        beam = float(table.index(label.azimuth_rad))
        row, col = heat_coordinates(frame, grid, label.range_m, beam)
        extent_beams = abs(
            float(table.index(label.azimuth_max_rad)) - float(table.index(label.azimuth_min_rad))
        )
        extent_bins = (label.range_max_m - label.range_min_m) / frame.range_resolution_m
        out.grid_targets.append(
            (
                1.0,
                row,
                col,
                extent_bins / (2 * grid.range_factor),
                extent_beams / (2 * grid.beam_factor),
            )
        )
        extent_range = label.range_max_m - label.range_min_m
        extent_cross = (label.azimuth_max_rad - label.azimuth_min_rad) * label.range_m
        for k in range(2):
            spread = 0.08 if k == 0 else 0.35
            d_range = float(np.clip(rng.normal(0.0, spread), -0.45, 0.45))
            d_cross = float(np.clip(rng.normal(0.0, spread), -0.45, 0.45))
            centre_range = label.range_m - d_range
            centre_az = label.azimuth_rad - d_cross / centre_range
            if centre_range <= 0.2:
                continue
            patch = crop_pair(image, frame, table, range_m=centre_range, azimuth_rad=centre_az)
            if ranged:
                patch = with_range_plane(patch, centre_range)
            # The target offset is measured at the crop's own range (its cross-range scale).
            out.crops.append(to_u8(patch))
            out.crop_ranges_m.append(centre_range)
            out.crop_targets.append(
                (
                    1.0,
                    d_range,
                    (label.azimuth_rad - centre_az) * centre_range,
                    extent_range,
                    extent_cross,
                    float(label.overlap),
                )
            )
    else:
        out.grid_targets.append((0.0, 0.0, 0.0, 0.0, 0.0))
    places = _negative_places(frame, grid, coarse, table, label, rng)
    if proposal is not None:
        from capsd.services.sonar_detect.cnn import propose

        peaks = propose(
            proposal,
            frame,
            image,
            table,
            threshold=0.05,
            max_candidates=3,
            inputs=inputs,
        )
        places += [(c.range_m, c.azimuth_rad) for c in peaks]
    for range_m, azimuth in places:
        place = FanPlace(range_m, azimuth)
        if truth is not None and fan_distance_m(truth, place) < NEGATIVE_MIN_DISTANCE_M:
            continue
        patch = crop_pair(image, frame, table, range_m=range_m, azimuth_rad=azimuth)
        if ranged:
            patch = with_range_plane(patch, range_m)
        out.crops.append(to_u8(patch))
        out.crop_ranges_m.append(range_m)
        out.crop_targets.append((0.0, 0.0, 0.0, 0.0, 0.0, float(label.overlap)))
    return out


def _negative_places(
    frame: SonarFrame,
    grid: Grid,
    coarse: npt.NDArray[np.float32],
    table: BeamTable,
    label: SonarLabel,
    rng: np.random.Generator,
) -> list[tuple[float, float]]:
    """Where a proposal might land other than the ROV: bright cells, ghosts, anywhere."""
    places = [(r, a) for r, a in ((g.range_m, g.azimuth_rad) for g in label.ghosts)]
    mean = coarse[0]
    # The brightest cells, one per 1 m x 8-cell block so they are spread out.
    flat = np.argsort(mean, axis=None)[::-1][:400]
    picked: list[tuple[int, int]] = []
    block_rows = max(1, int(1.0 / (grid.range_factor * frame.range_resolution_m)))
    for idx in flat:
        i, j = divmod(int(idx), mean.shape[1])
        if all(abs(i - pi) > block_rows or abs(j - pj) > 8 for pi, pj in picked):
            picked.append((i, j))
        if len(picked) >= 3:
            break
    for i, j in picked:
        range_m = frame.range_start_m + (i + 0.5) * grid.range_factor * frame.range_resolution_m
        azimuth = float(table.azimuth((j + 0.5) * grid.beam_factor - 0.5))
        places.append((range_m, azimuth))
    max_range = frame.range_start_m + frame.n_ranges * frame.range_resolution_m
    places.append(
        (
            float(rng.uniform(0.5, max_range)),
            float(rng.uniform(-table.half_fov_rad, table.half_fov_rad)),
        )
    )
    return [(r, a) for r, a in places if 0.3 < r < max_range and abs(a) <= table.half_fov_rad]


_PROPOSAL_CACHE: dict[bytes, Any] = {}


def _proposal_net(state: bytes, inputs: Inputs) -> Any:
    """A worker's copy of the proposal network (loaded once per process)."""
    if state not in _PROPOSAL_CACHE:
        import io

        import torch

        from capsd.services.sonar_detect.polar_net import ProposalNet

        loaded = torch.load(io.BytesIO(state), weights_only=True)
        net = ProposalNet.from_state(loaded, channels=2 + inputs.extra_planes)
        net.eval()
        _PROPOSAL_CACHE.clear()
        _PROPOSAL_CACHE[state] = net
    return _PROPOSAL_CACHE[state]


def render_run(job: tuple[RunPlan, bytes | None, Inputs, float | None]) -> Samples:
    """Render one run into samples (runs in a worker process); mine with a proposal state.

    With a range (the job's last item), only the crops centred nearer than it, no grids.
    """
    plan, state, inputs, crops_within_m = job
    proposal = _proposal_net(state, inputs) if state is not None else None
    rng = np.random.default_rng(plan.seed + 17)
    sim = Simulation(plan.config(), horizon_s=plan.start_s + plan.duration_s + 5.0)
    out = Samples()
    for _, frame, label in sim.labelled_pings(
        start_ns=OFFLINE_START_NS, duration_s=plan.duration_s, from_s=plan.start_s
    ):
        out.extend(samples_of_ping(frame, label, rng, proposal=proposal, inputs=inputs))
    return out if crops_within_m is None else out.crops_within(crops_within_m)


def render(
    plans: list[RunPlan],
    *,
    workers: int,
    proposal_state: bytes | None = None,
    inputs: Inputs = DEFAULT_INPUTS,
    crops_within_m: float | None = None,
) -> Samples:
    """Every run's samples, in plan order, with a progress line.

    With `crops_within_m`, only the crops centred nearer than it (each worker drops the rest).
    """
    out = Samples()
    what = "mining hard negatives" if proposal_state is not None else "rendering training runs"
    if crops_within_m is not None:
        what = "rendering near crops"
    bar = Progress(len(plans), label=what, unit=" runs")
    jobs = [(plan, proposal_state, inputs, crops_within_m) for plan in plans]
    with ExitStack() as stack:
        results: Iterator[Samples]
        if workers == 1:
            # Here, in this process: a spawned worker costs seconds of imports per call.
            results = map(render_run, jobs)
        else:
            # Each mining worker's torch on one thread: the workers already take every core.
            pool = stack.enter_context(
                ProcessPoolExecutor(
                    max_workers=workers,
                    mp_context=get_context("spawn"),
                    initializer=_one_thread if proposal_state is not None else None,
                )
            )
            results = pool.map(render_run, jobs)
        for done, samples in enumerate(results, start=1):
            out.extend(samples)
            bar.update(done)
    bar.close()
    return out


def _one_thread() -> None:
    """A mining worker's setup: torch on one thread."""
    import torch

    torch.set_num_threads(1)
