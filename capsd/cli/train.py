"""`capsd train detector|proposal|refiner|near-refiner|calibrate|range-bias`, `capsd label`."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import get_args

from capsd.cli.common import Subcommands, fail
from capsd.errors import CapsdError
from capsd.launch import (
    EXIT_CONFIG,
    EXIT_FAILURE,
    EXIT_OK,
    positive_float,
    positive_int,
)
from capsd.services.sonar_detect.one_rov import DEFAULT_CONFIDENCE, Confidence


def _cmd_train_calibrate(args: argparse.Namespace) -> int:
    from capsd.train.detector import TrainConfig, recalibrate

    try:
        recalibrate(
            args.weights,
            duration_s=(
                TrainConfig.calibration_duration_s if args.duration is None else args.duration
            ),
            confidence=args.confidence,
        )
    except CapsdError as exc:
        return fail(f"calibrate: {exc}", EXIT_CONFIG)
    return EXIT_OK


def _cmd_train_range_bias(args: argparse.Namespace) -> int:
    from capsd.services.sonar_detect.range_bias import DEFAULT_TABLE
    from capsd.train.range_bias import PITCH_DEG, STEEP_PITCH_DEG, run, run_evaluate

    try:
        if args.evaluate is not None:
            run_evaluate(
                args.evaluate or ["none", "shipped"],
                runs=args.runs,
                duration_s=args.duration,
                pitch_deg=tuple(args.pitch_deg or PITCH_DEG),
                json_out=args.json,
            )
        else:
            run(
                runs=args.runs,
                steep_runs=args.steep_runs,
                duration_s=args.duration,
                out=args.out or DEFAULT_TABLE,
                pitch_deg=tuple(args.pitch_deg or STEEP_PITCH_DEG),
            )
    except CapsdError as exc:
        return fail(f"range-bias: {exc}", EXIT_CONFIG)
    return EXIT_OK


def _cmd_train_near_refiner(args: argparse.Namespace) -> int:
    from capsd.train.near_refiner import (
        NearRefinerConfig,
        recalibrate_near_refiner,
        train_near_refiner,
    )

    config = NearRefinerConfig(
        seed=args.seed,
        near_runs=args.near_runs,
        edge_runs=args.edge_runs,
        other_runs=args.other_runs,
        epochs=args.epochs,
        max_range_m=args.max_range,
        edge_max_range_m=args.edge_max_range,
        edge_within_deg=args.edge_within,
        workers=args.workers,
        threads=args.threads,
        evaluate=args.evaluate,
    )
    try:
        if args.calibrate_only:
            recalibrate_near_refiner(args.weights, args.out, config)
        else:
            train_near_refiner(args.weights, args.out, config)
    except CapsdError as exc:
        return fail(str(exc), EXIT_CONFIG)
    return EXIT_OK


def _cmd_train_proposal(args: argparse.Namespace) -> int:
    from capsd.train.proposal import ProposalConfig, train_proposal

    config = ProposalConfig(
        seed=args.seed,
        network=args.network,
        close_share=args.close_share,
        close_max_range_m=args.close_max_range,
        **({} if args.width is None else {"width": args.width}),
        targets=args.targets,
        rack_heights=args.rack_heights,
        workers=args.workers,
        threads=args.threads,
        evaluate=args.evaluate,
    )
    try:
        train_proposal(args.weights, args.out, config)
    except CapsdError as exc:
        return fail(str(exc), EXIT_CONFIG)
    return EXIT_OK


def _cmd_train_refiner(args: argparse.Namespace) -> int:
    from capsd.train.refiner import RefinerConfig, train_refiner

    config = RefinerConfig(
        rounds=args.rounds,
        seed_offset=args.seed_offset,
        workers=args.workers,
        threads=args.threads,
        evaluate=args.evaluate,
    )
    try:
        train_refiner(args.weights, args.out, config)
    except CapsdError as exc:
        return fail(str(exc), EXIT_CONFIG)
    return EXIT_OK


def _cmd_label(args: argparse.Namespace) -> int:
    from capsd.config import load_config
    from capsd.services.locator.service import Config as LocatorConfig
    from capsd.train.labelling import label_recording, write_labels

    if not 0.0 < args.max_sigma <= 1.0:
        return fail(f"label: --max-sigma must be in (0, 1] m, not {args.max_sigma}", EXIT_CONFIG)
    try:
        locator = load_config(args.locator_config, LocatorConfig)
        labels, summary = label_recording(
            args.recording, sonar=locator.sonar, max_sigma_m=args.max_sigma
        )
    except CapsdError as exc:
        return fail(f"label: {exc}", EXIT_CONFIG)
    print(
        f"{summary.frames} frames, {summary.fixes} fixes, {summary.confident} confident and "
        f"tracked with a pose, {summary.labelled} labelled ({summary.outside_fan} outside the "
        f"fan, {summary.unreadable} unreadable messages)"
    )
    if not labels:
        return fail("label: no frame could be labelled (no confident tracked fix)", EXIT_FAILURE)
    sheets = write_labels(labels, args.out)
    print(f"labels in {args.out}: {len(sheets)} contact sheets; reject crops in rejected.txt")
    return EXIT_OK


def _cmd_train_detector(args: argparse.Namespace) -> int:
    from capsd.train.detector import TrainConfig, train

    if args.finetune is not None:
        from capsd.train.finetune import FinetuneConfig, finetune

        try:
            finetune(
                args.weights,
                args.finetune,
                args.out,
                FinetuneConfig(seed=args.seed, workers=args.workers, threads=args.threads),
            )
        except CapsdError as exc:
            return fail(f"finetune: {exc}", EXIT_CONFIG)
        return EXIT_OK

    if not 0.0 <= args.far_share <= 1.0:
        return fail(f"train detector: --far-share {args.far_share}: between 0 and 1", EXIT_CONFIG)
    if not 0.0 <= args.near_share <= 1.0:
        return fail(f"train detector: --near-share {args.near_share}: between 0 and 1", EXIT_CONFIG)
    if not 0.0 <= args.close_share <= 1.0:
        return fail(
            f"train detector: --close-share {args.close_share}: between 0 and 1", EXIT_CONFIG
        )
    if args.far_share + args.near_share > 1.0:
        return fail(
            f"train detector: --far-share {args.far_share} and --near-share {args.near_share}: "
            "together at most 1",
            EXIT_CONFIG,
        )
    if not 0.0 <= args.start_spread <= 1500.0:
        return fail(
            f"train detector: --start-spread {args.start_spread}: between 0 and 1500 s",
            EXIT_CONFIG,
        )
    config = TrainConfig(
        seed=args.seed,
        runs=args.runs,
        duration_s=args.run_duration,
        workers=args.workers,
        threads=args.threads,
        proposal_epochs=args.proposal_epochs,
        refine_epochs=args.refine_epochs,
        mining_runs=args.mining_runs,
        hard_runs=args.hard_runs,
        far_share=args.far_share,
        near_share=args.near_share,
        close_share=args.close_share,
        start_spread_s=args.start_spread,
        rack_heights=args.rack_heights,
        hard_rounds=args.hard_rounds,
        hard_epochs=args.hard_epochs,
        eval_duration_s=args.eval_duration,
        device=args.device,
        evaluate=args.evaluate,
        range_input=args.range_input,
        coarse_beams=args.coarse_beams,
        augment=args.augment,
    )
    try:
        train(config, args.out)
    except CapsdError as exc:
        return fail(str(exc), EXIT_CONFIG)
    return EXIT_OK


def register(sub: Subcommands) -> None:
    """Add the train verbs to the `capsd` parser's subcommands."""
    train = sub.add_parser("train", help="train a model").add_subparsers(
        dest="train_command", required=True
    )
    tdet = train.add_parser(
        "detector",
        help="train the polar CNN detector on simulated runs",
        description="Render simulator runs, train the proposal and refinement networks "
        "(deterministic for a seed), evaluate on held-out runs, write polar_net.pt and "
        "polar_net.json into --out. Defaults: about 29 minutes on 2 CPU cores.",
    )
    tdet.add_argument("--out", type=Path, default=Path("services/sonar_detect/weights"))
    tdet.add_argument("--seed", type=int, default=0)
    tdet.add_argument("--runs", type=positive_int, default=64, help="simulated training runs")
    tdet.add_argument(
        "--far-share",
        type=float,
        default=0.2,
        help="share of runs far off (the ROV 10-20 m away, the sonar 8-20 deg down; default "
        "0.2, as the shipped weights since session 51)",
    )
    tdet.add_argument(
        "--near-share",
        type=float,
        default=0.0,
        help="share of runs near (the mockup, the ROV 0.5-1.5 m away, the sonar 45-75 deg down; "
        "default 0)",
    )
    tdet.add_argument(
        "--close-share",
        type=float,
        default=0.0,
        help="share of runs close (the ROV 1-2.5 m away, the sonar 20-40 deg down, half of them "
        "profiling through the aperture; default 0: `capsd train proposal` adds them)",
    )
    tdet.add_argument(
        "--range-input",
        choices=["none", "channel"],
        default="none",
        help="channel: both networks also read each place's range (default none)",
    )
    tdet.add_argument(
        "--coarse-beams",
        type=positive_int,
        default=128,
        help="the proposal grid's width in cells (default 128; 256 resolves a far ROV's beams)",
    )
    tdet.add_argument(
        "--augment",
        choices=["gain", "look"],
        default="gain",
        help="look: also change the display curve, speckle, noise and beam width of every "
        "sample, beyond the renderer's variety (default gain: gain and contrast only)",
    )
    tdet.add_argument("--run-duration", type=positive_float, default=60.0, help="seconds per run")
    tdet.add_argument(
        "--start-spread",
        type=float,
        default=0.0,
        help="runs start at a time drawn from 0 to this many seconds into the vehicles' paths "
        "(default 0: every run from the start)",
    )
    tdet.add_argument(
        "--rack-heights",
        choices=["preset", "drawn"],
        default="preset",
        help="drawn: each run's racks and skips at even odds 5-100 cm under the ROV's hull at "
        "its lower flight level (default preset: the tanks' own heights)",
    )
    tdet.add_argument(
        "--workers", type=positive_int, default=2, help="rendering processes (1: this one)"
    )
    tdet.add_argument("--threads", type=int, default=2, help="torch threads for training")
    tdet.add_argument("--proposal-epochs", type=int, default=6)
    tdet.add_argument("--refine-epochs", type=int, default=6)
    tdet.add_argument("--mining-runs", type=int, default=24, help="runs for hard negatives")
    tdet.add_argument("--hard-runs", type=int, default=32, help="runs per hard-example round")
    tdet.add_argument("--hard-rounds", type=int, default=1, help="hard-example rounds")
    tdet.add_argument("--hard-epochs", type=int, default=2)
    tdet.add_argument(
        "--eval-duration", type=positive_float, default=20.0, help="seconds per held-out run"
    )
    tdet.add_argument(
        "--device",
        choices=("cpu", "cuda"),
        default="cpu",
        help="where the networks train (cuda: a GPU; rendering and calibration stay on the CPU)",
    )
    tdet.add_argument(
        "--evaluate",
        choices=("heldout", "none"),
        default="heldout",
        help="none: skip the held-out evaluation (run `capsd bench detect` after)",
    )
    tdet.add_argument(
        "--finetune",
        type=Path,
        metavar="LABELS",
        help="instead: adapt --weights to a `capsd label` folder (minutes on 2 cores)",
    )
    tdet.add_argument(
        "--weights",
        type=Path,
        default=Path("services/sonar_detect/weights/polar_net.pt"),
        help="the weights to fine-tune (--finetune)",
    )
    tdet.set_defaults(func=_cmd_train_detector)
    lab = sub.add_parser(
        "label",
        help="labelled sonar frames from a recording's confident tracked fixes",
        description="Project each good, tracked fix of a recording (sonar frames, ASV poses "
        "and fixes: `capsd record 'cap/**'`) back into its sonar frame; write labels.msgpack, "
        "numbered PNG contact sheets to check, and rejected.txt for the crops to leave out. "
        "`capsd train detector --finetune OUT` then adapts the detector.",
    )
    lab.add_argument("recording", type=Path, help="an MCAP recording")
    lab.add_argument("-o", "--out", type=Path, required=True, help="labels folder")
    lab.add_argument(
        "--locator-config",
        type=Path,
        default=Path("deploy/config/locator.yaml"),
        help="the locator's config during the dive (its sonar mount)",
    )
    lab.add_argument(
        "--max-sigma", type=float, default=0.05, help="largest horizontal fix sigma kept (m)"
    )
    lab.set_defaults(func=_cmd_label)
    tnear = train.add_parser(
        "near-refiner",
        help="add a refiner for ROVs under about 1.5 m (2 m by the fan's edge) to the polar "
        "CNN's weights",
        description="Start a second refiner from --weights' own, fine-tune it on crops near "
        "the sonar (near runs: the mockup, the sonar 45-75 deg down and turned up to 85 deg, "
        "the ROV by the fan's edge too; and the near crops of training-like runs), set its "
        "operating point on validation runs (at most 0.002 false alarms per frame among the "
        "candidates it scores), write polar_net.pt and polar_net.json into --out: the detector "
        "refines candidates under --max-range, and under --edge-max-range within --edge-within "
        "of the fan's edge, with it. About 10 minutes on 2 CPU cores; --calibrate-only: "
        "--weights' near refiner as it is, its operating point set again for where it takes "
        "over (5 minutes).",
    )
    tnear.add_argument(
        "--weights", type=Path, default=Path("services/sonar_detect/weights/polar_net.pt")
    )
    tnear.add_argument("--out", type=Path, required=True)
    tnear.add_argument("--seed", type=int, default=0)
    tnear.add_argument("--near-runs", type=positive_int, default=32, help="near runs")
    tnear.add_argument(
        "--edge-runs",
        type=positive_int,
        default=16,
        help="near runs with the ASV 0.8-1.6 m off and the sonar turned up to 85 deg (the ROV "
        "by the fan's edge)",
    )
    tnear.add_argument(
        "--other-runs", type=positive_int, default=24, help="training-like runs (near crops)"
    )
    tnear.add_argument("--epochs", type=positive_int, default=4)
    tnear.add_argument(
        "--max-range",
        type=positive_float,
        default=1.5,
        help="candidates nearer than this (m) go to the near refiner (default 1.5)",
    )
    tnear.add_argument(
        "--edge-max-range",
        type=positive_float,
        default=2.0,
        help="... and those nearer than this (m) within --edge-within of the fan's edge "
        "(default 2.0)",
    )
    tnear.add_argument(
        "--edge-within",
        type=float,
        default=20.0,
        help="degrees from the fan's edge (default 20; 0: no edge rule)",
    )
    tnear.add_argument(
        "--calibrate-only",
        action="store_true",
        help="keep --weights' near refiner, set where it takes over and its operating point",
    )
    tnear.add_argument(
        "--workers", type=positive_int, default=2, help="rendering processes (1: this one)"
    )
    tnear.add_argument("--threads", type=positive_int, default=2, help="torch threads")
    tnear.add_argument(
        "--evaluate",
        choices=("heldout", "none"),
        default="heldout",
        help="none: keep the stored evaluation of --weights (run `capsd bench detect` after)",
    )
    tnear.set_defaults(func=_cmd_train_near_refiner)
    tprop = train.add_parser(
        "proposal",
        help="train the polar CNN's close (or main) proposal network again, the rest kept",
        description="Train a proposal network on the runs --weights were trained on (their "
        "polar_net.json's train_config) with --close-share of them close runs (the ASV 0.8-2.2 "
        "m behind the ROV, the sonar 20-40 deg down, half of them the ROV going down and up "
        "through the aperture), add it to --weights as the heat of the rows nearer than "
        "--close-max-range (--network close) or of the rest of the frame (--network main), "
        "keep the rest, set both operating points again, write polar_net.pt and "
        "polar_net.json into --out. About 17 minutes on 2 CPU cores.",
    )
    tprop.add_argument(
        "--weights",
        type=Path,
        default=Path("services/sonar_detect/weights/polar_net.pt"),
        help="the weights whose refiners are kept (default: the shipped ones)",
    )
    tprop.add_argument("--out", type=Path, required=True, help="folder for the new weights")
    tprop.add_argument("--seed", type=int, default=0)
    tprop.add_argument(
        "--network",
        choices=("close", "main"),
        default="close",
        help="which proposal network to train again, the other kept (default %(default)s; "
        "main: for the whole frame beyond the close rows, on the weights' own runs)",
    )
    tprop.add_argument(
        "--close-share",
        type=float,
        default=None,
        help="share of the runs made close runs (default 0.25 for the close network, the "
        "weights' own for the main one)",
    )
    tprop.add_argument(
        "--close-max-range",
        type=float,
        default=2.5,
        help="the close network gives the heat nearer than this, m (default %(default)s)",
    )
    tprop.add_argument(
        "--width",
        type=int,
        help="the network's channels (default 32; fewer cost less on every whole-frame search)",
    )
    tprop.add_argument(
        "--targets",
        choices=("labels", "labels_and_teacher"),
        default="labels",
        help="labels_and_teacher: the network it replaces gives its heat as a soft target too "
        "(a narrow network learns from the wide one; default %(default)s)",
    )
    tprop.add_argument(
        "--workers", type=positive_int, default=2, help="rendering processes (1: this one)"
    )
    tprop.add_argument("--threads", type=positive_int, default=2, help="torch threads")
    tprop.add_argument(
        "--rack-heights",
        choices=["preset", "drawn"],
        default=None,
        help="drawn: each run's racks and skips at even odds 5-100 cm under the ROV's hull at "
        "its lower flight level; preset: the tanks' own heights (default: as the weights' "
        "runs were)",
    )
    tprop.add_argument(
        "--evaluate",
        choices=("heldout", "none"),
        default="heldout",
        help="none: no held-out evaluation in polar_net.json (run `capsd bench detect` after)",
    )
    tprop.set_defaults(func=_cmd_train_proposal)
    tref = train.add_parser(
        "refiner",
        help="more hard-example rounds for the polar CNN's main refiner, the rest kept",
        description="Run --rounds more hard-example rounds of --weights' main refiner (fresh "
        "runs planned as their polar_net.json's train_config, seen through their own proposal "
        "network; the crops it gets wrong repeated), keep both proposal networks and the near "
        "refiner, set the main operating point again, write polar_net.pt and polar_net.json "
        "into --out. About 6 minutes a round and 5 for the operating point on 2 CPU cores.",
    )
    tref.add_argument(
        "--weights",
        type=Path,
        default=Path("services/sonar_detect/weights/polar_net.pt"),
        help="the weights whose refiner trains on (default: the shipped ones)",
    )
    tref.add_argument("--out", type=Path, required=True, help="folder for the new weights")
    tref.add_argument("--rounds", type=positive_int, default=2, help="rounds (default 2)")
    tref.add_argument(
        "--seed-offset",
        type=int,
        default=0,
        help="plan the rounds' runs this many seeds further on (default 0: the next unused)",
    )
    tref.add_argument(
        "--workers", type=positive_int, default=2, help="rendering processes (1: this one)"
    )
    tref.add_argument("--threads", type=positive_int, default=2, help="torch threads")
    tref.add_argument(
        "--evaluate",
        choices=("heldout", "none"),
        default="heldout",
        help="none: no held-out evaluation in polar_net.json (run `capsd bench detect` after)",
    )
    tref.set_defaults(func=_cmd_train_refiner)
    tcal = train.add_parser(
        "calibrate",
        help="set the polar CNN's operating point on validation runs (part of `detector`)",
        description="Choose the confidence offset that keeps false alarms <= 0.005 per frame "
        "on validation runs (seeds used neither in training nor in the bench), save it in the "
        "weights and refresh their evaluation.",
    )
    tcal.add_argument(
        "--weights", type=Path, default=Path("services/sonar_detect/weights/polar_net.pt")
    )
    tcal.add_argument(
        "--duration",
        type=positive_float,
        default=None,
        help="seconds per validation run (default: the training's, 40; the held-out "
        "evaluation then runs twice as long)",
    )
    tcal.add_argument(
        "--confidence",
        choices=get_args(Confidence),
        default=DEFAULT_CONFIDENCE,
        help="how the false alarms are counted: each candidate as the one ROV among the "
        "frame's (exclusive, the service's cnn.confidence default) or scored alone",
    )
    tcal.set_defaults(func=_cmd_train_calibrate)
    tbias = train.add_parser(
        "range-bias",
        help="the CNN's range error to a near ROV by how steeply the sonar sees it and where "
        "it lies in the vertical aperture",
        description="On runs drawn as training runs are (tuning tanks, training looks, seeds "
        "of their own): training-like ones (the sonar pitched as trained) and steep ones (the "
        "sonar pitched from --pitch-deg, the ASV following), the configured CNN through the "
        "depth-aware search; its median signed range error by the line of sight's depression "
        "and the elevation the depth gate puts a near ROV at: the table `cnn.range_bias: "
        "by_elevation` takes off.",
    )
    tbias.add_argument(
        "--runs",
        type=positive_int,
        default=24,
        help="training-like runs (with --evaluate: the evaluation's runs)",
    )
    tbias.add_argument(
        "--steep-runs", type=positive_int, default=96, help="runs with the sonar pitched steeply"
    )
    tbias.add_argument(
        "--duration", type=positive_float, default=15.0, help="seconds per run (10 Hz pings)"
    )
    tbias.add_argument(
        "--out", type=Path, default=None, help="the table (JSON; default: the shipped one)"
    )
    tbias.add_argument(
        "--pitch-deg",
        type=float,
        nargs=2,
        default=None,
        metavar=("LOW", "HIGH"),
        help="sonar pitches drawn uniformly per run: the steep runs' (default 40 85: "
        "steeper than trained, to a tilt servo's steepest); with --evaluate its runs' "
        "(default 10 85)",
    )
    tbias.add_argument(
        "--evaluate",
        nargs="*",
        default=None,
        metavar="TABLE",
        help="measure no table: score each TABLE (a path, `none`: uncorrected, `shipped`; "
        "default: none shipped) on runs of a seed no table is measured on, by depression",
    )
    tbias.add_argument(
        "--json", type=Path, default=None, help="--evaluate: also write the figures here"
    )
    tbias.set_defaults(func=_cmd_train_range_bias)
