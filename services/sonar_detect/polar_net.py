"""The polar ROV network (pure torch): a coarse proposal heatmap and a crop refiner.

- `ProposalNet` reads the coarse grid (2 x rows x cols, see polar_input) and gives a heatmap
  logit at half its resolution: peaks are places that look like an ROV centre. Dilated
  convolutions give it ~3 m of context, enough to tell a hull from a rack edge or a ghost.
- `RefineNet` reads metric crops (detail and context, 2 x CROP_SIZE x CROP_SIZE) around each
  peak and gives an ROV/not-ROV logit, the centre's offset from the crop centre in range and
  cross-range (metres), the log scale of a Laplace error for each (the sigma we report), and
  the log of the echo's extent in range and cross-range.
What else the weights expect is theirs (`polar_input.Inputs`, stored with them): with
`range_input: channel` both stages read one more plane, the range (each grid row's, the
crop's centre), so that what an ROV looks like may depend on how far it is (a faint dash at
16 m, a wide blob at 2 m); `coarse_beams` sets the proposal grid's width.
- An optional near refiner (`near_refine`, the same network with weights of its own) reads the
  crops of candidates nearer than `near_max_range_m`: there a metric crop spans most of the
  fan, the ROV seen steeply from above fills up to a third of it, and a refiner trained on
  ROVs 1.5-20 m off doubts it (`capsd train near-refiner`). It has its own operating point.
  Since session 56 it also reads candidates nearer than `near_edge_max_range_m` within
  `near_edge_within_rad` of the fan's edge (`near_refined`): there the crop runs past the fan,
  and the main refiner found none of the ROVs 1.5-2 m off and 45-55 deg off the boresight.
- An optional close proposal network (`close_proposal`, a `ProposalNet` with weights of its
  own, since session 59) gives the heat of the grid's rows nearer than `close_max_range_m`:
  the main one, trained on few ROVs 1-2.5 m from a sonar 30 deg down, put under 0.1 of heat
  on them where the refiners were sure (`capsd train proposal`; trained with close runs the
  whole network lost far ROVs on the held-out look, so it takes over near the sonar only).
- Either proposal network may be narrower than 32 channels (`proposal_width`,
  `close_width`): the proposal stage is the largest part of a whole-frame search's time.
Weights are a plain state dict with a format tag, loaded with `weights_only=True`.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, get_args

import torch
from torch import nn

from capsd.errors import CapsdError
from capsd.services.sonar_detect.polar_input import (
    COARSE_BEAMS,
    DEFAULT_INPUTS,
    Inputs,
    RangeInput,
)

FORMAT = "capsd-polar-net"
VERSION = 1
OFFSET_SCALE_M = 0.1  # offsets are regressed in units of 10 cm


def _conv(c_in: int, c_out: int, *, stride: int = 1, dilation: int = 1) -> list[nn.Module]:
    return [
        nn.Conv2d(c_in, c_out, 3, stride=stride, padding=dilation, dilation=dilation, bias=False),
        nn.BatchNorm2d(c_out),
        nn.ReLU(inplace=True),
    ]


PROPOSAL_WIDTH = 32  # a proposal network's channels unless its weights say fewer
PROPOSAL_WIDTHS = (8, 64)  # what a weights file may say a proposal network's width is


class ProposalNet(nn.Module):
    """Coarse grid -> heatmap logit at stride 2."""

    def __init__(self, width: int = PROPOSAL_WIDTH, channels: int = 2):
        super().__init__()
        self.width = width
        self.body = nn.Sequential(
            *_conv(channels, 16, stride=2),
            *_conv(16, width),
            *_conv(width, width, dilation=2),
            *_conv(width, width, dilation=4),
            *_conv(width, width, dilation=8),
            nn.Conv2d(width, 1, 1),
        )
        # CenterNet's prior: start every cell at p = 0.1, or the first steps drown in negatives.
        head = self.body[-1]
        assert isinstance(head, nn.Conv2d)
        assert head.bias is not None
        nn.init.constant_(head.bias, -2.19)

    def forward(self, grid: torch.Tensor) -> torch.Tensor:
        out: torch.Tensor = self.body(grid)
        return out[:, 0]

    @classmethod
    def from_state(cls, state: Mapping[str, torch.Tensor], *, channels: int) -> ProposalNet:
        """A network with `state` loaded, as wide as the state is (its head's input channels)."""
        head = state[f"body.{_HEAD_INDEX}.weight"]  # (1, width, 1, 1)
        net = cls(int(head.shape[1]), channels=channels)
        net.load_state_dict(state)
        return net


_HEAD_INDEX = 15  # the 1x1 head's place in ProposalNet.body: after five conv, BN, ReLU triples


# How far (heat cells) a ProposalNet's output reads its input: 1 + 1 + 2 + 4 + 8 from its 3x3
# convolutions after the stride and their dilations, plus one for the first. A close network
# run on the grid's near rows and this many more gives there the heat of the whole grid.
PROPOSAL_REACH_CELLS = 17


REFINE_OUTPUTS = 7  # logit, d_range, d_cross, log_scale_range, log_scale_cross, log extents


class RefineNet(nn.Module):
    """Crop -> (logit, offsets, log scales, log extents)."""

    def __init__(self, crop_size: int = 96, channels: int = 2):
        super().__init__()
        self.features = nn.Sequential(
            *_conv(channels, 16, stride=2),
            *_conv(16, 32),
            nn.MaxPool2d(2),
            *_conv(32, 48),
            nn.MaxPool2d(2),
            *_conv(48, 64),
            nn.MaxPool2d(2),
            *_conv(64, 64),
            nn.MaxPool2d(2),
        )
        side = crop_size // 32
        self.head = nn.Sequential(
            nn.Flatten(),
            nn.Linear(64 * side * side, 128),
            nn.ReLU(inplace=True),
            nn.Linear(128, REFINE_OUTPUTS),
        )

    def forward(self, crops: torch.Tensor) -> torch.Tensor:
        out: torch.Tensor = self.head(self.features(crops))
        return out


def fused_for_inference(module: nn.Module) -> nn.Module:
    """A copy in eval mode with every Conv2d + BatchNorm2d pair folded into one convolution.

    The same function to float rounding (1e-6), a quarter less work: the service runs this.
    Its weights are laid out channels-last, as oneDNN's CPU convolutions run fastest (feed it
    `channels_last` inputs: about a third less time per crop, by hand in session 52).
    """
    import copy

    from torch.nn.utils.fusion import fuse_conv_bn_eval

    out = copy.deepcopy(module).eval()
    for seq in [m for m in out.modules() if isinstance(m, nn.Sequential)]:
        layers = list(seq)
        for i in range(len(layers) - 1):
            conv, bn = layers[i], layers[i + 1]
            if isinstance(conv, nn.Conv2d) and isinstance(bn, nn.BatchNorm2d):
                seq[i] = fuse_conv_bn_eval(conv, bn)
                seq[i + 1] = nn.Identity()
    for conv in [m for m in out.modules() if isinstance(m, nn.Conv2d)]:
        conv.weight.data = conv.weight.data.contiguous(memory_format=torch.channels_last)
    return out


class PolarNet(nn.Module):
    """Both stages under one state dict."""

    logit_offset: torch.Tensor
    near_logit_offset: torch.Tensor
    near_max_range_m: torch.Tensor
    near_edge_max_range_m: torch.Tensor
    near_edge_within_rad: torch.Tensor
    close_max_range_m: torch.Tensor

    def __init__(
        self,
        *,
        crop_size: int = 96,
        refine_channels: int = 2,
        inputs: Inputs = DEFAULT_INPUTS,
        near_refiner: bool = False,
        close_proposal: bool = False,
        proposal_width: int = PROPOSAL_WIDTH,
        close_width: int = PROPOSAL_WIDTH,
    ):
        super().__init__()
        self.crop_size = crop_size
        self.refine_channels = refine_channels  # 1: detail crop only; 2: detail and context
        self.inputs = inputs
        self.proposal = ProposalNet(proposal_width, channels=2 + inputs.extra_planes)
        self.refine = RefineNet(crop_size, refine_channels + inputs.extra_planes)
        # The operating point: subtracted from the refiner's logit so that confidence 0.5 is
        # the threshold chosen on validation runs (train.calibrate), not the raw 50%.
        self.register_buffer("logit_offset", torch.zeros(()))
        # The near refiner, for candidates nearer than `near_max_range_m`, with its own offset.
        self.near_refine: RefineNet | None = (
            RefineNet(crop_size, refine_channels + inputs.extra_planes) if near_refiner else None
        )
        self.register_buffer("near_logit_offset", torch.zeros(()))
        self.register_buffer("near_max_range_m", torch.zeros(()))
        # ... and for candidates nearer than this within `near_edge_within_rad` of the fan's
        # edge (0: none).
        self.register_buffer("near_edge_max_range_m", torch.zeros(()))
        self.register_buffer("near_edge_within_rad", torch.zeros(()))
        # The close proposal network, for the heat of rows nearer than `close_max_range_m`.
        self.close_proposal: ProposalNet | None = (
            ProposalNet(close_width, channels=2 + inputs.extra_planes) if close_proposal else None
        )
        self.register_buffer("close_max_range_m", torch.zeros(()))


def near_refined(net: PolarNet, *, range_m: float, azimuth_rad: float, half_fov_rad: float) -> bool:
    """Whether `net`'s near refiner (if any) scores a candidate at (range, azimuth)."""
    if net.near_refine is None:
        return False
    if range_m < float(net.near_max_range_m):
        return True
    return range_m < float(net.near_edge_max_range_m) and half_fov_rad - abs(azimuth_rad) < float(
        net.near_edge_within_rad
    )


def save(net: PolarNet, path: Path, *, meta: dict[str, Any]) -> None:
    """Weights as float32 with the format tag and the training metadata."""
    state = {k: v.detach().to(torch.float32).clone() for k, v in net.state_dict().items()}
    torch.save(
        {
            "format": FORMAT,
            "version": VERSION,
            "crop_size": net.crop_size,
            "refine_channels": net.refine_channels,
            "range_input": net.inputs.range_input,
            "coarse_beams": net.inputs.coarse_beams,
            "near_refiner": net.near_refine is not None,
            "close_proposal": net.close_proposal is not None,
            "proposal_width": net.proposal.width,
            "close_width": (
                PROPOSAL_WIDTH if net.close_proposal is None else net.close_proposal.width
            ),
            "state": state,
            "meta": meta,
        },
        path,
    )


def load(path: Path) -> PolarNet:
    """Load weights written by `save`; a clear error for anything else."""
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise CapsdError(f"{path}: no such weights file") from None
    except Exception as exc:  # torch raises many types for a bad file
        raise CapsdError(f"{path}: not a weights file ({exc})") from exc
    if not isinstance(blob, dict) or blob.get("format") != FORMAT:
        raise CapsdError(f"{path}: not a {FORMAT} weights file")
    if blob.get("version") != VERSION:
        raise CapsdError(f"{path}: weights version {blob.get('version')}, expected {VERSION}")
    # Weights saved before these existed: no range plane, the grid 128 cells wide.
    range_input = blob.get("range_input", "none")
    if range_input not in get_args(RangeInput):
        raise CapsdError(
            f"{path}: range_input {range_input!r}, expected one of {get_args(RangeInput)}"
        )
    coarse_beams = blob.get("coarse_beams", COARSE_BEAMS)
    if not isinstance(coarse_beams, int) or not 16 <= coarse_beams <= 1024:
        raise CapsdError(f"{path}: coarse_beams {coarse_beams!r}, expected 16 to 1024 cells")
    near_refiner = blob.get("near_refiner", False)  # weights saved before it existed: none
    if not isinstance(near_refiner, bool):
        raise CapsdError(f"{path}: near_refiner {near_refiner!r}, expected true or false")
    close_proposal = blob.get("close_proposal", False)  # ... before session 59: none
    if not isinstance(close_proposal, bool):
        raise CapsdError(f"{path}: close_proposal {close_proposal!r}, expected true or false")
    widths = {}
    for key in ("proposal_width", "close_width"):
        width = blob.get(key, PROPOSAL_WIDTH)  # ... before session 60: 32
        low, high = PROPOSAL_WIDTHS
        if not isinstance(width, int) or not low <= width <= high:
            raise CapsdError(f"{path}: {key} {width!r}, expected {low} to {high} channels")
        widths[key] = width
    net = PolarNet(
        crop_size=int(blob["crop_size"]),
        refine_channels=int(blob.get("refine_channels", 1)),
        inputs=Inputs(range_input=range_input, coarse_beams=coarse_beams),
        near_refiner=near_refiner,
        close_proposal=close_proposal,
        proposal_width=widths["proposal_width"],
        close_width=widths["close_width"],
    )
    state = dict(blob["state"])
    state.setdefault("logit_offset", torch.zeros(()))  # weights saved before calibration
    # Weights saved before the near refiner existed.
    state.setdefault("near_logit_offset", torch.zeros(()))
    state.setdefault("near_max_range_m", torch.zeros(()))
    state.setdefault("near_edge_max_range_m", torch.zeros(()))  # ... before session 56
    state.setdefault("near_edge_within_rad", torch.zeros(()))
    state.setdefault("close_max_range_m", torch.zeros(()))  # ... before session 59
    try:
        net.load_state_dict(state)
    except RuntimeError as exc:
        raise CapsdError(f"{path}: weights do not fit the network ({exc})") from exc
    net.eval()
    return net
