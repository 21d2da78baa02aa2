"""`capsd calibrate RECORDING`: the sonar mount and the depth offset from a calibration dive.

The recording holds the sonar frames, the ASV's poses and the ROV's depth and attitude
(`capsd record 'cap/**'` with the services running) while the ASV turns on the spot near the
tank's middle, a turn or two in about two minutes, walls in the sonar's range, and the ROV
floats at the surface before it dives. The mount fit (capsd.mount_calibration) gives the
sonar's heading, roll and horizontal position against the ASV's LiDAR-derived frame; the float
(capsd.depth_calibration) the offset of this autopilot boot's depth readings; each with its
uncertainty. Only what the data determined is written into the new locator config.

`--what range` reads another recording, made with the calibrated config: the ROV parked (on
the floor or a stand) while the ASV swings round it, facing it and looking to either side of
it; the fixes' offset along the line of sight (capsd.range_calibration) is the range offset
added to every detection's range, their offset along the ASV's axis the sonar's forward
position (when the ROV was seen across enough of the fan).

`--what pitch` reads a third, also made with the calibrated config: the ASV still, the ROV
holding its place in front of it and going slowly down and up through the sonar's vertical
aperture; where its echo fades above and below (capsd.pitch_calibration) gives the pitch. Two
such profiles at different distances (about 1.5 m and as far as the floor allows) give the
sonar's height too (`--orbit`: the range manoeuvre's recording, whose range offset took part
of the height in); from one, the offset is written as the pitch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar

import msgspec
import yaml

from capsd.codec import Codec
from capsd.depth_calibration import DepthFit, fit_depth_offset
from capsd.errors import CapsdError
from capsd.keys import Subject, subject_of
from capsd.mount_calibration import MountFit, Observation, corrected, fit_mount
from capsd.mounts import RovConfig, SonarMountConfig
from capsd.payloads import AsvPose, Payload, RovAttitude, RovDepth, RovFix, SonarFrame
from capsd.pitch_calibration import (
    ProfilesFit,
    ProfilesPrior,
    echo_samples,
    fit_profiles,
    rov_places,
    split_profiles,
)
from capsd.pose_lookup import PoseLookup
from capsd.range_calibration import RangeFit, fit_range_offset
from capsd.recording import Recorded, read
from capsd.services.locator.service import InstallationConfig
from capsd.simulator.install_errors import InstallErrorsConfig
from capsd.tank import TankBounds

EVERY_S = 0.5  # one frame per half second is plenty: neighbouring frames see the same walls
PITCH_EVERY_S = 0.2  # the ROV's echo: each frame's speckle and gain are its own
What = Literal["all", "mount", "depth", "range", "pitch"]
T = TypeVar("T", bound=Payload)


@dataclass(frozen=True)
class Calibration:
    """What was fitted (None: not asked for) and the configs with what was determined."""

    mount_fit: MountFit | None
    depth_fit: DepthFit | None
    mount: SonarMountConfig
    rov: RovConfig
    installation: InstallationConfig  # what the locator should still allow for
    range_fit: RangeFit | None = None
    pitch_fit: ProfilesFit | None = None

    def lines(self) -> list[str]:
        """What a person reads: each estimate, its uncertainty, and what could not be told."""
        return [
            *([] if self.mount_fit is None else self.mount_fit.lines()),
            *([] if self.depth_fit is None else self.depth_fit.lines()),
            *([] if self.range_fit is None else self.range_fit.lines()),
            *([] if self.pitch_fit is None else self.pitch_fit.lines()),
        ]

    @property
    def determined_anything(self) -> bool:
        """Whether the new config differs from the old one in anything."""
        m, d = self.mount_fit, self.depth_fit
        mount = m is not None and (m.yaw_determined or m.roll_determined or m.shift_determined)
        ranged = self.range_fit is not None and self.range_fit.determined
        pitched = self.pitch_fit is not None and self.pitch_fit.determined
        return mount or ranged or pitched or (d is not None and d.determined)

    @property
    def mount_changed(self) -> bool:
        """Whether a fit of the sonar mount ran (its config section is then rewritten)."""
        ranged = self.range_fit is not None and self.range_fit.determined
        pitched = self.pitch_fit is not None and self.pitch_fit.determined
        return self.mount_fit is not None or ranged or pitched


@dataclass
class _Streams:
    """The recording's messages this calibration reads, by stream, undecoded."""

    frames: list[Recorded] = field(default_factory=list)
    poses: list[Recorded] = field(default_factory=list)
    depths: list[Recorded] = field(default_factory=list)
    attitudes: list[Recorded] = field(default_factory=list)
    fixes: list[Recorded] = field(default_factory=list)


def _streams(recording: Path) -> _Streams:
    out = _Streams()
    by_subject = {
        Subject.SONAR_FRAME.value: out.frames,
        Subject.ASV_POSE.value: out.poses,
        Subject.ROV_DEPTH.value: out.depths,
        Subject.ROV_ATTITUDE.value: out.attitudes,
        Subject.ROV_FIX.value: out.fixes,
    }
    for message in read(recording):
        target = by_subject.get(subject_of(message.key))
        if target is not None:
            target.append(message)
    return out


def _decoded(messages: list[Recorded], cls: type[T]) -> list[T]:
    """Those that decode (a bad one is counted by its stream's own health, not here)."""
    codec = Codec(cls)
    out: list[T] = []
    for message in messages:
        try:
            out.append(codec.decode(message.data, encoding=message.encoding, key_expr=message.key))
        except CapsdError:
            continue
    return out


def _observations(
    streams: _Streams, recording: Path, *, every_s: float = EVERY_S
) -> list[Observation]:
    """Frames every `every_s`, each with the ASV pose at its stamp."""
    if not streams.frames:
        raise CapsdError(f"{recording}: no sonar frames in it (record cap/** with the frames)")
    poses = _decoded(streams.poses, AsvPose)
    if not poses:
        raise CapsdError(f"{recording}: no ASV poses in it (asv_pose must run while recording)")
    lookup = PoseLookup(poses)
    out: list[Observation] = []
    next_ns = 0
    frame_codec = Codec(SonarFrame)
    for message in sorted(streams.frames, key=lambda m: m.log_time_ns):
        try:
            frame = frame_codec.decode(message.data, encoding=None, key_expr=message.key)
        except CapsdError:
            continue
        if frame.stamp_ns < next_ns:
            continue
        asv = lookup.at(frame.stamp_ns)
        if asv is not None:
            out.append(Observation(frame, asv))
            next_ns = frame.stamp_ns + int(every_s * 1e9)
    return out


def calibrate(
    recording: Path,
    *,
    mount: SonarMountConfig,
    rov: RovConfig,
    tank: TankBounds,
    prior: InstallationConfig,
    what: What = "all",
    orbit: Path | None = None,
) -> Calibration:
    """The fits asked for, and the configs with what they determined applied.

    `orbit`: with `what="pitch"`, the range manoeuvre's recording (the sonar's height needs it).
    """
    streams = _streams(recording)
    mount_fit = depth_fit = None
    if what in ("all", "mount"):
        mount_fit = fit_mount(_observations(streams, recording), mount=mount, tank=tank)
    if what in ("all", "depth"):
        depth_fit = fit_depth_offset(
            _decoded(streams.depths, RovDepth), _decoded(streams.attitudes, RovAttitude), rov=rov
        )
    range_fit = pitch_fit = None
    if what == "range":
        range_fit = _range_fit(streams, recording, mount)
    if what == "pitch":
        # The range offset took part of a height error into the forward position: the height
        # is written only knowing how much (the orbit's recording).
        coupling = (
            None if orbit is None else _range_fit(_streams(orbit), orbit, mount).height_coupling
        )
        observations = _observations(streams, recording, every_s=PITCH_EVERY_S)
        try:
            places = rov_places(
                _decoded(streams.fixes, RovFix),
                _decoded(streams.depths, RovDepth),
                [o.frame.stamp_ns for o in observations],
            )
            samples = echo_samples(
                observations, places, mount=mount.transform(), beam_model=mount.beam_model
            )
            pitch_fit = fit_profiles(
                split_profiles(samples), height_coupling=coupling, prior=profiles_prior(prior)
            )
        except CapsdError as exc:
            raise CapsdError(f"{recording}: {exc}") from None
    return applied(mount, rov, prior, mount_fit, depth_fit, range_fit, pitch_fit)


def _range_fit(streams: _Streams, recording: Path, mount: SonarMountConfig) -> RangeFit:
    """The range offset from a recording of the parked ROV (its good fixes, the ASV's poses)."""
    poses = _decoded(streams.poses, AsvPose)
    if not poses:
        raise CapsdError(f"{recording}: no ASV poses in it (asv_pose must run while recording)")
    try:
        return fit_range_offset(
            _decoded(streams.fixes, RovFix), PoseLookup(poses), mount=mount.transform()
        )
    except CapsdError as exc:
        raise CapsdError(f"{recording}: {exc}") from None


def applied(
    mount: SonarMountConfig,
    rov: RovConfig,
    prior: InstallationConfig,
    mount_fit: MountFit | None,
    depth_fit: DepthFit | None,
    range_fit: RangeFit | None = None,
    pitch_fit: ProfilesFit | None = None,
) -> Calibration:
    """The configs with what the fits determined applied, and what is left to allow for."""
    if mount_fit is not None:
        mount = corrected(mount, mount_fit)
    if range_fit is not None and range_fit.determined:
        # Ranges too long: every detection's range less that much; fixes too far along the
        # ASV's axis: the sonar sits that much further back than configured.
        x, y, z = mount.position_m
        if range_fit.forward_determined:
            x = round(x - range_fit.forward_m, 4)
        offset = round(mount.range_offset_m - range_fit.range_offset_m, 4)
        mount = msgspec.structs.replace(mount, position_m=(x, y, z), range_offset_m=offset)
    if pitch_fit is not None and pitch_fit.determined:
        pitch = round(mount.pitch_deg + pitch_fit.pitch_correction_deg, 4)
        mount = msgspec.structs.replace(mount, pitch_deg=pitch)
    if pitch_fit is not None and pitch_fit.height_determined:
        # B's z is up: the sonar truly sits height_m higher; the range offset gives back what
        # it took of the height.
        x, y, z = mount.position_m
        offset = round(mount.range_offset_m + pitch_fit.range_give_back_m, 4)
        mount = msgspec.structs.replace(
            mount, position_m=(x, y, round(z + pitch_fit.height_m, 4)), range_offset_m=offset
        )
    if depth_fit is not None and depth_fit.determined:
        rov = msgspec.structs.replace(rov, depth_offset_m=round(depth_fit.offset_m, 4))
    installation = installation_after(prior, mount_fit, depth_fit, range_fit, pitch_fit)
    return Calibration(mount_fit, depth_fit, mount, rov, installation, range_fit, pitch_fit)


def tape_prior(errors: InstallErrorsConfig) -> InstallationConfig:
    """What a team that measured its installation with a tape knows it may have got wrong.

    The sizes the simulator draws its errors from (docs/INSTALL-ERRORS.md): the locator's
    `installation` section before `capsd calibrate`.
    """
    angle, position = errors.sonar_angle_sigma_deg, errors.sonar_position_sigma_m
    return InstallationConfig(
        range_scale=errors.sound_speed_sigma,
        sonar_position_m=(position, position, position),
        sonar_angles_deg=(angle, angle, angle),
        depth_offset_m=math.hypot(errors.depth_bias_sigma_m, errors.pressure_arm_sigma_m),
    )


def profiles_prior(installation: InstallationConfig) -> ProfilesPrior:
    """What the pitch manoeuvre's fit weighs in: the installation's pitch and height 1-sigma.

    The profiles see the sonar's height against the ROV's depth reference, so the height's
    prior holds the depth offset's 1-sigma too (the surface check's, once it ran).
    """
    return ProfilesPrior(
        pitch_sigma_rad=math.radians(installation.sonar_angles_deg[1]),
        height_sigma_m=math.hypot(installation.sonar_position_m[2], installation.depth_offset_m),
    )


def installation_after(
    prior: InstallationConfig,
    mount_fit: MountFit | None,
    depth_fit: DepthFit | None,
    range_fit: RangeFit | None = None,
    pitch_fit: ProfilesFit | None = None,
) -> InstallationConfig:
    """What the installation may still get wrong after the fits.

    Their 1-sigma where they determined a term; the prior (the tape's, from the locator
    config) where they did not.
    """
    yaw, pitch, roll = prior.sonar_angles_deg
    x, y, z = prior.sonar_position_m
    if mount_fit is not None:
        yaw = mount_fit.yaw_sigma_deg if mount_fit.yaw_determined else yaw
        roll = mount_fit.roll_sigma_deg if mount_fit.roll_determined else roll
        y = mount_fit.shift_y_sigma_m if mount_fit.shift_determined else y
    if range_fit is not None and range_fit.determined:
        # Near the boresight a range offset moves a fix as the forward position does.
        x = range_fit.range_offset_sigma_m
        if range_fit.forward_determined:
            x = math.hypot(x, range_fit.forward_sigma_m)
    if pitch_fit is not None and pitch_fit.determined:
        pitch = pitch_fit.offset_sigma_deg
    if pitch_fit is not None and pitch_fit.height_determined:
        z = pitch_fit.height_sigma_m
        coupling = pitch_fit.height_coupling or 0.0
        x = math.hypot(x, coupling * pitch_fit.height_sigma_m)
    depth = prior.depth_offset_m
    if depth_fit is not None and depth_fit.determined:
        depth = depth_fit.sigma_m
    return msgspec.structs.replace(
        prior,
        sonar_position_m=(round(x, 4), round(y, 4), round(z, 4)),
        sonar_angles_deg=(round(yaw, 4), round(pitch, 4), round(roll, 4)),
        depth_offset_m=round(depth, 4),
    )


def write_config(
    source: Path, out: Path, calibration: Calibration, recording: Path
) -> dict[str, Any]:
    """A copy of the locator config `source` with what was calibrated, and its provenance.

    Returns what it wrote (the config's data).
    """
    data: dict[str, Any] = yaml.safe_load(source.read_text()) or {}
    if calibration.mount_changed:
        data["sonar"] = calibrated_sonar(data.get("sonar") or {}, calibration)
    if calibration.depth_fit is not None and calibration.depth_fit.determined:
        rov = dict(data.get("rov") or {})
        rov["depth_offset_m"] = calibration.rov.depth_offset_m
        data["rov"] = rov
    data["installation"] = msgspec.to_builtins(calibration.installation)
    _write(out, data, source, calibration, recording)
    return data


def write_detector_config(
    source: Path,
    out: Path,
    calibration: Calibration,
    recording: Path,
    *,
    locator_sonar: dict[str, Any],
) -> None:
    """A copy of the sonar_detect config `source` whose depth gate sees the calibrated sonar.

    The gate's `sonar` section becomes the calibrated locator's whole `sonar` section
    (`locator_sonar`, as `write_config` wrote it: the mount and its servos), so that the
    detector rules candidates out against the sonar the locator fixes with.
    """
    data: dict[str, Any] = yaml.safe_load(source.read_text()) or {}
    gate = dict(data.get("depth_gate") or {})
    gate["sonar"] = locator_sonar
    data["depth_gate"] = gate
    _write(out, data, source, calibration, recording)


def calibrated_sonar(section: dict[str, Any], calibration: Calibration) -> dict[str, Any]:
    """A config's `sonar` section with the calibrated mount's fields (servos kept)."""
    mount = calibration.mount
    sonar = dict(section)
    sonar.update(
        position_m=list(mount.position_m),
        yaw_deg=mount.yaw_deg,
        pitch_deg=mount.pitch_deg,
        roll_deg=mount.roll_deg,
        range_offset_m=mount.range_offset_m,
    )
    return sonar


def _write(
    out: Path, data: dict[str, Any], source: Path, calibration: Calibration, recording: Path
) -> None:
    header = [
        f"# {source.name} calibrated by `capsd calibrate {recording.name}`:",
        *(f"#   {line}" for line in calibration.lines()),
    ]
    out.write_text("\n".join(header) + "\n" + yaml.safe_dump(data, sort_keys=False))
