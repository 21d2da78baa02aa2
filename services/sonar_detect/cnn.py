"""The CNN ROV detector: polar frame in, ROV candidates with sub-bin centres out.

1. The coarse grid of the frame (polar_input) goes through the proposal network; local maxima
   of its heatmap above `proposal_threshold` are candidates (at most `max_candidates`); inside
   the depth gate's range window, where the ROV must be, above `gated_proposal_threshold` if
   set lower. Weights with a close proposal network (`close_proposal: on`) take the heat of
   the rows nearer than its range (2.5 m in the shipped ones) from it (polar_net).
2. A metric crop around each candidate goes through the refiner: ROV or not (the confidence),
   the centre's offset in range and cross-range, its Laplace scale (reported as sigma) and the
   echo's extent. The crop is taken again around the refined centre `refine_passes - 1` times:
   the refiner is most precise near the crop's centre.
3. Candidates closer than `merge_distance_m` to a more confident one are the same ROV.
With `mirror_average`, the refiner's last pass (for candidates `mirror_min_range_m` off or
more; with "both" the proposal network too) also reads its input mirrored across the
boresight, and the two answers are averaged.
All in the polar image; the only geometry is the bearing table and the range resolution.

Tracking (`search_every_s` > 0): between whole-frame searches, a frame whose previous ping
gave confident detections skips the proposal network (half the work) and refines crops around
those detections once: at 40 Hz an ROV moves a few cm between pings, well inside a 1.9 m crop.
The whole frame is searched again every `search_every_s` of ping time, whenever the previous
ping found nothing confident, and whenever the stamps go backwards or the sonar's geometry
changes, so a new blob is proposed within one search interval.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import msgspec
import numpy as np
import torch
from torch.nn import functional

from capsd.payloads import Detection, SonarFrame
from capsd.services.sonar_detect.polar_input import (
    DEFAULT_INPUTS,
    BeamTable,
    Grid,
    Inputs,
    coarse_input,
    crop,
    crop_pair,
    normalised_image,
    with_range_plane,
    with_range_rows,
)
from capsd.services.sonar_detect.polar_net import (
    OFFSET_SCALE_M,
    PROPOSAL_REACH_CELLS,
    PolarNet,
    fused_for_inference,
    load,
    near_refined,
)
from capsd.sonar_geometry import fan_distance_m
from capsd.sonar_image import Image

DEFAULT_WEIGHTS = Path(__file__).with_name("weights") / "polar_net.pt"
LAPLACE_SIGMA = math.sqrt(2.0)  # standard deviation of a Laplace law per unit scale
TRACKED_PEAKS = 16  # peaks under the bar looked at for one near a tracked ROV
MirrorAverage = Literal["off", "refiner", "both"]


@dataclass(frozen=True)
class CnnSettings:
    weights: Path = DEFAULT_WEIGHTS
    proposal_threshold: float = 0.1
    # Inside the depth gate's range window (where the ROV's depth plane crosses the fan: it can
    # be nowhere else), a lower bar if set (None: proposal_threshold); the refiner still
    # decides. A ROV 1.6-1.8 m off in the aperture's upper two thirds was its frame's strongest
    # heat but under 0.1 (0.06-0.09: the pond, by hand, session 28), and never proposed; the
    # refiner called it ROV (0.82-0.93). Not set by default: at 0.03 the mockup's MED in
    # `capsd bench accuracy` rose 20.8 -> 26.2 mm as its availability rose 53.5 -> 63.7 %
    # (docs/JOURNAL.md, the detector).
    gated_proposal_threshold: float | None = None
    # Proposals refined per whole-frame search, strongest heat first. 6 since session 65: on the
    # validation runs (seeds 301-306, never the bench's; `capsd bench detect --prior-sweep 1
    # --max-candidates K`) 3 / 6 / 10 found 97.2 / 98.0 / 98.4 % on the fixed look at 0.0017 /
    # 0.0006 / 0.0006 false alarms per frame and 72.0 / 74.1 / 74.3 % on drawn looks at 0.0033
    # each: more candidates put one on a ROV the heat ranks below clutter, and scored as the one
    # ROV (service's cnn.confidence) the clutter's do not pass. Past 6 little more for the
    # refiner's time (docs/JOURNAL.md, the detector).
    max_candidates: int = 6
    refine_passes: int = 2
    merge_distance_m: float = 0.3
    threads: int = 1  # torch intra-op threads: one core keeps the service's CPU predictable
    search_every_s: float = 0.1  # ping time between whole-frame searches; 0: every frame
    track_confidence: float = 0.5  # detections at least this confident are tracked
    # Hysteresis: a candidate within `track_gate_m` of a tracked detection of a ping at most
    # `track_max_gap_s` before has this added to its logit. On the validation runs (seeds
    # 301-306, never the bench's; 20 s each) prior 0 / 1 gave 77.2 / 81.4 % on the
    # fixed look (0.0033 / 0.0062 false alarms per frame) and 58.4 / 60.7 % on drawn looks
    # (0.044 / 0.059): 1.0 keeps the fixed look under 0.01; no prior does on drawn looks.
    # (`capsd bench detect --prior-sweep 0 1 --duration 20`.)
    track_prior_logit: float = 1.0
    track_gate_m: float = 0.3
    track_max_gap_s: float = 0.2
    # What a whole-frame search refines: the proposals only, or also the last ping's tracked
    # detections (a far, faint ROV the proposal network ranks below brighter clutter, which the
    # refiner still knows). Without the depth gate it moved along the same trade-off (session
    # 49's validation runs); through the gate it beats it (session 68, `capsd bench detect
    # --depth-gate truth`: held out 82.6 -> 83.3 % found at 0.023 -> 0.022 false alarms per
    # frame, fixed look 95.5 -> 96.9 % at 0.005 -> 0.001; `capsd bench accuracy` MED within
    # +1.4 % on every run), so the tracked ROV is refined in every search since session 68.
    search_refines: Literal["proposals", "proposals_and_track"] = "proposals_and_track"
    # After pings without a confident ROV, keep refining where it last was for this long
    # (0: forget it at the first miss): a far ROV's echo fades for a ping or two.
    track_hold_s: float = 0.0
    # Hysteresis on the proposals too: in a whole-frame search, a heat peak within
    # `track_gate_m` of the last ping's confident ROV is refined from this bar (None: off).
    # The mockup demo's ROV 1.3 m off on the boresight made heat of 0.04-0.1 while the refiner
    # called it ROV (0.9): each search under 0.1 ended the track (seconds of misses). Unlike
    # `proposals_and_track` it needs a peak there: `capsd bench accuracy` MED within +6.6 % on
    # every run at 0.03 (availability up to +6.1 points), pond random's 34.6 -> 39.0 mm
    # (p95 93 -> 150) with `proposals_and_track` (docs/JOURNAL.md, session 49).
    track_proposal_threshold: float | None = 0.03
    # A sonar image mirrored across the boresight is as real as the original (both networks
    # train on mirrored samples): averaging a network's answers on a crop (or the frame) and
    # on its mirror cancels part of what it learnt of one renderer's texture. "refiner": the
    # refiner's last pass; "both": the proposals' heat as well (a third more time per search
    # again). Figures: docs/JOURNAL.md, session 52 (`capsd bench detect --mirror-average ...`).
    mirror_average: MirrorAverage = "refiner"
    # Only candidates this far off: nearer, the averaged refiner lost a ROV 0.5-1.5 m off a
    # sonar 60 deg down (`capsd bench detect --runs near`, fixed look: 43.8 -> 40.5 % found,
    # 15-30 deg off the boresight 45.2 -> 30.9 %; with this bar 42.8 and 45.2 %), where its
    # false alarms were few; from 1.5 m it keeps the held-out false alarms it cuts.
    mirror_min_range_m: float = 1.5
    # The weights' near refiner (if they have one) for candidates where it takes over
    # (polar_net.near_refined: near, or nearish by the fan's edge): "off" refines every
    # candidate with the main refiner, as before session 55.
    near_refiner: Literal["on", "off"] = "on"
    # The weights' close proposal network (if they have one) for the heat of the rows where it
    # takes over (polar_net: nearer than close_max_range_m); "off": the main one everywhere,
    # as before session 59.
    close_proposal: Literal["on", "off"] = "on"


# The network alone: every frame searched, no track prior (calibration, stored evaluation).
# The proposals alone too: since session 68 the service's search also refines the tracked ROV,
# which the operating point's calibration and the weights' evaluation must not lean on.
NETWORK_ALONE = CnnSettings(search_every_s=0.0, track_prior_logit=0.0, search_refines="proposals")


@dataclass(frozen=True)
class Candidate:
    range_m: float
    azimuth_rad: float


@dataclass(frozen=True)
class _Track:
    """What the last ping left for the next: its confident detections and when it searched."""

    candidates: list[Candidate]
    stamp_ns: int
    searched_ns: int
    geometry: tuple[int, int, float, float]
    seen_ns: int  # when the candidates were last confident


def _geometry(frame: SonarFrame) -> tuple[int, int, float, float]:
    return (frame.n_ranges, frame.n_beams, frame.range_resolution_m, frame.range_start_m)


class CnnDetector:
    """`detect` frames of one sonar in ping order (one worker thread; not thread-safe).

    Frames in any other order are still detected right: a stamp going backwards or a gap
    longer than `search_every_s` means a whole-frame search.
    """

    def __init__(self, settings: CnnSettings | None = None, *, net: PolarNet | None = None):
        self.settings = settings or CnnSettings()
        torch.set_num_threads(self.settings.threads)
        self.net = net if net is not None else load(self.settings.weights)
        self.net.eval()
        self._proposal_net = fused_for_inference(self.net.proposal)
        self._refine_net = fused_for_inference(self.net.refine)
        near = self.net.near_refine if self.settings.near_refiner == "on" else None
        self._near_refine_net = None if near is None else fused_for_inference(near)
        close = self.net.close_proposal if self.settings.close_proposal == "on" else None
        self._close: tuple[torch.nn.Module, float] | None = (
            None
            if close is None
            else (fused_for_inference(close), float(self.net.close_max_range_m))
        )
        self._track: _Track | None = None
        self.searches = 0  # whole-frame searches
        self.tracked = 0  # frames refined around the previous ping's detections only

    def detect(
        self, frame: SonarFrame, *, range_window: tuple[float, float] | None = None
    ) -> list[Detection]:
        """ROV candidates, most confident first; proposals only inside `range_window` if given."""
        s = self.settings
        image = normalised_image(frame)
        table = BeamTable(frame.azimuths_rad)
        track = self._track
        geometry = _geometry(frame)
        search = (
            track is None
            or s.search_every_s <= 0.0
            or not track.candidates
            or track.geometry != geometry
            or frame.stamp_ns <= track.stamp_ns
            or frame.stamp_ns - track.searched_ns >= s.search_every_s * 1e9
        )
        if search or track is None:
            # The last ping's confident ROV, where this ping continues its track.
            tracked = (
                track.candidates if track is not None and self._continues(track, frame) else []
            )
            candidates = self._propose(frame, image, table, range_window, tracked)
            if s.search_refines == "proposals_and_track":
                # A search adds what the proposals found, it never drops a tracked ROV: the
                # proposal network ranks a far, faint echo below brighter clutter, where the
                # refiner, looking at its crop, still knows it.
                candidates += [
                    c
                    for c in tracked
                    if all(fan_distance_m(c, p) >= s.merge_distance_m for p in candidates)
                ]
            passes = max(1, s.refine_passes)
            searched_ns = frame.stamp_ns
            self.searches += 1
        else:
            # Already refined last ping: one pass around it is as precise as a second pass.
            candidates, passes, searched_ns = track.candidates, 1, track.searched_ns
            self.tracked += 1
        found: list[Detection] = []
        for k in range(passes):
            if not candidates:
                break
            mirror = self.settings.mirror_average != "off" and k == passes - 1
            found = self._refine(frame, image, table, candidates, mirror=mirror)
            candidates = [Candidate(d.range_m, d.azimuth_rad) for d in found]
        merged = self._merge(found)
        if (
            track is not None
            and s.track_prior_logit != 0.0
            and self._continues(track, frame)
            and track.seen_ns == track.stamp_ns  # confident last ping, not only held
        ):
            prior = [self._with_prior(d, track.candidates) for d in merged]
            merged = sorted(prior, key=lambda d: -d.confidence)
        confident = [
            Candidate(d.range_m, d.azimuth_rad)
            for d in merged
            if d.confidence >= s.track_confidence
        ]
        seen_ns = frame.stamp_ns
        if (
            not confident
            and track is not None
            and track.candidates
            and self._continues(track, frame)
            and frame.stamp_ns - track.seen_ns <= s.track_hold_s * 1e9
        ):
            confident, seen_ns = track.candidates, track.seen_ns
        self._track = _Track(confident, frame.stamp_ns, searched_ns, geometry, seen_ns)
        return merged

    def _continues(self, track: _Track, frame: SonarFrame) -> bool:
        """Whether `frame` continues the track: the same geometry, soon after, in order."""
        return (
            track.geometry == _geometry(frame)
            and 0 < frame.stamp_ns - track.stamp_ns <= self.settings.track_max_gap_s * 1e9
        )

    def _with_prior(self, d: Detection, tracked: list[Candidate]) -> Detection:
        """`d` with the track's prior added to its logit when it continues a tracked one."""
        s = self.settings
        if not any(fan_distance_m(d, c) < s.track_gate_m for c in tracked):
            return d
        c = min(max(d.confidence, 1e-12), 1.0 - 1e-12)
        logit = math.log(c / (1.0 - c)) + s.track_prior_logit
        return msgspec.structs.replace(
            d, confidence=1.0 / (1.0 + math.exp(-min(max(logit, -30.0), 30.0)))
        )

    def _propose(
        self,
        frame: SonarFrame,
        image: Image,
        table: BeamTable,
        range_window: tuple[float, float] | None,
        tracked: list[Candidate],
    ) -> list[Candidate]:
        s = self.settings
        return propose(
            self._proposal_net,
            frame,
            image,
            table,
            threshold=(
                s.proposal_threshold
                if range_window is None or s.gated_proposal_threshold is None
                else min(s.proposal_threshold, s.gated_proposal_threshold)
            ),
            max_candidates=s.max_candidates,
            range_window=range_window,
            inputs=self.net.inputs,
            tracked=tracked,
            tracked_threshold=s.track_proposal_threshold,
            tracked_gate_m=s.track_gate_m,
            mirror=s.mirror_average == "both",
            close=self._close,
        )

    def _refine(
        self,
        frame: SonarFrame,
        image: Image,
        table: BeamTable,
        candidates: list[Candidate],
        *,
        mirror: bool,
    ) -> list[Detection]:
        """Each candidate refined: the near refiner where it takes over (if any), else the main."""
        near_net = self._near_refine_net
        routed = [
            near_net is not None
            and near_refined(
                self.net,
                range_m=c.range_m,
                azimuth_rad=c.azimuth_rad,
                half_fov_rad=table.half_fov_rad,
            )
            for c in candidates
        ]
        if near_net is None or not any(routed):
            return self._refined(frame, image, table, candidates, mirror=mirror)
        near = [c for c, r in zip(candidates, routed, strict=True) if r]
        far = [c for c, r in zip(candidates, routed, strict=True) if not r]
        # The near refiner never mirrors: candidates that near are not averaged anyway
        # (`mirror_min_range_m`).
        return self._refined(frame, image, table, far, mirror=mirror) + self._refined(
            frame,
            image,
            table,
            near,
            mirror=False,
            net=near_net,
            offset=float(self.net.near_logit_offset),
        )

    def _refined(
        self,
        frame: SonarFrame,
        image: Image,
        table: BeamTable,
        candidates: list[Candidate],
        *,
        mirror: bool,
        net: torch.nn.Module | None = None,
        offset: float | None = None,
    ) -> list[Detection]:
        """`candidates` through one refiner (the main one unless `net`) and its operating point."""
        if not candidates:
            return []
        refine_net = self._refine_net if net is None else net
        crops = torch.from_numpy(
            np.stack([refine_input(self.net, image, frame, table, c) for c in candidates])
        ).contiguous(memory_format=torch.channels_last)
        bar = self.settings.mirror_min_range_m
        far = torch.tensor([c.range_m >= bar for c in candidates]) if mirror else None
        with torch.inference_mode():
            if far is not None and bool(far.any()):
                both = refine_net(torch.cat([crops, torch.flip(crops[far], dims=[-1])]))
                raw, mirrored = both[: len(candidates)], both[len(candidates) :]
                mirrored[:, 2] = -mirrored[:, 2]  # the cross-range offset changes sign
                raw[far] = 0.5 * (raw[far] + mirrored)
            else:
                raw = refine_net(crops)
            out = raw.numpy().astype(np.float64)
        half_fov = table.half_fov_rad
        offset = float(self.net.logit_offset) if offset is None else offset
        found = []
        for c, o in zip(candidates, out, strict=True):
            range_m = c.range_m + float(o[1]) * OFFSET_SCALE_M
            if range_m <= 0.0:
                continue
            azimuth = c.azimuth_rad + float(o[2]) * OFFSET_SCALE_M / c.range_m
            azimuth = min(max(azimuth, -half_fov), half_fov)
            log_scales = np.clip(o[3:5], -8.0, 3.0)
            sigma_range, sigma_cross = np.exp(log_scales) * OFFSET_SCALE_M * LAPLACE_SIGMA
            extent_range, extent_cross = np.exp(np.clip(o[5:7], -6.0, 2.0))
            found.append(
                Detection(
                    range_m=range_m,
                    azimuth_rad=azimuth,
                    range_sigma_m=float(sigma_range),
                    azimuth_sigma_rad=float(sigma_cross) / range_m,
                    confidence=float(
                        1.0 / (1.0 + math.exp(-float(np.clip(o[0] - offset, -30, 30))))
                    ),
                    range_extent_m=float(extent_range),
                    azimuth_extent_rad=float(extent_cross) / range_m,
                )
            )
        return found

    def _merge(self, found: list[Detection]) -> list[Detection]:
        kept: list[Detection] = []
        for d in sorted(found, key=lambda d: -d.confidence):
            if all(fan_distance_m(d, k) >= self.settings.merge_distance_m for k in kept):
                kept.append(d)
        return kept


def refine_input(
    net: PolarNet, image: Image, frame: SonarFrame, table: BeamTable, at: Candidate
) -> Image:
    """What the refiner reads around `at`: the detail crop (and context, and range plane)."""
    if net.refine_channels == 2:
        out = crop_pair(image, frame, table, range_m=at.range_m, azimuth_rad=at.azimuth_rad)
    else:
        out = crop(image, frame, table, range_m=at.range_m, azimuth_rad=at.azimuth_rad)[None]
    return with_range_plane(out, at.range_m) if net.inputs.range_input == "channel" else out


def proposal_input(image: Image, frame: SonarFrame, grid: Grid, inputs: Inputs) -> Image:
    """What the proposal network reads: the coarse grid (and its range plane)."""
    coarse = coarse_input(image, grid)
    return with_range_rows(coarse, frame, grid) if inputs.range_input == "channel" else coarse


def propose(
    proposal: torch.nn.Module,
    frame: SonarFrame,
    image: Image,
    table: BeamTable,
    *,
    threshold: float,
    max_candidates: int,
    range_window: tuple[float, float] | None = None,
    inputs: Inputs = DEFAULT_INPUTS,
    tracked: Sequence[Candidate] = (),
    tracked_threshold: float | None = None,
    tracked_gate_m: float = 0.3,
    mirror: bool = False,
    close: tuple[torch.nn.Module, float] | None = None,
) -> list[Candidate]:
    """Local maxima of the proposal heatmap above `threshold`, strongest first.

    With `range_window` (metres), heat cells outside it are not candidates (depth-aware search).
    A peak within `tracked_gate_m` of one of `tracked` needs only `tracked_threshold` (if set).
    With `mirror`, the heat is the mean of the frame's and its mirror's (logits, mirrored back).
    With `close` (a network and a range), that network gives the heat of the rows nearer.
    """
    if not tracked or tracked_threshold is None:
        tracked, tracked_threshold = (), threshold
    lowest = min(threshold, tracked_threshold)
    grid = Grid.of(frame, beams=inputs.coarse_beams)
    if grid.rows < 4 or grid.cols < 4:
        return []
    coarse = torch.from_numpy(proposal_input(image, frame, grid, inputs))[None].contiguous(
        memory_format=torch.channels_last
    )
    # Heat row i is centred on bin (2i + 1) x range_factor (see below).
    cell_m = 2 * grid.range_factor * frame.range_resolution_m
    near: tuple[torch.nn.Module, int] | None = None
    if close is not None:
        close_net, close_max_m = close
        rows = math.ceil((close_max_m - frame.range_start_m) / cell_m - 0.5)
        # Where the depth gate's window starts beyond them, those rows' heat is not read.
        beyond = range_window is not None and range_window[0] - cell_m >= close_max_m
        if rows > 0 and not beyond:
            near = (close_net, rows)
    with torch.inference_mode():
        logits = heat_logits(proposal, coarse, mirror=mirror, close=near)
        heat = torch.sigmoid(logits)[0]
        if range_window is not None:
            centres = frame.range_start_m + (torch.arange(heat.shape[0]) + 0.5) * cell_m
            outside = (centres < range_window[0] - cell_m) | (centres > range_window[1] + cell_m)
            heat[outside] = 0.0
        peaks = (heat == functional.max_pool2d(heat[None], 3, stride=1, padding=1)[0]) & (
            heat >= lowest
        )
        scores = torch.where(peaks, heat, torch.zeros_like(heat)).flatten()
        # Peaks under `threshold` count only near a tracked ROV: look past the strongest few.
        wanted = max_candidates if lowest >= threshold else max_candidates + TRACKED_PEAKS
        top = torch.topk(scores, min(wanted, scores.numel()))
    out: list[Candidate] = []
    cols = heat.shape[1]
    for score, index in zip(top.values.tolist(), top.indices.tolist(), strict=True):
        if score < lowest or len(out) == max_candidates:
            break
        i, j = divmod(int(index), cols)
        bin_index = (2 * i + 1) * grid.range_factor
        beam = (2 * j + 1) * grid.beam_factor - 0.5
        candidate = Candidate(
            frame.range_start_m + bin_index * frame.range_resolution_m,
            float(table.azimuth(beam)),
        )
        if score >= threshold or any(
            fan_distance_m(candidate, t) < tracked_gate_m for t in tracked
        ):
            out.append(candidate)
    return out


def heat_logits(
    proposal: torch.nn.Module,
    coarse: torch.Tensor,
    *,
    mirror: bool,
    close: tuple[torch.nn.Module, int] | None = None,
) -> torch.Tensor:
    """The heat logits of a grid (batch x rows x cols); with `mirror`, averaged with its mirror's.

    With `close` (a network, a number of heat rows), that network's for the first rows; it
    reads only those rows and PROPOSAL_REACH_CELLS more, which is all its heat there depends on.
    """
    logits = _mirrored(proposal, coarse, mirror=mirror)
    if close is not None:
        close_net, rows = close
        rows = min(rows, logits.shape[1])
        strip = coarse[..., : 2 * (rows + PROPOSAL_REACH_CELLS), :]
        logits[:, :rows] = _mirrored(close_net, strip, mirror=mirror)[:, :rows]
    return logits


def _mirrored(proposal: torch.nn.Module, coarse: torch.Tensor, *, mirror: bool) -> torch.Tensor:
    """A network's heat logits; with `mirror`, averaged with its mirror image's."""
    logits: torch.Tensor = proposal(coarse)
    if mirror:
        logits = 0.5 * (logits + torch.flip(proposal(torch.flip(coarse, dims=[-1])), dims=[-1]))
    return logits
