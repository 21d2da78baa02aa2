"""`capsd bench latency`: ping to autopilot at 10, 20 and 40 Hz; per stage, Zenoh floor, CPU, RSS.

The whole pipeline runs as in `capsd demo` (router, simulator, asv_pose, sonar_detect, locator,
mav_bridge, the ArduSub stand-in over MAVLink TCP), one process each on 127.0.0.1, once per
sonar rate. The services time themselves (capsd.latency histograms in their Health): every
input's transport from the put-time attachment, each service's own stage from arrival to its
output's put, and at the bridge the ping's stamp to the VISION_POSITION_ESTIMATE leaving the
socket. The bench snapshots every Health and /proc after a warm-up and at the end, and reports
the difference: exactly the measurement window.

The Zenoh floor is measured in the same run first: a bare publisher and subscriber, each its own
session on the same router, putting random bytes of each stage's payload size with the same
put-time attachment (no encoding, no decoding, no work).
"""

from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import zenoh

from capsd.bench.footprint import status_kb
from capsd.bus import open_session
from capsd.codec import Codec
from capsd.config import BusConfig
from capsd.harness import Processes, Watch, free_port, start_service, write_configs
from capsd.latency import LatencyRecorder, count_above_ms, difference, percentile_ms
from capsd.payloads import Detection, Health, LatencyStats, RovFix, SonarDetections, SonarFrame
from capsd.runner import put_time_ns

RATES_HZ = (10.0, 20.0, 40.0)
# The services counted in the CPU target; the router and the simulator are listed apart.
SERVICES = ("asv_pose", "sonar_detect", "locator", "mav_bridge")
# (stage, service, latency name in its Health, payload whose Zenoh floor it is compared with)
STAGES: tuple[tuple[str, str, str, str | None], ...] = (
    ("sonar: ping -> frame put", "sim", "sonar frame put after ping", None),
    ("frame transport", "sonar_detect", "transport sonar/frame", "frame"),
    ("detection (arrival -> put)", "sonar_detect", "detection", None),
    ("  of which detect() itself", "sonar_detect", "detector compute", None),
    ("detections transport", "locator", "transport sonar/detections", "detections"),
    ("fix (arrival -> put)", "locator", "fix", None),
    ("fix transport", "mav_bridge", "transport locator/fix", "fix"),
    ("bridge (arrival -> socket)", "mav_bridge", "bridge", None),
    ("END TO END: ping -> VPE sent", "mav_bridge", "end to end", None),
)
AGE = ("sonar_detect", "frame age at detection start")
TARGETS_AT_HZ = 40.0
TARGET_E2E_MEDIAN_MS = 25.0
TARGET_E2E_P99_MS = 60.0
TARGET_CPU_CORES = 1.2
TARGET_BRIDGE_RSS_MB = 80.0
TARGET_DETECTOR_RSS_MB = 400.0


@dataclass
class Snapshot:
    """Every service's Health and every process's CPU seconds at one instant."""

    at: float
    health: dict[str, Health | None]
    cpu_s: dict[str, float]


@dataclass
class RateResult:
    rate_hz: float
    window_s: float
    stages: dict[str, dict[str, float | int | None]] = field(default_factory=dict)
    frame_age: dict[str, float | int | None] = field(default_factory=dict)
    cpu_cores: dict[str, float] = field(default_factory=dict)
    rss_mb: dict[str, float] = field(default_factory=dict)
    peak_rss_mb: dict[str, float] = field(default_factory=dict)
    frames: dict[str, int] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    busy_cores: int = 0


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process so far (/proc/PID/stat fields 14 and 15)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def payload_sizes() -> dict[str, int]:
    """Encoded sizes of one sonar frame (the simulator's 512 x 1000), detections and a fix."""
    from capsd.bench.detect import sonar_only
    from capsd.simulator.config import OFFLINE_START_NS
    from capsd.simulator.sim import Simulation

    sim = Simulation(sonar_only("nfp", "square", "follow", 1), horizon_s=3)
    frame = next(iter(sim.labelled_pings(start_ns=OFFLINE_START_NS, duration_s=1.0)))[1]
    detection = Detection(
        range_m=7.5, azimuth_rad=0.1, range_sigma_m=0.01, azimuth_sigma_rad=0.002, confidence=0.9
    )
    detections = SonarDetections(
        stamp_ns=1, seq=1, ping_id=1, detector="cnn", detections=(detection,)
    )
    cov = (1e-4, 0.0, 0.0, 1e-4, 0.0, 1e-4)
    fix = RovFix(
        stamp_ns=1,
        seq=1,
        method="capsd",
        quality="good",
        raw_position_m=(1.0, 2.0, 3.0),
        raw_covariance_m2=cov,
        conditioning=1.0,
        track_state="tracking",
        candidates=1,
        position_m=(1.0, 2.0, 3.0),
        velocity_m_s=(0.1, 0.0, 0.0),
        covariance_m2=cov,
        asv_pose_stamp_ns=1,
        depth_stamp_ns=1,
        attitude_stamp_ns=1,
    )
    return {
        "frame": len(Codec(SonarFrame).encode(frame)),
        "detections": len(Codec(SonarDetections).encode(detections)),
        "fix": len(Codec(RovFix).encode(fix)),
    }


def zenoh_floor(
    endpoint: str, sizes: dict[str, int], *, count: int, rate_hz: float
) -> dict[str, dict[str, Any]]:
    """Bare put -> callback latency through the router, per payload size."""
    out: dict[str, dict[str, Any]] = {}
    bus = BusConfig(connect=(endpoint,))
    with open_session(bus) as pub_session, open_session(bus) as sub_session:
        for name, size in sizes.items():
            recorder = LatencyRecorder(name)
            shared = [0]

            def on_sample(
                sample: zenoh.Sample, rec: LatencyRecorder = recorder, shm: list[int] = shared
            ) -> None:
                now = time.time_ns()
                sent = put_time_ns(sample)
                if sent is not None:
                    rec.record_ns(now - sent)
                if sample.payload.as_shm() is not None:
                    shm[0] += 1

            key = f"capsd/bench/floor/{name}"
            sub = sub_session.declare_subscriber(key, on_sample)
            pub = pub_session.declare_publisher(key)
            time.sleep(0.5)  # the route exists before the first put (it could be lost)
            body = os.urandom(size)
            for _ in range(count):
                pub.put(body, attachment=time.time_ns().to_bytes(8, "little"))
                time.sleep(1.0 / rate_hz)
            time.sleep(0.3)
            pub.undeclare()
            sub.undeclare()
            stats = recorder.snapshot()
            out[name] = {
                "bytes": size,
                "received": stats.count,
                "median_ms": percentile_ms(stats, 50),
                "p99_ms": percentile_ms(stats, 99),
                "shared_memory": shared[0],
            }
    return out


def _snapshot(watch: Watch, procs: Processes) -> Snapshot:
    health = watch.health()
    cpu: dict[str, float] = {}
    for child in procs.children:
        if child.popen.poll() is None:
            cpu[child.name] = _cpu_s(child.popen.pid)
    return Snapshot(time.monotonic(), health, cpu)


def _latency(h: Health | None, name: str) -> LatencyStats | None:
    if h is None:
        return None
    return next((s for s in h.latencies if s.name == name), None)


def _window(first: Snapshot, last: Snapshot, service: str, name: str) -> LatencyStats | None:
    later = _latency(last.health.get(service), name)
    if later is None:
        return None
    return difference(later, _latency(first.health.get(service), name))


def _summary(stats: LatencyStats | None) -> dict[str, float | int | None]:
    if stats is None:
        return {"count": 0, "median_ms": None, "p99_ms": None}
    return {
        "count": stats.count,
        "median_ms": percentile_ms(stats, 50),
        "p99_ms": percentile_ms(stats, 99),
        "negative": stats.negative,
    }


def _counter(h: Health | None, key: str) -> int:
    return 0 if h is None else h.counters.get(key, 0)


# A process that keeps one core busy: the load a shared vehicle computer has besides us.
BUSY_LOOP = "while True: pass"


def measure_rate(
    rate_hz: float,
    *,
    duration_s: float,
    warmup_s: float,
    out: Path,
    stream: TextIO,
    busy_cores: int = 0,
) -> RateResult:
    """One pipeline run at `rate_hz`; the figures of its measurement window.

    `busy_cores` processes spin for the whole run: the simulator must then skip pings it
    cannot render in time (counted) rather than fall behind, and fixes must still flow.
    """
    logs = out / f"logs_{rate_hz:g}hz"
    logs.mkdir(parents=True, exist_ok=True)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    mav_port = free_port()
    configs = write_configs(
        logs,
        endpoint,
        trajectory="square",
        tank="nfp",
        seed=0,
        mav_port=mav_port,
        sonar_hz=rate_hz,
    )
    procs = Processes(logs)
    result = RateResult(rate_hz=rate_hz, window_s=0.0)
    try:
        procs.start("router", ["-m", "capsd", "router", "--listen", endpoint])
        procs.start("autopilot", ["-m", "capsd.simulator.autopilot", "--port", str(mav_port)])
        for k in range(busy_cores):
            procs.start(f"busy{k}", ["-c", BUSY_LOOP])
        time.sleep(1.0)
        for name in ("sim", *SERVICES):
            start_service(procs, name, configs[name])
        with open_session(BusConfig(connect=(endpoint,))) as session:
            watch = Watch(session)
            started = time.monotonic()
            # Warm-up: until the bridge sends estimates (pose found, track up), then warmup_s.
            while time.monotonic() - started < 60.0:
                time.sleep(1.0)
                if _counter(watch.health().get("mav_bridge"), "gate_sent") > 0:
                    break
            time.sleep(warmup_s)
            first = _snapshot(watch, procs)
            print(
                f"  {rate_hz:g} Hz: measuring {duration_s:g} s "
                f"(warm-up {first.at - started:.0f} s)",
                file=stream,
                flush=True,
            )
            time.sleep(duration_s)
            last = _snapshot(watch, procs)
            rss = {
                c.name: status_kb(c.popen.pid, "VmRSS") / 1024
                for c in procs.children
                if c.popen.poll() is None
            }
            peak = {
                c.name: status_kb(c.popen.pid, "VmHWM") / 1024
                for c in procs.children
                if c.popen.poll() is None
            }
            watch.close()
    finally:
        codes = procs.stop()
    window = last.at - first.at
    result.window_s = window
    for stage, service, name, _ in STAGES:
        result.stages[stage] = _summary(_window(first, last, service, name))
    age = _window(first, last, *AGE)
    result.frame_age = _summary(age)
    result.frame_age["older_than_period"] = (
        count_above_ms(age, 1000.0 / rate_hz) if age is not None else None
    )
    for name, cpu in last.cpu_s.items():
        if name in first.cpu_s:
            result.cpu_cores[name] = (cpu - first.cpu_s[name]) / window
    result.rss_mb, result.peak_rss_mb = rss, peak
    sim_h, det_h = first.health.get("sim"), last.health.get("sim")
    detect_first, detect_last = first.health.get("sonar_detect"), last.health.get("sonar_detect")
    frames_in = sum(
        s.count
        for s in (detect_last.inputs if detect_last else ())
        if s.key.endswith("sonar/frame")
    ) - sum(
        s.count
        for s in (detect_first.inputs if detect_first else ())
        if s.key.endswith("sonar/frame")
    )
    frames_shm = sum(
        s.shared_memory
        for s in (detect_last.inputs if detect_last else ())
        if s.key.endswith("sonar/frame")
    ) - sum(
        s.shared_memory
        for s in (detect_first.inputs if detect_first else ())
        if s.key.endswith("sonar/frame")
    )
    result.frames = {
        "published": _counter(det_h, "sonar/frame@asv:count")
        - _counter(sim_h, "sonar/frame@asv:count"),
        "received": frames_in,
        "received_in_shared_memory": frames_shm,
        "detected": _counter(detect_last, "frames") - _counter(detect_first, "frames"),
        "dropped_stale": _counter(detect_last, "dropped_stale_frames")
        - _counter(detect_first, "dropped_stale_frames"),
        "dropped_older_than_period": _counter(detect_last, "dropped_older_than_period")
        - _counter(detect_first, "dropped_older_than_period"),
        "vpe_sent": _counter(last.health.get("mav_bridge"), "gate_sent")
        - _counter(first.health.get("mav_bridge"), "gate_sent"),
        "sim_skipped_late_pings": _counter(det_h, "skipped_late_pings")
        - _counter(sim_h, "skipped_late_pings"),
    }
    result.busy_cores = busy_cores
    for name, code in codes.items():
        if name != "autopilot" and not name.startswith("busy") and code != 0:
            result.problems.append(f"{name} exited {code} (log: {logs}/{name}.log)")
    return result


def _ms(value: float | int | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def _report(
    results: list[RateResult], floor: dict[str, dict[str, Any]], stream: TextIO
) -> list[str]:
    lines: list[str] = []
    lines.append("Zenoh floor (bare put -> callback through the router, same payload sizes):")
    for name, f in floor.items():
        lines.append(
            f"  {name:<11} {f['bytes']:>8} B  median {_ms(f['median_ms'])} ms  "
            f"p99 {_ms(f['p99_ms'])} ms  ({f['received']} received, "
            f"{f['shared_memory']} via shared memory)"
        )
    for r in results:
        period_ms = 1000.0 / r.rate_hz
        lines.append("")
        lines.append(
            f"sonar at {r.rate_hz:g} Hz (period {period_ms:.0f} ms), window {r.window_s:.1f} s"
        )
        lines.append(f"  {'stage':<32} {'count':>6} {'median ms':>10} {'p99 ms':>8} {'/floor':>7}")
        for stage, _, _, floor_of in STAGES:
            s = r.stages[stage]
            ratio = "-"
            if floor_of is not None and s["median_ms"] is not None:
                base = floor[floor_of]["median_ms"]
                if base:
                    ratio = f"{float(s['median_ms']) / base:.2f}"
            lines.append(
                f"  {stage:<32} {s['count']:>6} {_ms(s['median_ms']):>10} "
                f"{_ms(s['p99_ms']):>8} {ratio:>7}"
            )
        a = r.frame_age
        lines.append(
            f"  {'frame age at detection start':<32} {a['count']:>6} {_ms(a['median_ms']):>10} "
            f"{_ms(a['p99_ms']):>8}   older than one period: {a['older_than_period']}"
        )
        f = r.frames
        lines.append(
            f"  frames: published {f['published']}, received {f['received']} "
            f"({f['received_in_shared_memory']} in shared memory), detected "
            f"{f['detected']}, replaced by a newer one {f['dropped_stale']}, older than a period "
            f"when the detector was free {f['dropped_older_than_period']}; VPE sent {f['vpe_sent']}"
        )
        lines.append(
            f"  simulator: {f.get('sim_skipped_late_pings', 0)} pings skipped as too late to "
            f"render (the world holds real time), {r.busy_cores} other busy process(es)"
        )
        cpu = "  ".join(f"{n} {c:.2f}" for n, c in sorted(r.cpu_cores.items()))
        services_cpu = sum(r.cpu_cores.get(n, 0.0) for n in SERVICES)
        lines.append(f"  CPU cores: {cpu}")
        lines.append(f"  CPU of the four services: {services_cpu:.2f} cores")
        rss = "  ".join(
            f"{n} {r.rss_mb[n]:.0f} (peak {r.peak_rss_mb[n]:.0f})" for n in sorted(r.rss_mb)
        )
        lines.append(f"  RSS MB: {rss}")
        for p in r.problems:
            lines.append(f"  PROBLEM: {p}")
    target = next((r for r in results if r.rate_hz == TARGETS_AT_HZ), None)
    if target is not None:
        e2e = target.stages[STAGES[-1][0]]
        services_cpu = sum(target.cpu_cores.get(n, 0.0) for n in SERVICES)
        checks = [
            ("end-to-end median", e2e["median_ms"], TARGET_E2E_MEDIAN_MS, "ms"),
            ("end-to-end p99", e2e["p99_ms"], TARGET_E2E_P99_MS, "ms"),
            (
                "frames older than one period processed",
                target.frame_age["older_than_period"],
                0,
                "",
            ),
            ("CPU of all services", services_cpu, TARGET_CPU_CORES, "cores"),
            ("bridge RSS", target.rss_mb.get("mav_bridge"), TARGET_BRIDGE_RSS_MB, "MB"),
            ("detector RSS", target.rss_mb.get("sonar_detect"), TARGET_DETECTOR_RSS_MB, "MB"),
        ]
        lines.append("")
        lines.append(f"targets at {TARGETS_AT_HZ:g} Hz:")
        for what, value, limit, unit in checks:
            ok = value is not None and float(value) <= limit
            shown = "-" if value is None else f"{float(value):.2f}"
            lines.append(
                f"  {what:<40} {shown:>8} {unit:<5} target <= {limit:g} {unit:<5} "
                f"{'met' if ok else 'NOT MET'}"
            )
    for line in lines:
        print(line, file=stream)
    stream.flush()
    return lines


def run(
    *,
    rates_hz: tuple[float, ...] = RATES_HZ,
    duration_s: float = 30.0,
    warmup_s: float = 5.0,
    out: Path = Path("reports/latency"),
    floor_count: int = 200,
    busy_cores: int = 0,
    stream: TextIO = sys.stdout,
) -> int:
    """The bench; 0 when every service ran to the end (targets are printed, not asserted)."""
    out.mkdir(parents=True, exist_ok=True)
    sizes = payload_sizes()
    print(
        f"capsd bench latency: rates {list(rates_hz)} Hz, {duration_s:g} s each"
        + (f", {busy_cores} other process(es) keeping a core busy" if busy_cores else ""),
        file=stream,
    )
    procs = Processes(out)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    try:
        procs.start("floor_router", ["-m", "capsd", "router", "--listen", endpoint])
        time.sleep(1.0)
        floor = zenoh_floor(endpoint, sizes, count=floor_count, rate_hz=max(rates_hz))
    finally:
        procs.stop()
    results = [
        measure_rate(
            r,
            duration_s=duration_s,
            warmup_s=warmup_s,
            out=out,
            stream=stream,
            busy_cores=busy_cores,
        )
        for r in rates_hz
    ]
    lines = _report(results, floor, stream)
    figures = {
        "floor": floor,
        "rates": [r.__dict__ for r in results],
        "medians_note": "histogram bins are 5 % wide: figures are within 2.5 %",
    }
    (out / "latency.json").write_text(json.dumps(figures, indent=1, sort_keys=True) + "\n")
    (out / "latency.md").write_text("```\n" + "\n".join(lines) + "\n```\n")
    print(f"report: {out}/latency.md, latency.json", file=stream)
    return 0 if all(not r.problems for r in results) else 1
