"""Round-trip latency of the flight link, nav -> flight side -> cmd through Zenoh. Prints figures,
asserts nothing; writes them to a JSON file as well.

Section "echo": the link alone, on loopback. The host is a real eclipse-zenoh session (peer or
router) listening on a free port. Two echoers answer every nav message with the same bytes on cmd,
measured side by side in one run, in interleaved blocks so that machine noise hits both alike:

  * the C++ flight client (tests/cpp/tools/zenoh_probe --echo), i.e. rvd::link::ZenohSession
    with a trivial "guidance";
  * a Python eclipse-zenoh client session doing the same (the Rust stack as the reference).

Section "flight": flight software nav -> cmd round trip, trivial guidance. The real flight
executable (flight_sw/app, `rvd_flight_sw --trivial`: every nav is answered at once with a
zero-thrust cmd, no guidance) is run by rvd_pil.host_sim.pil.run_pil against the real host server:
lockstep, CW truth, no noise, the chaser at rest on V-bar (a CW equilibrium, so zero thrust keeps
the state constant for any number of steps). Rows, measured one after another in interleaved
rounds (every row once per round, so a burst of load on the shared machine hits all rows):

  native            the host build
  qemu-user q7s     static armhf build, qemu-arm -cpu cortex-a9
  qemu-user rpi3    static aarch64 build, qemu-aarch64 -cpu cortex-a53
  qemu-system rpi3  the same aarch64 build in a Debian arm64 guest (-M virt, -icount, user
                    networking: the guest reaches the host at tcp/10.0.2.2:PORT); runs when the
                    system image is already prepared, or with --system (downloads it)
  qemu-system rpi3 semihosting
                    the same guest with the link through semihosting and host FIFOs
                    (rvd_pil/qemu/semihosting_link.py, as the campaign's bit-exact timing runs use it)

Clock: every figure is host time, Python time.monotonic() (CLOCK_MONOTONIC), read in the host
server just before nav k is put and again when cmd k has been taken out of the host's inbox
(run record column round_trip_ms). It includes the host's message encode/decode, both Zenoh stacks,
TCP on loopback (QEMU's user-mode network stack in system mode) and the flight process's poll loop.
Under QEMU it is host wall time, not target time (rvd_pil/qemu/README.md): it says how much the
emulated link slows a PIL run, not how long a real board would take. The first `--flight-warmup`
steps of each run are left out of the statistics (QEMU translates code on first use; the first
puts carry Zenoh declarations); the cold first step is reported on its own.

    python -m rvd_pil.bench.link_latency                       both sections, all rows available
    python -m rvd_pil.bench.link_latency --sections flight --native-only
    python -m rvd_pil.bench.link_latency --sections flight --targets rpi3 --system
    python -m rvd_pil.bench.link_latency --sections echo --runner "qemu-aarch64 -cpu cortex-a53" \\
        --probe build/cross/rpi3/tests/cpp/zenoh_probe

--runner prefixes the echo section's probe command (QEMU user mode reaches 127.0.0.1 directly);
the Python reference echoer always runs natively.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as _dt
import json
import math
import os
import platform
import queue
import shutil
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

from rvd_pil import paths

paths.require_checkout("the link latency benchmark (tests/cpp/tools/zenoh_probe, tests/support)")
from support.zenoh_link_harness import Probe, free_port, python_zenoh, wait_matching  # noqa: E402

CLOCK = ("host time.monotonic() (CLOCK_MONOTONIC): nav put -> cmd taken from the host inbox; "
         "host wall time, also under QEMU (not target time)")
DEFAULT_JSON = paths.reports_root() / "link_latency.json"
QEMU_USER_TARGETS = ("q7s", "rpi3")
SYSTEM_TARGET = "rpi3"


def percentile(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, int(round(q * (len(s) - 1))))]


# ---- section "echo": the link alone ----------------------------------------------------------

def python_echoer(endpoint: str, nav: str, cmd: str):
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", f'["{endpoint}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    publisher = session.declare_publisher(cmd)
    subscriber = session.declare_subscriber(nav, lambda s: publisher.put(s.payload))
    return session, subscriber


def echo_section(args) -> dict:
    """The C++ probe and the Python client echoing side by side; prints the table, returns the figures."""
    if args.probe:
        os.environ["RVD_ZENOH_PROBE"] = args.probe

    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    host = python_zenoh(args.mode, port)
    replies = {"cpp": queue.Queue(), "py": queue.Queue()}
    publishers = {}
    for name in replies:
        host.declare_subscriber(f"rvd/bench/{name}/cmd", lambda s, q=replies[name]: q.put(s.payload.to_bytes()))
        publishers[name] = host.declare_publisher(f"rvd/bench/{name}/nav")

    try:
        probe = Probe(endpoint, "--sub", "rvd/bench/cpp/nav", "--echo", "rvd/bench/cpp/cmd", "--quiet",
                      "--lease-ms", "30000", runner=args.runner)
    except BaseException:
        host.close()
        raise
    py_session, _py_sub = python_echoer(endpoint, "rvd/bench/py/nav", "rvd/bench/py/cmd")
    rtt_us: dict[str, list[float]] = {"cpp": [], "py": []}
    try:
        if probe.expect("OPEN", timeout=60)["status"] != "Ok":
            raise RuntimeError(f"the probe could not open its session: {probe.history[-1]}")
        for pub in publishers.values():
            wait_matching(pub, timeout=60)

        payload = bytearray(os.urandom(args.payload))

        def exchange(name: str, k: int) -> float:
            payload[:8] = k.to_bytes(8, "little")
            t0 = time.perf_counter_ns()
            publishers[name].put(bytes(payload))
            got = replies[name].get(timeout=args.timeout)
            t1 = time.perf_counter_ns()
            if got[:8] != payload[:8]:
                raise RuntimeError(f"{name}: reply {k} out of order")
            return (t1 - t0) / 1000.0

        k = 0
        for name in rtt_us:
            for _ in range(args.warmup):
                exchange(name, k)
                k += 1
        done = 0
        while done < args.n:
            block = min(args.block, args.n - done)
            for name in rtt_us:
                for _ in range(block):
                    rtt_us[name].append(exchange(name, k))
                    k += 1
            done += block
        stats = probe.stats()
    finally:
        probe.close()
        py_session.close()
        host.close()

    runner = args.runner or "native"
    print(f"Link round trip nav -> echo -> cmd, {args.n} exchanges each, {args.payload} B payload, "
          f"host in {args.mode} mode, loopback TCP; C++ probe runner: {runner}")
    print(f"{'echo side':<34}{'median':>10}{'p99':>10}{'mean':>10}{'max':>10}   [us]")
    rows = {"cpp": "C++ rvd::link::ZenohSession", "py": "Python eclipse-zenoh client"}
    out = {"exchanges": args.n, "payload_bytes": args.payload, "host_mode": args.mode, "probe_runner": runner,
           "clock": "host time.perf_counter_ns() around put -> reply received", "rows": {}}
    for name, label in rows.items():
        xs = rtt_us[name]
        print(f"{label:<34}{statistics.median(xs):>10.1f}{percentile(xs, 0.99):>10.1f}"
              f"{statistics.fmean(xs):>10.1f}{max(xs):>10.1f}")
        out["rows"][name] = {"label": label, "median_us": statistics.median(xs), "p99_us": percentile(xs, 0.99),
                             "mean_us": statistics.fmean(xs), "max_us": max(xs)}
    ratio = statistics.median(rtt_us["cpp"]) / statistics.median(rtt_us["py"])
    print(f"median ratio C++ / Python: {ratio:.2f}")
    print(f"C++ side counters: samples {stats['samples_rx']}, puts {stats['puts_tx']}, "
          f"rejected {stats['rx_rejected']}, link losses {stats['link_losses']}")
    out["median_ratio_cpp_to_py"] = ratio
    out["probe_counters"] = {k: stats[k] for k in ("samples_rx", "puts_tx", "rx_rejected", "link_losses")}
    return out


# ---- section "flight": the flight executable with trivial guidance ---------------------------

class RowUnavailable(RuntimeError):
    """A row cannot run on this machine (no cross compiler, no QEMU, no system image...)."""


def trivial_scenario(steps: int):
    """Case 1's vehicles with the chaser at rest on V-bar, 1580 m behind the target: under CW truth a
    zero-thrust chaser stays exactly there, so a run of any length neither drifts, collides nor docks.
    The scenario timeout is far beyond `steps` periods, so the run ends at the step limit."""
    from rvd_pil.host_sim import scenario

    base = scenario.load("case1_vbar")
    chaser = dataclasses.replace(base.chaser, position_lvlh_m=(0.0, -1580.0, 0.0), velocity_lvlh_mps=(0.0, 0.0, 0.0))
    return base.replace(name="link_latency_vbar_hold", chaser=chaser, timeout_s=3600.0 * (steps + 1),
                        description="chaser at rest on V-bar (CW equilibrium); link latency benchmark")


def latency_stats(xs_ms: list[float]) -> dict:
    """Median / p90 / p99 / max / mean of round trips [ms] (nearest-rank percentiles)."""
    if not xs_ms:
        raise ValueError("no round trips to summarise")
    return {"n": len(xs_ms), "median_ms": statistics.median(xs_ms), "p90_ms": percentile(xs_ms, 0.90),
            "p99_ms": percentile(xs_ms, 0.99), "max_ms": max(xs_ms), "mean_ms": statistics.fmean(xs_ms)}


def flight_round_trip(steps: int, *, flight_exe: Optional[str] = None, flight_command: Optional[Callable] = None,
                      host_mode: str = "peer", run_dir: Optional[Path] = None, hello_timeout_s: float = 60.0,
                      cmd_timeout_s: float = 10.0) -> dict:
    """One lockstep run of `rvd_flight_sw --trivial` for `steps` steps; returns its record, read back.

    flight_exe: the native executable (default: rvd_pil.host_sim.pil.find_flight_executable); flight_command:
    instead, a function from the flight software's arguments to the whole command (QEMU). Returns
    {"round_trip_ms": per step, "steps": [k...], "nav_attempts": [...], "end", "nav_resends",
    "flight_hello", "flight_telemetry", "flight_command", "guidance_status", "solver_status",
    "pulse_cmd_max_s", "truth_drift_m", "wall_s"}."""
    import numpy as np

    from rvd_pil.host_sim.pil import run_pil
    from rvd_pil.host_sim.record import load_run
    from rvd_pil.host_sim.server import ServerConfig

    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    cfg = ServerConfig(mode=host_mode, max_steps=steps, hello_timeout_s=hello_timeout_s, cmd_timeout_s=cmd_timeout_s,
                       delay_model="none")
    scen = trivial_scenario(steps)
    with tempfile.TemporaryDirectory(prefix="rvd-link-latency-") as tmp:
        rdir = Path(run_dir) if run_dir else Path(tmp) / "run"
        t0 = time.monotonic()
        summary, rdir = run_pil(scen, truth="cw", sensor_noise=False, thrust_noise=False, flight_exe=flight_exe,
                                flight_args=["--trivial"], flight_command=flight_command, config=cfg, run_dir=rdir,
                                meta={"benchmark": "link_latency"})
        wall_s = time.monotonic() - t0
        meta, df = load_run(rdir)
        log = (rdir / "flight_sw.log").read_text(errors="replace")[-2000:]
    truth = df[["truth_x_m", "truth_y_m", "truth_z_m"]].to_numpy(dtype=float)
    pulses = df[[c for c in df.columns if c.startswith("pulse_cmd_")]].to_numpy(dtype=float)
    return {
        "end": summary.end,
        "steps": df["step"].astype(int).tolist(),
        "round_trip_ms": df["round_trip_ms"].astype(float).tolist(),
        "nav_attempts": df["nav_attempts"].astype(int).tolist(),
        "guidance_status": sorted(set(df["guidance_status"].dropna().astype(int))),
        "solver_status": sorted(set(df["solver_status"].dropna().astype(int))),
        "pulse_cmd_max_s": float(np.abs(pulses).max()) if pulses.size else 0.0,
        "truth_drift_m": float(np.abs(truth - truth[0]).max()) if len(truth) else 0.0,
        "nav_resends": meta.get("nav_resends"),
        "flight_hello": meta.get("flight_hello"),
        "flight_telemetry": meta.get("flight_telemetry"),
        "flight_exit_code": meta.get("flight_exit_code"),
        "flight_command": meta.get("flight_command"),
        "flight_log_tail": log,
        "wall_s": wall_s,
    }


@dataclass
class FlightRow:
    """One row of the flight table. `prepare()` builds what the row needs (cross build, initramfs)
    and returns the keyword arguments of flight_round_trip, or raises RowUnavailable."""

    key: str
    mode: str                  # "native", "qemu-user" or "qemu-system"
    target: Optional[str]      # rvd_pil/qemu/targets.toml name; None for native
    emulator: str              # how it runs, for the table
    steps: int
    prepare: Callable[[], dict]
    hello_timeout_s: float = 60.0
    samples: list = field(default_factory=list)      # round trips after the warm-up, all rounds [ms]
    first_ms: list = field(default_factory=list)     # cold first step of each round [ms]
    runs: list = field(default_factory=list)         # per round: end, steps, resends, wall time
    hello: Optional[dict] = None
    skipped: Optional[str] = None
    _launch: Optional[dict] = None


def _native_row(steps: int, exe: Optional[str]) -> FlightRow:
    def prepare():
        from rvd_pil.host_sim.pil import find_flight_executable

        try:
            return {"flight_exe": str(find_flight_executable(exe))}
        except FileNotFoundError as err:
            raise RowUnavailable(str(err)) from None

    return FlightRow("native", "native", None, "none (host build)", steps, prepare)


def _cross_exe(name: str):
    """The target's static flight executable (cross_build, cached in build/cross/<target>)."""
    from rvd_pil.qemu import build, targets

    t = targets.load(name)
    if not shutil.which(t.compiler):
        raise RowUnavailable(f"cross compiler {t.compiler} not found (Debian: apt-get install "
                             f"g++-{t.compiler.removesuffix('-g++')}, or `make deps-pil`)")
    try:
        exe = build.cross_build(t)
    except (RuntimeError, FileNotFoundError) as err:
        raise RowUnavailable(f"cross build of the flight executable for {name} failed: {err}") from None
    return t, exe


def _user_row(name: str, steps: int) -> FlightRow:
    from rvd_pil.qemu import targets, user

    t = targets.load(name)

    def prepare():
        if not shutil.which(t.qemu_user):
            raise RowUnavailable(f"{t.qemu_user} not found (Debian: apt-get install qemu-user)")
        _, exe = _cross_exe(name)
        return {"flight_command": lambda args: user.command(t, exe.path, args)}

    return FlightRow(f"qemu-user {name}", "qemu-user", name, f"{t.qemu_user} -cpu {t.qemu_cpu}", steps, prepare)


def _system_row(name: str, steps: int, download: bool, icount: bool, workdir: Path,
                semihosting: bool = False) -> FlightRow:
    from rvd_pil.qemu import semihosting_link, system, targets

    t = targets.load(name)
    emulator = (f"{t.qemu_system} -M {t.system.machine} -cpu {t.qemu_cpu}, "
                f"{'semihosting link' if semihosting else 'user net'}{', -icount shift=0' if icount else ''}")

    def prepare():
        if not shutil.which(t.qemu_system):
            raise RowUnavailable(f"{t.qemu_system} not found (Debian: apt-get install qemu-system-arm)")
        try:
            img = system.image(t, download=download)
        except Exception as err:  # apt errors, a missing package in the archive...
            raise RowUnavailable(f"system image for {name}: {type(err).__name__}: {err}") from None
        if img is None:
            raise RowUnavailable(f"no system image for {name} prepared (python -m rvd_pil.qemu prepare, or pass --system "
                                 "to download it)")
        _, exe = _cross_exe(name)
        initrd = system.program_initrd(img, exe.path, workdir / f"{name}-initrd.cpio")
        if semihosting:
            return {"flight_command": semihosting_link.flight_command(
                lambda args: system.command(t, img, initrd, args, icount=icount, net=False, semihosting=True),
                workdir / f"{name}-semihosting-link")}

        # The link over the user network (the guest reaches the host at 10.0.2.2); only the link key
        # goes through semihosting.
        return {"flight_command": semihosting_link.key_only_command(
            lambda args: system.command(t, img, initrd, args, icount=icount, semihosting=True),
            workdir / f"{name}-link-key", system.HOST_IP)}

    # A boot takes seconds (vexpress-a9 up to 15 s on a loaded machine): generous hello timeout.
    label = f"qemu-system {name}{' semihosting' if semihosting else ''}"
    return FlightRow(label, "qemu-system", name, emulator, steps, prepare, hello_timeout_s=180.0)


def _per_round(total: int, rounds: int, warmup: int) -> int:
    """Steps per run so that `rounds` runs leave at least `total` measured steps after the warm-ups."""
    return math.ceil(total / rounds) + warmup


def flight_section(rows: list[FlightRow], *, rounds: int, warmup: int, host_mode: str) -> dict:
    """Runs every available row once per round (interleaved), prints the table, returns the figures."""
    for row in rows:
        try:
            row._launch = row.prepare()
        except RowUnavailable as why:
            row.skipped = str(why)
            print(f"  {row.key}: skipped: {why}", flush=True)
    active = [r for r in rows if r.skipped is None]
    for rnd in range(rounds):
        for row in active:
            if row.skipped:
                continue
            n = _per_round(row.steps, rounds, warmup)
            try:
                res = flight_round_trip(n, host_mode=host_mode, hello_timeout_s=row.hello_timeout_s, **row._launch)
            except Exception as err:  # the run itself failed (record, Zenoh): say so, keep the others
                row.skipped = f"run failed: {type(err).__name__}: {err}"
                print(f"  {row.key}: {row.skipped}", flush=True)
                continue
            row.runs.append({k: res[k] for k in ("end", "nav_resends", "wall_s", "flight_command", "flight_exit_code")}
                            | {"steps": len(res["steps"])})
            if res["end"] != "step limit" or len(res["steps"]) != n:
                row.skipped = (f"run ended early: {res['end']} after {len(res['steps'])} of {n} steps; "
                               f"flight log tail:\n{res['flight_log_tail']}")
                print(f"  {row.key}: {row.skipped}", flush=True)
                continue
            row.hello = res["flight_hello"]
            row.first_ms.append(res["round_trip_ms"][0])
            row.samples.extend(res["round_trip_ms"][warmup:])
            print(f"  round {rnd + 1}/{rounds} {row.key:<30} {n} steps, median "
                  f"{statistics.median(res['round_trip_ms'][warmup:]):.3f} ms, {res['wall_s']:.1f} s wall", flush=True)

    measured = [r for r in rows if r.skipped is None and r.samples]
    native = next((r for r in measured if r.mode == "native"), None)
    base = latency_stats(native.samples) if native else None
    table = []
    for row in rows:
        entry = {"key": row.key, "mode": row.mode, "target": row.target, "emulator": row.emulator,
                 "skipped": row.skipped, "runs": row.runs}
        if row.skipped is None and row.samples:
            st = latency_stats(row.samples)
            entry.update(stats=st, first_step_ms=row.first_ms,
                         ratio_to_native=({k: st[k] / base[k] for k in ("median_ms", "p90_ms", "p99_ms", "max_ms")}
                                          if base else None),
                         flight_arch=(row.hello or {}).get("arch"), flight_cpu_model=(row.hello or {}).get("cpu_model"),
                         samples_ms=[round(x, 4) for x in row.samples])
        table.append(entry)

    print(f"\nFlight software nav -> cmd round trip, trivial guidance (rvd_flight_sw --trivial): lockstep, CW truth, "
          f"no noise, host Zenoh {host_mode} mode; {rounds} round(s), first {warmup} steps of each run left out")
    print(f"clock: {CLOCK}")
    head = f"{'row':<30}{'flight CPU':<22}{'steps':>6}{'median':>9}{'p90':>9}{'p99':>9}{'max':>9}{'cold':>9}   x native (median / p99)"
    print(head + "\n" + "-" * len(head))
    for e in table:
        if "stats" not in e:
            print(f"{e['key']:<30}skipped: {(e['skipped'] or 'no data').splitlines()[0]}")
            continue
        st, ratio = e["stats"], e["ratio_to_native"]
        cpu = f"{e['flight_arch']} {e['flight_cpu_model']}"
        ratio_s = f"x{ratio['median_ms']:.2f} / x{ratio['p99_ms']:.2f}" if ratio else "-"
        print(f"{e['key']:<30}{cpu:<22}{st['n']:>6}{st['median_ms']:>9.3f}{st['p90_ms']:>9.3f}{st['p99_ms']:>9.3f}"
              f"{st['max_ms']:>9.3f}{max(e['first_step_ms']):>9.3f}   {ratio_s}")
    print("[ms]; cold = the first step of a run (worst over rounds), not in the statistics")
    for e in table:
        if "stats" in e:
            print(f"  {e['key']}: {e['emulator']}")
    return {"title": "flight software nav -> cmd round trip, trivial guidance",
            "clock": CLOCK, "scenario": "case1_vbar vehicles, chaser at rest on V-bar (CW equilibrium)",
            "truth": "cw", "noise": False, "lockstep": True, "host_mode": host_mode, "rounds": rounds,
            "warmup_steps_per_run": warmup, "rows": table}


def build_rows(args, workdir: Path) -> list[FlightRow]:
    """The rows the options select: native always; QEMU user mode per --targets unless --native-only;
    QEMU system mode rpi3 when its image is prepared (or with --system), unless --native-only/--no-system."""
    from rvd_pil.qemu import targets

    rows = [_native_row(args.steps, args.flight_sw)]
    if args.native_only:
        return rows
    names = [t for t in args.targets.split(",") if t]
    known = targets.names()
    for name in names:
        if name not in known:
            raise SystemExit(f"unknown target {name!r}; known: {', '.join(known)}")
        if targets.load(name).arch == "host":
            continue
        rows.append(_user_row(name, args.emulated_steps))
    if not args.no_system:
        for semihosting in (False, True):
            rows.append(_system_row(SYSTEM_TARGET, args.emulated_steps, download=args.system,
                                    icount=args.icount == "on", workdir=workdir, semihosting=semihosting))
    return rows


def _host_info() -> dict:
    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    return {"machine": platform.machine(), "python": platform.python_version(), "cpus": os.cpu_count(),
            "loadavg_1_5_15": load}


def parse_args(argv=None):
    ap = argparse.ArgumentParser(prog="python -m rvd_pil.bench.link_latency", description=__doc__.split("\n\n")[0],
                                 epilog=__doc__.split("\n\n", 1)[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sections", default="echo,flight", help="comma-separated: echo, flight (default both)")
    ap.add_argument("--mode", choices=["peer", "router"], default="peer", help="host Zenoh mode (both sections)")
    ap.add_argument("--json", default=str(DEFAULT_JSON), help="write the figures here (default reports/link_latency.json); '' for none")
    g = ap.add_argument_group("echo section")
    g.add_argument("--n", type=int, default=2000, help="exchanges per echoer (default 2000)")
    g.add_argument("--block", type=int, default=200, help="exchanges per interleaved block")
    g.add_argument("--warmup", type=int, default=100, help="untimed exchanges per echoer first")
    g.add_argument("--payload", type=int, default=64, help="nav payload bytes (default 64)")
    g.add_argument("--runner", default="", help='command prefix for the probe, e.g. "qemu-aarch64 -cpu cortex-a53"')
    g.add_argument("--probe", default=None, help="zenoh_probe binary (default: $RVD_ZENOH_PROBE or build/native)")
    g.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for one reply")
    f = ap.add_argument_group("flight section")
    f.add_argument("--steps", type=int, default=2000, help="measured steps of the native row (default 2000)")
    f.add_argument("--emulated-steps", type=int, default=1000, help="measured steps of each QEMU row (default 1000)")
    f.add_argument("--rounds", type=int, default=2, help="interleaved rounds; the steps are split across them (default 2)")
    f.add_argument("--flight-warmup", type=int, default=20, help="steps at the start of each run left out (default 20)")
    f.add_argument("--flight-sw", default=None, help="native flight executable (default: $RVD_FLIGHT_SW or build/native)")
    f.add_argument("--native-only", action="store_true", help="only the native row")
    f.add_argument("--targets", default=",".join(QEMU_USER_TARGETS), help="QEMU user-mode rows (default q7s,rpi3; '' for none)")
    f.add_argument("--system", action="store_true", help=f"QEMU system-mode {SYSTEM_TARGET} row, downloading its image if needed "
                   "(without it the row runs only when the image is already prepared)")
    f.add_argument("--no-system", action="store_true", help="skip the system-mode row")
    f.add_argument("--icount", choices=["on", "off"], default="on", help="system mode with -icount shift=0 as the campaign (default on)")
    a = ap.parse_args(argv)
    a.sections = [s for s in a.sections.split(",") if s]
    bad = set(a.sections) - {"echo", "flight"}
    if bad or not a.sections:
        ap.error(f"--sections takes echo and/or flight, not {a.sections}")
    if a.system and a.no_system:
        ap.error("--system and --no-system contradict each other")
    for name in ("n", "steps", "emulated_steps", "rounds"):
        if getattr(a, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be >= 1")
    if a.flight_warmup < 0:
        ap.error("--flight-warmup must be >= 0")
    return a


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    result = {"benchmark": "rvd_pil/bench/link_latency.py", "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(),
              "host": _host_info(), "echo": None, "flight": None}
    rc = 0
    if "echo" in args.sections:
        try:
            result["echo"] = echo_section(args)
        except (FileNotFoundError, RuntimeError, AssertionError) as err:
            print(f"echo section not run: {err}", file=sys.stderr)
            result["echo"] = {"skipped": str(err)}
            rc = 1
        print()
    if "flight" in args.sections:
        with tempfile.TemporaryDirectory(prefix="rvd-link-latency-") as tmp:
            rows = build_rows(args, Path(tmp))
            print(f"Flight rows: {', '.join(r.key for r in rows)}", flush=True)
            result["flight"] = flight_section(rows, rounds=args.rounds, warmup=args.flight_warmup, host_mode=args.mode)
        if not any("stats" in r for r in result["flight"]["rows"]):
            rc = 1
    result["host"]["loadavg_at_end"] = os.getloadavg() if hasattr(os, "getloadavg") else None
    if args.json:
        out = Path(args.json)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(result, indent=1))
        print(f"\nfigures written to {out}")
    return rc


if __name__ == "__main__":
    sys.exit(main())
