"""`capsd bench ...`: the benchmarks, each printing its figures."""

from __future__ import annotations

import argparse
import itertools
from pathlib import Path
from typing import TYPE_CHECKING, cast, get_args

from capsd.cli.common import Subcommands, fail
from capsd.launch import (
    EXIT_CONFIG,
    EXIT_FAILURE,
    EXIT_OK,
    non_negative_float,
    non_negative_int,
    positive_float,
    positive_int,
)

if TYPE_CHECKING:
    from capsd.simulator.sonar_look import OutsideKnob


def _cmd_bench_sim(args: argparse.Namespace) -> int:
    from capsd.bench import sim

    return sim.run(
        tank=args.tank, trajectory=args.trajectory, duration_s=args.duration, warmup_s=args.warmup
    )


def _cmd_bench_finetune(args: argparse.Namespace) -> int:
    from capsd.bench import finetune

    if not (args.duration > 0 and args.eval_duration > 0):
        return fail("bench finetune: durations must be positive", EXIT_CONFIG)
    outside_knobs = _outside_knobs("bench finetune", args.outside_knobs)
    if isinstance(outside_knobs, int):
        return outside_knobs
    return finetune.run(
        out=args.out,
        duration_s=args.duration,
        eval_duration_s=args.eval_duration,
        outside_knobs=outside_knobs,
    )


def _outside_knobs(command: str, knobs: list[str] | None) -> tuple[OutsideKnob, ...] | int | None:
    """`--outside-knobs` checked: the knobs (None: all five), or the exit status of a refusal."""
    from capsd.simulator.sonar_look import OutsideKnob

    named = ("none", *get_args(OutsideKnob))
    for knob in knobs or ():
        if knob not in named:
            return fail(
                f"{command}: --outside-knobs {knob}: one of {', '.join(named)}", EXIT_CONFIG
            )
    if knobs is not None and "none" in knobs and len(knobs) > 1:
        return fail(
            f"{command}: --outside-knobs {' '.join(knobs)}: 'none' stands alone", EXIT_CONFIG
        )
    return None if knobs is None else tuple(cast(OutsideKnob, k) for k in knobs if k != "none")


def _cmd_bench_detect(args: argparse.Namespace) -> int:
    from capsd.bench import detect

    for weights in args.weights or []:
        if not weights.is_file():
            return fail(f"bench detect: --weights {weights}: no such file", EXIT_CONFIG)
    mirrors = tuple(dict.fromkeys(args.mirror_average))
    if args.examples is not None and (
        args.detector == "classical" or args.throughput or args.prior_sweep
    ):
        return fail(
            "bench detect: --examples draws the configured CNN's misses and false alarms on the "
            "held-out runs: not with --detector classical, --throughput or --prior-sweep",
            EXIT_CONFIG,
        )
    if args.throughput:
        return detect.run_throughput(
            frames=args.frames,
            which=args.detector,
            weights=args.weights,
            options=detect.CnnOptions(mirror_averages=mirrors, max_candidates=args.max_candidates),
        )
    if not 0.0 < args.proposal_threshold < 1.0:
        return fail(
            f"bench detect: --proposal-threshold {args.proposal_threshold:g}: between 0 and 1",
            EXIT_CONFIG,
        )
    track_bar: float | None = None
    if args.track_proposal_threshold != "off":
        try:
            track_bar = float(args.track_proposal_threshold)
        except ValueError:
            track_bar = None
        if track_bar is None or not 0.0 < track_bar < 1.0:
            return fail(
                f"bench detect: --track-proposal-threshold {args.track_proposal_threshold}: "
                "between 0 and 1, or off",
                EXIT_CONFIG,
            )
    options = detect.CnnOptions(
        search_refines=args.search_refines,
        track_hold_s=args.track_hold,
        proposal_threshold=args.proposal_threshold,
        track_proposal_threshold=track_bar,
        mirror_averages=mirrors,
        max_candidates=args.max_candidates,
    )
    starts = tuple(args.start) if args.start is not None else detect.BENCH_STARTS_S
    duration_s = args.duration if args.duration is not None else detect.BENCH_WINDOW_S
    for start in starts:
        if not 0.0 <= start <= 1500.0:
            return fail(f"bench detect: --start {start:g}: between 0 and 1500 s", EXIT_CONFIG)
    starts = tuple(sorted(starts))
    # A start given twice is an overlap too.
    if any(b - a < duration_s for a, b in itertools.pairwise(starts)):
        return fail(
            f"bench detect: --start {' '.join(f'{s:g}' for s in starts)}: stretches of "
            f"{duration_s:g} s overlap",
            EXIT_CONFIG,
        )
    if args.outside_knobs is not None and "outside" not in (args.looks or ()):
        return fail("bench detect: --outside-knobs needs --looks ... outside", EXIT_CONFIG)
    outside_knobs = _outside_knobs("bench detect", args.outside_knobs)
    if isinstance(outside_knobs, int):
        return outside_knobs
    if args.prior_sweep:
        return detect.sweep_prior(
            args.prior_sweep, duration_s=duration_s, options=options, starts_s=starts
        )
    return detect.run(
        duration_s=duration_s,
        which=args.detector,
        fixtures=args.fixtures,
        weights=args.weights,
        json_out=args.json,
        options=options,
        starts_s=starts,
        depth_gate=args.depth_gate,
        looks=tuple(dict.fromkeys(args.looks)) if args.looks else detect.LOOKS,
        outside_knobs=outside_knobs,
        runs=detect.RUN_SETS[args.runs],
        examples_dir=args.examples,
        confidence=args.confidence,
    )


def _cmd_bench_calibrate(args: argparse.Namespace) -> int:
    from capsd.bench import calibrate

    calibrate.bench(
        seeds=args.seeds,
        duration_s=args.duration,
        tank=args.tank,
        trajectory="square",
        out=args.out,
    )
    return EXIT_OK


def _cmd_bench_evaluate(args: argparse.Namespace) -> int:
    from capsd.bench import evaluate

    result = evaluate.bench(
        tank=args.tank,
        trajectory=args.trajectory,
        seed=args.seed,
        duration_s=args.duration,
        out_dir=args.out,
        detector=args.detector,
    )
    return EXIT_OK if all(result["verdicts"].values()) else EXIT_FAILURE


def _cmd_bench_consistency(args: argparse.Namespace) -> int:
    from capsd.bench import consistency

    consistency.bench(duration_s=args.duration, out=args.out)
    return EXIT_OK


def _cmd_bench_accuracy(args: argparse.Namespace) -> int:
    from capsd.bench import accuracy

    accuracy.bench(
        duration_s=args.duration,
        seed=args.seed,
        out_dir=args.out,
        install_errors=args.install_errors,
    )
    return 0


def _cmd_bench_faults(args: argparse.Namespace) -> int:
    from capsd.bench import faults

    return faults.bench(out=args.out, baseline_s=args.baseline, skew_s=args.skew_duration)


def _cmd_bench_latency(args: argparse.Namespace) -> int:
    from capsd.bench import latency

    return latency.run(
        rates_hz=tuple(args.rates),
        duration_s=args.duration,
        warmup_s=args.warmup,
        out=args.out,
        busy_cores=args.busy_cores,
    )


def _cmd_bench_asv_pose(args: argparse.Namespace) -> int:
    from capsd.bench import asv_pose

    return asv_pose.run(seconds=args.duration)


def _cmd_bench_search(_args: argparse.Namespace) -> int:
    from capsd.bench import search

    return search.run()


def _cmd_bench_follow(args: argparse.Namespace) -> int:
    from capsd.bench import follow

    return follow.run(
        args.tank,
        args.mission,
        drive=args.asv_drive,
        duration_s=args.duration,
        seeds=args.seeds,
        asv_mode=args.asv,
        tilt=args.sonar_tilt,
        detect_from_m=args.detect_from,
        detect_within_deg=args.detect_within,
    )


def _cmd_bench_footprint(args: argparse.Namespace) -> int:
    from capsd.bench import footprint

    return footprint.bridge(runs=args.runs, settle_s=args.settle)


def register(sub: Subcommands) -> None:
    """Add the bench verbs to the `capsd` parser's subcommands."""
    bench = sub.add_parser(
        "bench",
        help="benchmarks that print measured figures",
        description="Benchmarks: each prints figures measured in one run.",
    )
    bench_sub = bench.add_subparsers(dest="bench_command", required=True, metavar="BENCH")
    foot = bench_sub.add_parser(
        "footprint",
        help="start-up time and resident memory of the MAVLink bridge",
        description="Start the bridge against a local router and the autopilot stand-in; "
        "print start-up time to READY=1, resident memory and heavy libraries.",
    )
    foot.add_argument("--runs", type=positive_int, default=5, help="repetitions (median reported)")
    foot.add_argument("--settle", type=float, default=3.0, help="seconds running before RSS")
    foot.set_defaults(func=_cmd_bench_footprint)
    bsim = bench_sub.add_parser(
        "sim",
        help="achieved rate and CPU per stream of the real-time simulator",
        description="Run `capsd sim` as its own process; print each stream's achieved rate and "
        "CPU share next to its target, and the process's total CPU.",
    )
    bsim.add_argument("--tank", choices=["nfp", "mockup", "pond"], default="nfp")
    bsim.add_argument(
        "--trajectory",
        default="lawnmower",
        choices=["square", "lawnmower", "bouncing", "random", "two_floor"],
    )
    bsim.add_argument("--duration", type=positive_float, default=20.0, help="seconds measured")
    bsim.add_argument("--warmup", type=positive_float, default=4.0, help="seconds before measuring")
    bsim.set_defaults(func=_cmd_bench_sim)
    bdet = bench_sub.add_parser(
        "detect",
        help="detectors on held-out simulated frames against the labels",
        description="Detection rate, false alarms per frame, range/azimuth errors (median, "
        "p90) in the simulator's fixed look and in held-out look settings (docs/SONAR-"
        "VARIETY.md), with and without clutter overlapping the ROV and by range band; the "
        "paper's box-centre pipeline as the baseline; detections on real Oculus pings (none "
        "allowed); or time per frame.",
    )
    bdet.add_argument(
        "--duration",
        type=positive_float,
        default=None,
        help="seconds per stretch of each run (default 5)",
    )
    bdet.add_argument(
        "--start",
        type=float,
        nargs="+",
        default=None,
        metavar="S",
        help="seconds into each run's paths where each scored stretch begins "
        "(default 0 120 240: the start and two later stretches)",
    )
    bdet.add_argument("--json", type=Path, default=None, help="also write the figures as JSON")
    bdet.add_argument(
        "--examples",
        type=Path,
        default=None,
        metavar="DIR",
        help="also write PNGs of the configured CNN's misses and false alarms here, one per "
        "look, a row per run",
    )
    bdet.add_argument(
        "--runs",
        choices=["held-out", "near", "close"],
        default="held-out",
        help="held-out: the bench's runs, 1.5-20 m; near: a small tank's ASV 0.6 m off the ROV, "
        "its sonar 60 deg down, the ROV 0.5-1.5 m off; close: the ASV 1.5 m off, the sonar 30 "
        "deg down, the ROV 1.2-2 m off at every elevation (default: %(default)s)",
    )
    bdet.add_argument(
        "--fixtures",
        type=Path,
        default=Path("tests/fixtures/oculus"),
        help="folder of raw Oculus captures without an ROV (skipped if absent)",
    )
    bdet.add_argument(
        "--detector", choices=["all", "classical", "cnn"], default="all", help="which to run"
    )
    bdet.add_argument(
        "--throughput",
        action="store_true",
        help="instead: per-frame latency on 512 x 1000 frames on one CPU core",
    )
    bdet.add_argument(
        "--frames", type=positive_int, default=300, help="frames timed (--throughput)"
    )
    bdet.add_argument(
        "--prior-sweep",
        type=float,
        nargs="+",
        metavar="LOGIT",
        help="instead: the CNN's hysteresis prior on the validation runs (e.g. 0 1 2)",
    )
    bdet.add_argument(
        "--weights",
        type=Path,
        nargs="+",
        metavar="PT",
        help="CNN weights to compare in one run (default: the shipped ones), each named by "
        "its folder",
    )
    bdet.add_argument(
        "--depth-gate",
        choices=("off", "truth"),
        default="off",
        help="truth: the service's depth-aware search, given the true ASV pose and ROV depth "
        "(what the deployed detector finds); off: the detector alone (default: %(default)s)",
    )
    bdet.add_argument(
        "--confidence",
        choices=("exclusive", "independent"),
        default="exclusive",
        help="the service's cnn.confidence: exclusive, each CNN candidate the probability that "
        "it is the one ROV among the frame's; independent, each scored alone (default: "
        "%(default)s; the classical detector's scores as they are either way)",
    )
    bdet.add_argument(
        "--looks",
        nargs="+",
        choices=("off", "heldout", "outside"),
        default=None,
        help="the looks rendered (default: off heldout; outside: five knobs just beyond the "
        "range trained on, docs/SONAR-VARIETY.md, a look no training run has)",
    )
    bdet.add_argument(
        "--outside-knobs",
        nargs="+",
        default=None,
        metavar="KNOB",
        help="with --looks outside: only these knobs beyond the range trained on, the rest "
        "from their whole range and the same draws ('none': no knob beyond; default: all "
        "five with an outside band, docs/SONAR-VARIETY.md)",
    )
    bdet.add_argument(
        "--search-refines",
        choices=("proposals", "proposals_and_track"),
        default="proposals_and_track",
        help="the service's cnn.search_refines for the CNN with its settings (default: "
        "%(default)s)",
    )
    bdet.add_argument(
        "--track-hold",
        type=non_negative_float,
        default=0.0,
        metavar="S",
        help="the service's cnn.track_hold_s for the CNN with its settings (default: %(default)s)",
    )
    bdet.add_argument(
        "--proposal-threshold",
        type=float,
        default=0.1,
        metavar="P",
        help="the service's cnn.proposal_threshold for the CNN, searching alone too (default: "
        "%(default)s)",
    )
    bdet.add_argument(
        "--max-candidates",
        type=positive_int,
        default=6,  # CnnOptions and the service (not imported here: start-up time)
        metavar="K",
        help="the service's cnn.max_candidates: proposals refined per whole-frame search, "
        "for the CNN with its settings and alone, and in --throughput (default: %(default)s)",
    )
    bdet.add_argument(
        "--track-proposal-threshold",
        default="0.03",  # CnnOptions and the service (not imported here: start-up time)
        metavar="P",
        help="the service's cnn.track_proposal_threshold for the CNN with its settings, a "
        "number or off (default: %(default)s)",
    )
    bdet.add_argument(
        "--mirror-average",
        nargs="+",
        choices=("off", "refiner", "both"),
        default=["refiner"],  # the service's default
        help="the service's cnn.mirror_average (crops, and with both the frame, also read "
        "mirrored, the answers averaged); several: the CNN once with each, in one run "
        "(default: %(default)s)",
    )
    bdet.set_defaults(func=_cmd_bench_detect)
    bft = bench_sub.add_parser(
        "finetune",
        help="the fine-tune path on a sonar look outside the training variety, before/after",
        description="A simulated first dive in a look never trained on, recorded; `capsd "
        "label` on it; `capsd train detector --finetune`; both weights on held-out runs.",
    )
    bft.add_argument("--out", type=Path, default=Path("reports/finetune"), help="report folder")
    bft.add_argument(
        "--duration", type=positive_float, default=60.0, help="first dive, simulated s"
    )
    bft.add_argument(
        "--eval-duration", type=positive_float, default=15.0, help="seconds per held-out run"
    )
    bft.add_argument(
        "--outside-knobs",
        nargs="+",
        default=None,
        metavar="KNOB",
        help="only these knobs beyond the range trained on in the site's look, the rest from "
        "their whole range and the same draws (default: all five with an outside band)",
    )
    bft.set_defaults(func=_cmd_bench_finetune)
    bcal = bench_sub.add_parser(
        "calibrate",
        help="how well `capsd calibrate` recovers the simulator's hidden mount errors",
        description="Per seed, simulated runs of the calibration manoeuvres (the ASV turning "
        "on the spot while the ROV floats; the ASV swinging round the parked ROV; the ROV "
        "going down and up in front of the still ASV) with realistic installation errors, "
        "through the services' own pose estimate and locator; the fitted corrections against "
        "those the hidden errors call for.",
    )
    bcal.add_argument("--seeds", type=positive_int, default=5, help="runs (seeds 500, 501, ...)")
    bcal.add_argument(
        "--duration", type=positive_float, default=120.0, help="simulated seconds per run"
    )
    bcal.add_argument(
        "--tank",
        choices=["nfp", "mockup", "pond"],
        default="pond",
        help="pond: the tank held out of training and tuning",
    )
    bcal.add_argument(
        "--out", type=Path, default=Path("reports/calibrate.json"), help="figures as JSON"
    )
    bcal.set_defaults(func=_cmd_bench_calibrate)
    beval = bench_sub.add_parser(
        "evaluate",
        help="`capsd evaluate` on a simulated dive with a rotated, shifted, late reference",
        description="The offline pipeline's fixes and a motion-capture stand-in (the tank "
        "frame rotated 30 deg and shifted 2 m, stamps 150 ms late, 100 Hz, 0.5 mm noise, "
        "marker swaps, an occlusion) in one recording; `capsd evaluate`'s recovered transform, "
        "clock offset and MED against the known answer and the accuracy bench's MED.",
    )
    beval.add_argument("--tank", choices=["nfp", "mockup", "pond"], default="nfp")
    beval.add_argument(
        "--trajectory",
        choices=["square", "lawnmower", "bouncing", "random", "two_floor"],
        default="square",
    )
    beval.add_argument("--seed", type=int, default=0, help="simulator seed")
    beval.add_argument("--duration", type=positive_float, default=300.0, help="simulated seconds")
    beval.add_argument(
        "--detector",
        choices=["cnn", "truth"],
        default="cnn",
        help="cnn: the shipped detector's fixes; truth: the ROV's true centre as the one "
        "candidate (checks the evaluation alone, without the detector's misses and outliers)",
    )
    beval.add_argument(
        "--out", type=Path, default=Path("reports/bench-evaluate"), help="report folder"
    )
    beval.set_defaults(func=_cmd_bench_evaluate)
    bcons = bench_sub.add_parser(
        "consistency",
        help="the locator's covariance floor derived on tuning runs, NEES on held-out ones",
        description="The smallest covariance floor with which 95 %% of fixes' NEES fall under "
        "the chi-square bound on tuning runs; the NEES on the held-out pond with it, with the "
        "configured floor and with none.",
    )
    bcons.add_argument("--duration", type=positive_float, default=60.0, help="seconds per run")
    bcons.add_argument(
        "--out", type=Path, default=Path("reports/consistency.json"), help="figures as JSON"
    )
    bcons.set_defaults(func=_cmd_bench_consistency)
    bacc = bench_sub.add_parser(
        "accuracy",
        help="the paper's results table: its method vs ours on the same runs, and an ablation",
        description="Five trajectories in the nfp tank, one in the mockup and two in the held-out "
        "pond through the "
        "offline pipeline; x/y/z RMSE, MED, p95, availability; targets; ablation; PNGs.",
    )
    bacc.add_argument(
        "--duration", type=positive_float, default=60.0, help="simulated seconds per run"
    )
    bacc.add_argument("--seed", type=int, default=0, help="simulator seed")
    bacc.add_argument("--out", type=Path, default=Path("reports/accuracy"), help="report folder")
    bacc.add_argument(
        "--install-errors",
        choices=("off", "realistic"),
        default="off",
        help="realistic: mount, sound-speed, depth and attitude errors drawn per run and "
        "unknown to the services (docs/INSTALL-ERRORS.md); the services stay uncalibrated",
    )
    bacc.set_defaults(func=_cmd_bench_accuracy)
    bpose = bench_sub.add_parser(
        "asv_pose",
        help="ASV pose error against the simulator's truth (both tanks, both modes)",
        description="Run the pose estimator on simulated IMU and LiDAR (waves on), ASV stationary "
        "and following; print RMS position, yaw, roll and pitch error and the targets.",
    )
    bpose.add_argument("--duration", type=positive_float, default=60.0, help="seconds per run")
    bpose.set_defaults(func=_cmd_bench_asv_pose)
    bsearch = bench_sub.add_parser(
        "search",
        help="how soon the ASV's follower sees a lost, drifting ROV again (mockup geometry)",
        description="48 losses in the mockup (3 stop points, 8 directions, 0.3 or 0.6 m off "
        "the last fix, drifting 1 cm/s), the follower's ASV a perfect autopilot: how many are "
        "seen again within 150 s, within 60 s, the median time.",
    )
    bsearch.set_defaults(func=_cmd_bench_search)
    bfollow = bench_sub.add_parser(
        "follow",
        help="a mission with the ASV following, geometry alone (a perfect detector), in seconds",
        description="Fly a mission plan on the simulated ArduSub with the follower driving the "
        "simulated ArduRover (the demo's settings), fixes the true position whenever the ROV is "
        "in the sonar's view; print the share of the mission's time in view, the losses of 5 s "
        "or more, the ASV's nearest wall. What the follower's choices give, apart from the "
        "detector (`capsd demo --mission PLAN --asv follow` has both).",
    )
    bfollow.add_argument("--tank", choices=("nfp", "mockup", "pond"), default="nfp")
    bfollow.add_argument(
        "--mission",
        type=Path,
        default=Path("deploy/missions/nfp-lawnmower.yaml"),
        help="the plan (default: deploy/missions/nfp-lawnmower.yaml)",
    )
    bfollow.add_argument("--asv-drive", choices=("steered", "lateral"), default="steered")
    bfollow.add_argument(
        "--asv",
        choices=("follow", "station"),
        default="follow",
        help="station: the ASV held where it starts (the pilot's station for the plan's start), "
        "to compare with following",
    )
    bfollow.add_argument(
        "--sonar-tilt",
        choices=("fixed", "servo", "pan-tilt"),
        default="fixed",
        help="servo: the sonar on a tilt servo the follower drives (30 deg/s, -15 to +40 deg "
        "about the mount's pitch); pan-tilt: on a pan servo too (60 deg/s, +-90 deg)",
    )
    bfollow.add_argument("--duration", type=positive_float, default=900.0,
                         help="seconds at most per run")  # fmt: skip
    bfollow.add_argument("--seeds", type=int, default=1, help="runs (fix noise seeds)")
    bfollow.add_argument(
        "--detect-from",
        type=positive_float,
        default=0.3,
        help="metres: no fix of a ROV nearer the sonar than this (default 0.3; the shipped "
        "detector misses a quarter to half of the pings under 0.95 m in the mockup demo)",
    )
    bfollow.add_argument(
        "--detect-within",
        type=positive_float,
        default=60.0,
        help="degrees: no fix of a ROV further off the boresight than this (default 60; the "
        "fan is 130 deg wide, and a detector may lose a ROV crossing its edges)",
    )
    bfollow.set_defaults(func=_cmd_bench_follow)
    blat = bench_sub.add_parser(
        "latency",
        help="ping to autopilot latency per stage at 10/20/40 Hz, Zenoh floor, CPU and RSS",
        description="Run the whole pipeline (as `capsd demo`) once per sonar rate; print the "
        "latency of each stage and end to end (median, p99), the bare Zenoh floor for the "
        "same payload sizes, frames dropped, CPU share and resident memory per service, and "
        "the 40 Hz targets next to the measured values.",
    )
    blat.add_argument(
        "--rates", type=float, nargs="+", default=[10.0, 20.0, 40.0], help="sonar rates, Hz"
    )
    blat.add_argument(
        "--duration", type=positive_float, default=30.0, help="seconds measured per rate"
    )
    blat.add_argument(
        "--warmup", type=positive_float, default=5.0, help="seconds after the first VPE"
    )
    blat.add_argument(
        "--busy-cores",
        type=non_negative_int,
        default=0,
        help="other processes that each keep a core busy during the run (a loaded computer)",
    )
    blat.add_argument("--out", type=Path, default=Path("reports/latency"), help="report folder")
    blat.set_defaults(func=_cmd_bench_latency)
    bfault = bench_sub.add_parser(
        "faults",
        help="inject faults (kill -9, router restart, dropouts, clock skew); judge ArduSub input",
        description="Run the demo pipeline and inject one fault at a time; print per fault the "
        "recovery time, good fixes lost, and the estimates the autopilot received that were "
        "stale, invalid or wrong by more than 3 sigma against the simulator's truth.",
    )
    bfault.add_argument("--baseline", type=float, default=10.0, help="seconds without a fault")
    bfault.add_argument(
        "--skew-duration", type=float, default=25.0, help="seconds per clock-skew run"
    )
    bfault.add_argument("--out", type=Path, default=Path("reports/faults"), help="report folder")
    bfault.set_defaults(func=_cmd_bench_faults)
