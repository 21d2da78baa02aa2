"""`capsd bench faults`: inject faults into the running pipeline and judge what reached ArduSub.

The pipeline of `capsd demo` runs (each service its own process on 127.0.0.1, the ArduSub
stand-in at the end of the MAVLink link). Faults are injected one at a time, each after the
system has settled again:
- kill -9 of a service, restarted 1 s later (the units' Restart=on-failure, RestartSec=1);
- the router killed and restarted on its port;
- sensor dropouts through the simulator's control key: no sonar 5 s, no LiDAR 5 s, no depth 2 s;
- separate runs: the ASV-topside link degraded (200 ms, 10% loss): over TCP, the deploy
  configs' transport, through a proxy with a lossy path's timing (losses become retransmission
  stalls, 40 ms of jitter head-of-line waits); over UDP through a datagram relay (and with
  40 ms of jitter, which reorders); the ASV's clock 0.5 s ahead, 0.5 s behind, drifting 200 ppm.
For each: recovery time (from the restart, or the end of the dropout, to the next estimate at
the autopilot) and outage (from the fault to that estimate); for the router also until every
service answers again; good fixes lost against the undisturbed rate; and every estimate the
autopilot received in the fault's window judged against the simulator's truth of its ping:
stale (older than the bridge's 0.3 s limit when it arrived, plus 5 ms for the MAVLink hop
after the gate's decision), invalid (not finite), or wrong by more than 3 sigma on an axis
(sigma from the covariance it was sent with). Those must be 0.
"""

from __future__ import annotations

import json
import math
import signal
import socket
import sys
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, NamedTuple, TextIO

import numpy as np
import yaml
import zenoh

from capsd import topics
from capsd.bench.lossy_link import LossyLink
from capsd.bench.lossy_tcp_link import LossyTcpLink
from capsd.bus import open_session
from capsd.codec import Codec
from capsd.config import BusConfig
from capsd.harness import SERVICES as DEMO_SERVICES
from capsd.harness import Child, Processes, decoder, free_port, start_service, write_configs
from capsd.health import query_health
from capsd.payloads import RovFix, SimControl, SonarLabel

SERVICES = ("asv_pose", "sonar_detect", "locator", "mav_bridge")


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@dataclass(frozen=True)
class LinkFault:
    """The ASV-topside link degraded: 200 ms each way, 10 % loss, some jitter.

    udp: Zenoh's UDP link through a datagram relay (jitter reorders datagrams);
    tcp: Zenoh's TCP link (the deploy configs') through a proxy with a lossy path's timing
    (losses come back as retransmission stalls, jitter as head-of-line waits).
    """

    transport: Literal["udp", "tcp"]
    jitter_s: float
    delay_s: float = 0.2
    loss: float = 0.1


VEHICLES = {service: vehicle for vehicle, service in DEMO_SERVICES}
RESTART_S = 1.0  # the systemd units' RestartSec
MAX_AGE_S = 0.3  # the bridge gate's default max_age_s
# The gate applies max_age_s when it decides; the MAVLink hop to the autopilot comes after it
# (under 1 ms on loopback): an estimate is stale if it arrives older than the limit plus this.
HOP_ALLOWANCE_S = 0.005
VERDICTS = ("ok", "stale", "invalid", "wrong_3sigma", "no_truth")
TARGET_SERVICE_RECOVERY_S = 3.0
TARGET_ROUTER_RECOVERY_S = 5.0


@dataclass
class Window:
    """One fault: when it was injected, when it was over, what it measured."""

    name: str
    start: float  # wall clock, s
    end: float = 0.0
    resume_from: float | None = None  # wall s: the restart, or the end of the dropout
    recovery_s: float | None = None  # from resume_from to the next estimate at the autopilot
    outage_s: float | None = None  # from the fault to the next estimate after resume_from
    recovery_target_s: float | None = None
    note: str = ""
    judged: dict[str, int] = field(default_factory=dict)
    sigmas: list[float] = field(default_factory=list)  # each judged estimate's worst |err|/sigma
    good_fixes: int = 0
    expected_fixes: float = 0.0


@dataclass
class Observed:
    """What the bench's own Zenoh client saw: fixes by arrival, labels by ping stamp."""

    fixes: list[tuple[float, str]] = field(default_factory=list)  # (wall s, quality)
    reasons: list[tuple[float, str]] = field(default_factory=list)  # (wall s, no-fix reason)
    labels: dict[int, tuple[float, float, float]] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def first_good_after(self, t: float) -> float | None:
        with self.lock:
            return next((a for a, q in self.fixes if a > t and q == "good"), None)

    def top_reason(self, t0: float, t1: float) -> str:
        """The commonest reason given for no fix between t0 and t1."""
        with self.lock:
            counts = Counter(r for a, r in self.reasons if t0 <= a < t1)
        return (
            "" if not counts else f"{counts.most_common(1)[0][0]} ({counts.most_common(1)[0][1]})"
        )

    def qualities(self, t0: float, t1: float) -> str:
        """Fix qualities between t0 and t1, e.g. 'good 3, unsure 40, invalid 60'."""
        with self.lock:
            counts = Counter(q for a, q in self.fixes if t0 <= a < t1)
        return ", ".join(f"{q} {n}" for q, n in counts.most_common()) or "none"

    def good_between(self, t0: float, t1: float) -> int:
        with self.lock:
            return sum(1 for a, q in self.fixes if t0 <= a < t1 and q == "good")


class Pipeline:
    """The demo's processes, with handles to kill, restart and mute them."""

    def __init__(
        self,
        out: Path,
        *,
        sim_clock: dict[str, float] | None = None,
        link: LinkFault | None = None,
    ):
        self.out = out
        out.mkdir(parents=True, exist_ok=True)
        self.port = free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        mav_port = free_port()
        self.configs = write_configs(
            out, self.endpoint, trajectory="square", tank="nfp", seed=0, mav_port=mav_port
        )
        if sim_clock is not None:
            body = yaml.safe_load(self.configs["sim"].read_text())
            body["clocks"] = {"asv": sim_clock}
            self.configs["sim"].write_text(yaml.safe_dump(body, sort_keys=False))
        self.link_fault = link
        self.link: LossyLink | LossyTcpLink | None = None
        if link is not None:
            # The ASV side (sensors, pose, detector) has its own router, joined to topside's
            # through the UDP relay or the TCP proxy: ASV -> topside is the degraded link.
            self.asv_endpoint = f"tcp/127.0.0.1:{free_port()}"
            if link.transport == "udp":
                self._link_topside, self._link_relay = _free_udp_port(), _free_udp_port()
            else:
                self._link_topside, self._link_relay = free_port(), free_port()
            for name in ("sim", "asv_pose", "sonar_detect"):
                body = yaml.safe_load(self.configs[name].read_text())
                body["bus"] = {"connect": [self.asv_endpoint]}
                self.configs[name].write_text(yaml.safe_dump(body, sort_keys=False))
        self.procs = Processes(out)
        self.estimates_file = out / "estimates.jsonl"
        self._mav_port = mav_port
        self.observed = Observed()
        self._session: zenoh.Session | None = None
        self._truth_session: zenoh.Session | None = None
        self._subs: list[Any] = []

    def start(self) -> None:
        if (fault := self.link_fault) is not None:
            kind = fault.transport
            topside = f"{kind}/127.0.0.1:{self._link_topside}"
            self.procs.start(
                "router",
                ["-m", "capsd", "router", "--listen", self.endpoint, "--listen", topside],
            )
            link_class = LossyLink if kind == "udp" else LossyTcpLink
            self.link = link_class(
                listen_port=self._link_relay,
                target_port=self._link_topside,
                delay_s=fault.delay_s,
                loss=fault.loss,
                jitter_s=fault.jitter_s,
            )
            self.link.start()
            relay = f"{kind}/127.0.0.1:{self._link_relay}"
            args = ["router", "--listen", self.asv_endpoint, "--connect", relay]
            self.procs.start("asv_router", ["-m", "capsd", *args, "--vehicle", "asv"])
        else:
            self.start_router()
        self.procs.start(
            "autopilot",
            [
                "-m",
                "capsd.simulator.autopilot",
                "--port",
                str(self._mav_port),
                "--estimates-out",
                str(self.estimates_file),
            ],
        )
        time.sleep(1.0)
        for name in ("sim", *SERVICES):
            start_service(self.procs, name, self.configs[name])
        self._session = open_session(BusConfig(connect=(self.endpoint,)))
        # The simulator's truth is read where it is published: on a degraded link it would
        # cross the link too, and estimates whose labels were lost could not be judged.
        self._truth_session = (
            self._session
            if self.link_fault is None
            else open_session(BusConfig(connect=(self.asv_endpoint,)))
        )
        obs = self.observed

        def on_fix(fix: RovFix) -> None:
            with obs.lock:
                now = time.time()
                obs.fixes.append((now, fix.quality))
                if fix.no_fix_reason is not None:
                    obs.reasons.append((now, fix.no_fix_reason))

        def on_label(label: SonarLabel) -> None:
            with obs.lock:
                obs.labels[label.stamp_ns // 1000] = label.rov_position_m

        self._subs = [
            self._session.declare_subscriber(
                topics.ROV_FIX.key("tank", "topside"), decoder(Codec(RovFix), on_fix)
            ),
            self._truth_session.declare_subscriber(
                topics.SIM_LABEL.key("tank", "sim"), decoder(Codec(SonarLabel), on_label)
            ),
        ]

    def start_router(self) -> Child:
        return self.procs.start("router", ["-m", "capsd", "router", "--listen", self.endpoint])

    def child(self, name: str) -> Child:
        return next(c for c in reversed(self.procs.children) if c.name == name)

    def kill(self, name: str) -> None:
        child = self.child(name)
        child.popen.send_signal(signal.SIGKILL)
        child.popen.wait()
        self.procs.children.remove(child)

    def restart(self, name: str) -> None:
        if name == "router":
            self.start_router()
        else:
            start_service(self.procs, name, self.configs[name])

    def mute(self, streams: tuple[str, ...], for_s: float) -> None:
        assert self._session is not None
        codec = Codec(SimControl)
        control = SimControl(stamp_ns=time.time_ns(), seq=0, mute=streams, for_s=for_s)
        self._session.put(
            topics.SIM_CONTROL.key("tank", "sim"),
            codec.encode(control),
            encoding=zenoh.Encoding(codec.encoding),
        )

    def bridge_refusals(self) -> dict[str, int]:
        """The bridge gate's refusals so far, by reason (from its Health)."""
        assert self._session is not None
        health = query_health(
            self._session, site="tank", vehicle="rov_ap", service="mav_bridge", timeout_s=1.0
        )
        if health is None:
            return {}
        return {
            k.removeprefix("gate_"): n
            for k, n in sorted(health.counters.items())
            if k.startswith("gate_") and k != "gate_sent" and n > 0
        }

    def all_answer(self) -> bool:
        assert self._session is not None
        return all(
            query_health(self._session, site="tank", vehicle=VEHICLES[s], service=s, timeout_s=0.3)
            is not None
            for s in ("sim", *SERVICES)
        )

    def stop(self) -> dict[str, int | None]:
        for sub in self._subs:
            sub.undeclare()
        if self._truth_session is not None and self._truth_session is not self._session:
            self._truth_session.close()
        if self._session is not None:
            self._session.close()
        codes = self.procs.stop()
        if self.link is not None:
            self.link.__exit__()
        return codes


class Verdict(NamedTuple):
    """One estimate judged: when it arrived, what it was, its largest error in its own sigmas."""

    arrival_s: float
    verdict: str  # one of VERDICTS
    sigmas: float | None  # max over axes of |error| / sigma; None without truth


def judge(
    estimates: list[dict[str, Any]], labels: dict[int, tuple[float, float, float]], ned: Any
) -> list[Verdict]:
    """A Verdict per estimate: ok, stale, invalid, wrong_3sigma, no_truth."""
    out = []
    for e in estimates:
        arrival = float(e["arrival_s"])
        values = [e["x"], e["y"], e["z"], *e["covariance"]]
        if not all(math.isfinite(v) for v in values):
            out.append(Verdict(arrival, "invalid", None))
            continue
        if arrival - e["usec"] / 1e6 > MAX_AGE_S + HOP_ALLOWANCE_S:
            out.append(Verdict(arrival, "stale", None))
            continue
        truth = labels.get(int(e["usec"]))
        if truth is None:
            out.append(Verdict(arrival, "no_truth", None))
            continue
        truth_ned = ned.position(np.array(truth))
        cov = e["covariance"]
        sigmas = np.sqrt([cov[0], cov[6], cov[11]])
        errors = np.array([e["x"], e["y"], e["z"]]) - truth_ned
        worst = float(np.max(np.abs(errors) / sigmas))
        out.append(Verdict(arrival, "wrong_3sigma" if worst > 3.0 else "ok", worst))
    return out


def _wait_settled(pipe: Pipeline, *, timeout_s: float = 60.0) -> bool:
    """Until good fixes flow (3 in the last second)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        now = time.time()
        if pipe.observed.good_between(now - 1.0, now) >= 3:
            return True
        time.sleep(0.2)
    return False


def run_main(out: Path, stream: TextIO, *, baseline_s: float) -> tuple[list[Window], Pipeline]:
    pipe = Pipeline(out)
    windows: list[Window] = []
    pipe.start()
    try:
        if not _wait_settled(pipe):
            raise RuntimeError("the pipeline never gave good fixes")
        base = Window("baseline (no fault)", time.time())
        time.sleep(baseline_s)
        base.end = time.time()
        windows.append(base)
        rate = pipe.observed.good_between(base.start, base.end) / baseline_s
        print(f"  baseline: {rate:.1f} good fixes/s", file=stream, flush=True)
        for name in (*SERVICES, "router"):
            w = Window(f"kill -9 {name}, restart after {RESTART_S:g} s", time.time())
            w.recovery_target_s = (
                TARGET_ROUTER_RECOVERY_S if name == "router" else TARGET_SERVICE_RECOVERY_S
            )
            pipe.kill(name)
            time.sleep(RESTART_S)
            w.resume_from = time.time()
            pipe.restart(name)
            if name == "router":
                t0 = time.monotonic()
                while not pipe.all_answer() and time.monotonic() - t0 < 20:
                    time.sleep(0.2)
                w.note = (
                    f"every service answering {time.time() - w.resume_from:.1f} s after the restart"
                )
            _wait_settled(pipe, timeout_s=30)
            time.sleep(2.0)
            w.end = time.time()
            windows.append(w)
            print(f"  {w.name}: done", file=stream, flush=True)
        for label, streams, for_s in (
            ("no sonar 5 s", ("sonar/frame@asv",), 5.0),
            ("no LiDAR 5 s", ("asv/scan@asv",), 5.0),
            ("no depth 2 s", ("rov/depth@rov",), 2.0),
        ):
            w = Window(label, time.time())
            pipe.mute(streams, for_s)
            time.sleep(for_s)
            w.resume_from = time.time()
            _wait_settled(pipe, timeout_s=30)
            time.sleep(2.0)
            w.end = time.time()
            windows.append(w)
            print(f"  {w.name}: done", file=stream, flush=True)
        for w in windows:
            w.good_fixes = pipe.observed.good_between(w.start, w.end)
            w.expected_fixes = rate * (w.end - w.start)
            if w.resume_from is not None:
                during = pipe.observed.qualities(w.start, w.resume_from)
                w.note = "; ".join(x for x in (w.note, f"fixes during the fault: {during}") if x)
    finally:
        codes = pipe.stop()
    bad = {n: c for n, c in codes.items() if c not in (0, None) and n != "autopilot"}
    if bad:
        windows[-1].note += f" exit codes {bad}"
    return windows, pipe


def run_separate(
    out: Path,
    name: str,
    duration_s: float,
    *,
    clock: dict[str, float] | None = None,
    link: LinkFault | None = None,
) -> tuple[Window, Pipeline]:
    """A whole pipeline run under one condition; the window is all of it after start-up.

    `link` not None: the ASV-topside link is degraded.
    """
    pipe = Pipeline(out, sim_clock=clock, link=link)
    pipe.start()
    w = Window(name, time.time())
    try:
        time.sleep(duration_s)
        w.end = time.time()
        w.good_fixes = pipe.observed.good_between(w.start, w.end)
        first = pipe.observed.first_good_after(w.start)
        w.note = "no good fix" if first is None else f"first good fix after {first - w.start:.1f} s"
        if reason := pipe.observed.top_reason(w.start, w.end):
            w.note += f"; commonest no-fix reason {reason}"
        refused = pipe.bridge_refusals()
        if refused:
            w.note += "; the bridge refused " + ", ".join(f"{k} {n}" for k, n in refused.items())
        if pipe.link is not None:
            w.note += f"; link: {pipe.link.summary()}"
    finally:
        pipe.stop()
    return w, pipe


# A wrong value for a key every service has, and one that is not a mapping at all.
BAD_CONFIGS = {
    "bad value": "site: tank\nhealth_period_s: -1\n",
    "not yaml": "site: [tank\n",
}


def malformed_configs(out: Path) -> Window:
    """Each service started with each bad config: exit 2 naming the file (and key), quickly."""
    import subprocess

    w = Window("malformed configs (every service)", time.time())
    results = []
    for name in ("sim", *SERVICES):
        for label, body in BAD_CONFIGS.items():
            path = out / f"bad_{name}_{label.replace(' ', '_')}.yaml"
            path.write_text(body)
            t0 = time.monotonic()
            done = subprocess.run(
                [sys.executable, "-m", "capsd", "run", name, "--config", str(path)],
                capture_output=True,
                text=True,
                timeout=60,
            )
            named = str(path) in done.stderr and (
                label != "bad value" or "health_period_s" in done.stderr
            )
            results.append((done.returncode == 2 and named, time.monotonic() - t0))
    w.end = time.time()
    good = sum(ok for ok, _ in results)
    slowest = max(t for _, t in results)
    w.note = (
        f"{good} of {len(results)} exited 2 naming the file and key (slowest {slowest:.1f} s); "
        "the units' RestartPreventExitStatus=2: no restart loop"
    )
    w.judged = {"config_not_refused": len(results) - good}
    return w


def _judge_into(windows: list[Window], pipe: Pipeline) -> None:
    from capsd.services.mav_bridge.service import NedConfig

    ned = NedConfig().tank_to_ned()
    estimates = [json.loads(line) for line in pipe.estimates_file.read_text().splitlines()]
    with pipe.observed.lock:
        labels = dict(pipe.observed.labels)
    verdicts = judge(estimates, labels, ned)
    # Kept for a look at any estimate judged wrong: what was sent, the verdict, the truth.
    with (pipe.out / "verdicts.jsonl").open("w") as out:
        for e, v in zip(estimates, verdicts, strict=True):
            truth = labels.get(int(e["usec"]))
            row = {**e, "verdict": v.verdict, "sigmas": v.sigmas, "truth_tank_m": truth}
            out.write(json.dumps(row) + "\n")
    arrivals = sorted(float(e["arrival_s"]) for e in estimates)
    for w in windows:
        if w.resume_from is not None:
            after = [a for a in arrivals if w.resume_from < a < w.end]
            if after:
                w.recovery_s = after[0] - w.resume_from
                w.outage_s = after[0] - w.start
        counts: dict[str, int] = {}
        for v in verdicts:
            if w.start <= v.arrival_s < w.end:
                counts[v.verdict] = counts.get(v.verdict, 0) + 1
                if v.sigmas is not None:
                    w.sigmas.append(v.sigmas)
        w.judged = counts


def bench(
    *, out: Path, baseline_s: float = 10.0, skew_s: float = 25.0, stream: TextIO = sys.stdout
) -> int:
    print("capsd bench faults: the demo pipeline, one fault at a time", file=stream, flush=True)
    windows, pipe = run_main(out / "main", stream, baseline_s=baseline_s)
    _judge_into(windows, pipe)
    runs: list[tuple[str, dict[str, float] | None, LinkFault | None]] = [
        ("link TCP: 200 ms, 10% loss, 40 ms jitter", None, LinkFault("tcp", 0.04)),
        ("link UDP: 200 ms, 10% loss", None, LinkFault("udp", 0.0)),
        ("link UDP: 200 ms, 10% loss, reorder", None, LinkFault("udp", 0.04)),
        ("ASV clock +0.5 s", {"offset_s": 0.5}, None),
        ("ASV clock -0.5 s", {"offset_s": -0.5}, None),
        ("ASV clock drifting 200 ppm", {"drift_ppm": 200.0}, None),
    ]
    base = windows[0]
    base_rate = base.good_fixes / max(base.end - base.start, 1e-9)
    for name, clock, link in runs:
        print(f"  {name}: {skew_s:g} s run", file=stream, flush=True)
        folder = out / "".join(c if c.isalnum() else "_" for c in name)
        w, p = run_separate(folder, name, skew_s, clock=clock, link=link)
        _judge_into([w], p)
        w.expected_fixes = base_rate * (w.end - w.start)
        windows.append(w)
    windows.append(malformed_configs(out))
    lines = report(windows)
    for line in lines:
        print(line, file=stream)
    (out / "faults.md").write_text("```\n" + "\n".join(lines) + "\n```\n")
    from capsd.plots import sigma_strips

    sigma_strips(
        {w.name: w.sigmas for w in windows},
        out / "faults_sigmas.png",
        title="capsd bench faults: every estimate the autopilot got, against the truth",
        limit=3.0,
    )
    (out / "faults.json").write_text(
        json.dumps([w.__dict__ for w in windows], indent=1, sort_keys=True) + "\n"
    )
    print(f"report: {out}/faults.md, faults.json, faults_sigmas.png", file=stream)
    failures = [
        w
        for w in windows
        if sum(w.judged.get(k, 0) for k in ("stale", "invalid", "wrong_3sigma"))
        or w.judged.get("config_not_refused", 0)
        or (
            w.recovery_target_s is not None
            and (w.recovery_s is None or w.recovery_s > w.recovery_target_s)
        )
    ]
    return 1 if failures else 0


def report(windows: list[Window]) -> list[str]:
    lines = [
        f"{'fault':<40} {'outage s':>8} {'recovery s':>10} {'target':>7} {'good fixes':>10} "
        f"{'lost':>6} "
        f"{'sent':>5} {'stale':>5} {'invalid':>7} {'>3sigma':>7}  note"
    ]
    for w in windows:
        j = w.judged
        sent = sum(n for k, n in j.items() if k in VERDICTS)
        lost = max(0, round(w.expected_fixes - w.good_fixes)) if w.expected_fixes else "-"
        rec = "-" if w.recovery_s is None else f"{w.recovery_s:.2f}"
        outage = "-" if w.outage_s is None else f"{w.outage_s:.2f}"
        tgt = "-" if w.recovery_target_s is None else f"{w.recovery_target_s:g}"
        lines.append(
            f"{w.name:<40} {outage:>8} {rec:>10} {tgt:>7} {w.good_fixes:>10} {lost!s:>6} {sent:>5} "
            f"{j.get('stale', 0):>5} {j.get('invalid', 0):>7} {j.get('wrong_3sigma', 0):>7}  "
            f"{w.note}"
        )
    return lines
