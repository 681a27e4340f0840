"""rvd-run: run one scenario processor-in-the-loop with the flight executable.

    rvd-run case1_vbar                           nonlinear truth (J2, drag), thruster and sensor noise
    rvd-run case1_vbar --truth cw --ideal        CW truth, no noise, impulsive burns (exact reference)
    rvd-run random:7                             a seeded random scenario (dissertation ch. 4 distribution)
    rvd-run case1_vbar --target q7s              cross-built for the Q7S, under qemu-arm with the
                                                 instruction counter, block profiler and cycle model
    rvd-run case1_vbar --target q7s --cpu cortex-a8    another CPU model for the same target
    rvd-run case3_rotating --runner "qemu-arm -cpu cortex-a9" --flight-sw build/cross/q7s/flight_sw/rvd_flight_sw
    rvd-run case1_vbar -- --horizon 45,15,12     everything after -- goes to the flight software

It starts the host's Zenoh session and the flight software, shows progress, prints a summary
(delta-v and time per phase, docked or why not, what was dropped from the link, which settings
depend on this host's speed) and writes the run record (runs/<time>-<scenario>/). With --ideal the
control delay is "none" unless --delay says otherwise, so the run uses no wall-clock reading:
three runs give the same record digest.

With --target (rvd_pil/qemu/targets.toml) the flight executable is cross-built for that target, run under
QEMU user mode with the instruction-counting plugin and the block profiler, the control delay is
the estimated target time (instructions x the CPU's CPI / its clock), the flight software takes
its deadlines and step times on the same target time (--target-clock), and after the run the cycle
model prices every solve. Every time in the summary says where it comes from: the flight clock
(wall time on this host natively, target time under --target), instructions counted by the
plugin, or the cycle model's estimated target time.
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from pathlib import Path

from rvd_pil.host_sim import scenario as scenarios
from rvd_pil.host_sim.server import PHASE_NAMES, ServerConfig


def _scenario(text: str):
    if text.startswith("random:"):
        try:
            seed = int(text.split(":", 1)[1])
        except ValueError:
            raise argparse.ArgumentTypeError(f"random:<seed> needs an integer seed, got {text!r}") from None
        return scenarios.random_scenario(seed)
    try:
        return scenarios.load(text)
    except (FileNotFoundError, scenarios.ScenarioError) as exc:
        raise argparse.ArgumentTypeError(f"{exc} (available: {', '.join(scenarios.available())}, random:<seed>)") from None


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="rvd-run", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__.split("\n\n", 1)[1])
    ap.add_argument("scenario", type=_scenario, help="scenario name, TOML path, or random:<seed>")
    ap.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    ap.add_argument("--truth", choices=("nonlinear", "cw"), default="nonlinear", help="truth model (default nonlinear)")
    ap.add_argument("--ideal", action="store_true", help="no sensor or thruster noise, impulsive burns")
    ap.add_argument("--no-sensor-noise", action="store_true")
    ap.add_argument("--no-thrust-noise", action="store_true")
    ap.add_argument("--impulsive", action="store_true", help="apply burns as impulses instead of finite burns")
    ap.add_argument("--delay", choices=("none", "reported", "estimated"), default=None,
                    help="control delay model (default: none with --ideal, else the flight computer's "
                         "reported step time, which depends on this host's speed)")
    ap.add_argument("--realtime", type=float, metavar="SPEEDUP", default=None,
                    help="real-time pacing at SPEEDUP simulated seconds per wall second (default: lockstep)")
    ap.add_argument("--zenoh-mode", choices=("peer", "router"), default="peer", help="host Zenoh mode")
    ap.add_argument("--cmd-timeout", type=float, default=10.0, help="lockstep: seconds before nav is resent")
    ap.add_argument("--target", default=None, metavar="NAME",
                    help="run under QEMU as this flight computer (rvd_pil/qemu/targets.toml: q7s, rpi3, beaglebone, rpi4): "
                         "cross build, instruction counter, cycle model, estimated control delay")
    ap.add_argument("--cpu", default=None, help="with --target: another CPU model (e.g. cortex-a8)")
    ap.add_argument("--no-cycle-model", action="store_true",
                    help="with --target: count instructions only, no block profile and no cycle-model pricing")
    ap.add_argument("--flight-sw", default=None, help="flight executable (default: build/native or $RVD_FLIGHT_SW; "
                                                      "with --target: the cross build)")
    ap.add_argument("--guidance", default=None, metavar="PATH",
                    help="a plug-in guidance law's folder (law.toml and its sources, see README 'Plug-in guidance'): "
                         "built with the flight software's harness and flown instead of the built-in MPC")
    ap.add_argument("--runner", default="", help='command prefix for the flight executable, e.g. "qemu-arm -cpu cortex-a9"')
    ap.add_argument("--allow-vehicle-mismatch", action="store_true",
                    help="run even when the flight software plans with another vehicle than the truth simulates "
                         "(a robustness study; its own --set thrusters.* pins it)")
    ap.add_argument("--out", default=None, help="run record directory (default runs/<time>-<scenario>-<id>)")
    ap.add_argument("-q", "--quiet", action="store_true", help="no progress display")
    return ap


class Progress:
    """One status line, rewritten in place on a terminal, every 25 steps otherwise."""

    def __init__(self, quiet: bool):
        self.quiet = quiet
        self.tty = sys.stderr.isatty()
        self.t0 = time.monotonic()

    def __call__(self, k, summary, cmd) -> None:
        if self.quiet or (not self.tty and k % 25):
            return
        phase = PHASE_NAMES.get(cmd.phase, "?") if cmd is not None else "-"
        solve = f"{cmd.solve_time_us:8.0f} us" if cmd is not None else "       -"
        line = (f"step {k:5d}  {phase:<10}  dv {sum(summary.dv_per_phase_mps.values()):7.3f} m/s  "
                f"solve {solve}  wall {time.monotonic() - self.t0:6.1f} s")
        print(("\r" + line) if self.tty else line, end="" if self.tty else "\n", file=sys.stderr, flush=True)

    def done(self) -> None:
        if self.tty and not self.quiet:
            print(file=sys.stderr)


def _safety_line(safety: dict) -> str:
    f = safety["figures"]
    head = {"safe": "SAFE", "started_unsafe": "STARTED UNSAFE (the initial state violates a limit; the guidance "
            "added no violation)"}.get(safety["verdict"], f"UNSAFE, {safety['violations']} violation(s)")
    worst = [f"{name} by {st['worst']:.3g} {st['unit']} (step {st['worst_step']}, {st['worst_phase']})"
             for name, st in safety["per_limit"].items() if st["violations"] or st["initial"]]
    figures = []
    if f.get("min_axial_distance_approach_m") is not None:
        figures.append(f"closest axial distance in approach {f['min_axial_distance_approach_m']:.2f} m")
    if f.get("max_docking_cone_excursion_m") is not None:
        figures.append(f"docking-cone margin {-100 * f['max_docking_cone_excursion_m']:+.1f} cm")
    if f.get("max_speed_inf_docking_mps"):
        figures.append(f"max |v|inf in docking {1000 * f['max_speed_inf_docking_mps']:.1f} mm/s")
    for i, o in (f.get("obstacles") or {}).items():
        if o["min_clearance"] is not None:
            figures.append(f"obstacle {i} clearance min {o['min_clearance']:.3f} (>= 1 outside) at t = {o['t_s']:.0f} s")
    return "; ".join([head] + (["worst: " + ", ".join(worst)] if worst else []) + figures)


class CliError(Exception):
    """A bad input: printed as one line, exit code 2."""


def emulated_lease_args(cmd_timeout_s: float) -> list[str]:
    """The lease an emulated flight announces: as long as the host waits for a command. The flight sends
    nothing while its guidance step runs, and under QEMU with the profiler a heavy step (a generated
    peer solver at its iteration cap) lasts longer than the default 20 s of wall time; with the default
    the host's Zenoh session expired in mid-step and the run ended "flight software lost". A flight
    given its own --lease-ms later on the command line keeps that one."""
    return ["--lease-ms", str(int(cmd_timeout_s * 1000))]


def _target_setup(args, run_dir: Path):
    """--target: the cross-built executable, the QEMU command with the plugins, the delay model."""
    from rvd_pil.qemu import build, plugin, targets, user

    try:
        t = targets.load(args.target, cpu=args.cpu)
    except ValueError as exc:
        raise CliError(f"--target/--cpu: {exc}") from None
    if not t.emulated:
        raise CliError(f"--target {args.target}: the host target runs natively; leave --target out")
    if args.flight_sw:
        from rvd_pil.host_sim.pil import ELF_MACHINES, elf_machine, find_flight_executable

        exe = find_flight_executable(args.flight_sw)
        want = {"armhf": 0x28, "aarch64": 0xB7}.get(t.arch)
        got = elf_machine(exe)
        if want is not None and got != want:
            raise CliError(f"--flight-sw {exe} is {ELF_MACHINES.get(got, 'not an ELF executable') if got else 'not an ELF executable'}, "
                           f"target {t.name} needs {ELF_MACHINES[want]}")
    else:
        print(f"rvd-run: cross-building the flight executable for {t.name} ({t.arch}, {t.cpu})", file=sys.stderr)
        try:
            exe = build.cross_build(t).path
        except Exception as exc:  # a build failure: its cause, not a traceback
            raise CliError(f"cross build for {t.name} failed: {str(exc).strip().splitlines()[-1] if str(exc).strip() else exc}") from None
    lib = plugin.build(download=os.environ.get("RVD_QEMU_FETCH", "1") == "1")
    if lib is None:
        raise CliError("the instruction-counting plugin is not built (needs qemu-plugin.h): run "
                       "`python -m rvd_pil.qemu prepare`")
    insns_log = run_dir.with_name(run_dir.name + ".insns")
    plugins = [plugin.InsnCounter(log=insns_log, library=lib)]
    profile = None
    if not args.no_cycle_model:
        from rvd_pil.qemu import cycles

        prof_lib = plugin.build_profile(download=False)
        if prof_lib is None:
            raise CliError("the block-profile plugin is not built: run `python -m rvd_pil.qemu prepare`")
        if t.cpu not in cycles.models():
            raise CliError(f"no cycle model for CPU {t.cpu} (rvd_pil/qemu/cycle_models.toml); pass --no-cycle-model to count "
                           "instructions only")
        model = cycles.CycleModel(t)
        profile = run_dir.with_name(run_dir.name + ".blocks")
        plugins.append(plugin.BlockProfiler(out=profile, cache=model.cache_geometry, library=prof_lib))
    # The flight's deadlines and step times on the target time the estimated control delay is priced
    # in (ServerConfig.cpi = the registry CPI); options after `--` come later and win.
    clock = user.target_clock_args(t.cpi.nominal, t.clock_hz)
    return t, exe, (lambda fargs: user.command(t, exe, [*clock, *fargs], plugin=plugins)), profile


def _flight_failure(run_dir: Path, summary, exit_code) -> str | None:
    """Why the flight process failed, from its exit code and the last lines of its log."""
    lost = summary.hello is None or "flight software" in summary.end
    bad_exit = exit_code not in (None, 0) and not (exit_code < 0 and summary.reached)
    if not (lost or bad_exit):
        return None
    how = ("killed by signal %d" % -exit_code) if isinstance(exit_code, int) and exit_code < 0 else f"exit code {exit_code}"
    try:
        lines = [ln for ln in (run_dir / "flight_sw.log").read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        lines = []
    usage = next((i for i, ln in enumerate(lines) if ln.lower().startswith("usage:")), None)
    shown = lines[:usage][-8:] if usage else lines[-8:]  # an option error: its message, not the usage text
    tail = "\n".join("  | " + ln for ln in shown) or "  | (no output)"
    return f"flight software failed ({how}): {summary.end}; the end of {run_dir / 'flight_sw.log'}:\n{tail}"


def flight_clock_label(hello, target=None) -> str:
    """What the flight software's step and solve times were measured on (its hello's step_clock)."""
    step_clock = getattr(hello, "step_clock", 0)
    if step_clock == 1:
        return "target time on the flight clock (instructions counted by the plugin x CPI / f_clk)"
    if target is not None:
        why = " (--target-clock asked for, no plugin answered)" if step_clock == 2 else ""
        return f"emulated wall time (host clock under QEMU user mode for {target.name}: host time, not target time){why}"
    return "wall time on this host (native)"


def _times(run_dir: Path, summary, target, cycles_csv: Path | None) -> list[str]:
    """The per-phase solve times, each labelled with its source."""
    from rvd_pil.host_sim.record import load_run

    out = []
    t = summary.telemetry
    if t is not None:
        clock = flight_clock_label(summary.hello, target)
        out.append(f"solve times, {clock}:")
        for i, ph in enumerate(("rendezvous", "approach", "docking")):
            if t.steps[i]:
                out.append(f"  {ph:<10} {t.steps[i]:4d} solves  mean {t.mean_solve_us[i] / 1e3:9.3f} ms  "
                           f"max {t.max_solve_us[i] / 1e3:9.3f} ms (step {t.max_step[i]})  "
                           f"overruns on this clock {t.overruns[i]}")
    if target is None:
        return out
    _, steps = load_run(run_dir)
    steps = steps[steps["phase"].isin([1, 2, 3]) & (steps.get("instructions", 0) > 0)] if "phase" in steps else steps.iloc[:0]
    names = {1: "rendezvous", 2: "approach", 3: "docking"}
    if len(steps):
        out.append("instructions per solve (counting plugin, exact):")
        for ph, g in steps.groupby("phase"):
            out.append(f"  {names[ph]:<10} {len(g):4d} solves  mean {g['instructions'].mean():12,.0f}  "
                       f"max {g['instructions'].max():12,.0f}")
    if cycles_csv is not None and cycles_csv.exists():
        import pandas as pd

        cyc = pd.read_csv(cycles_csv).merge(steps[["step", "phase"]], on="step")
        f = target.clock_hz / 1e3
        out.append(f"estimated target time per solve (cycle model, {target.cpu} at {target.clock_hz / 1e6:.0f} MHz; "
                   "not measured on hardware):")
        for ph, g in cyc.groupby("phase"):
            out.append(f"  {names[ph]:<10} {len(g):4d} solves  mean {g['cycles_nominal'].mean() / f:9.3f} ms  "
                       f"max {g['cycles_nominal'].max() / f:9.3f} ms [interval {g['cycles_low'].max() / f:.3f}"
                       f"-{g['cycles_high'].max() / f:.3f}]")
    return out


def main(argv=None) -> int:
    try:
        return _main(argv)
    except CliError as exc:
        print(f"rvd-run: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("rvd-run: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # anything else: its cause in one line (RVD_DEBUG=1 shows the traceback)
        if os.environ.get("RVD_DEBUG"):
            raise
        print(f"rvd-run: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1


def _main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    split = argv.index("--") if "--" in argv else len(argv)
    args = build_parser().parse_args(argv[:split])
    flight_args = argv[split + 1:]
    if args.cpu and not args.target:
        raise CliError("--cpu needs --target (the CPU model of which flight computer?)")
    if args.target and args.guidance:
        raise CliError("--guidance with --target: a law is cross-built by `make pil GUIDANCE=PATH` (natively: leave --target out)")
    if args.target and args.runner:
        raise CliError("--target sets the runner itself (QEMU with the counting plugins); leave --runner out")
    from rvd_pil.host_sim.pil import FlightLaunchError, default_run_dir, run_pil  # after argument errors: --help stays fast

    run_dir = Path(args.out) if args.out else default_run_dir(args.scenario.name)
    target = flight_command = profile = None
    exe = args.flight_sw
    if args.target:
        target, exe, flight_command, profile = _target_setup(args, run_dir)
    delay = args.delay or ("none" if args.ideal else "estimated" if target is not None else "reported")
    cfg = ServerConfig(mode=args.zenoh_mode, lockstep=args.realtime is None, speedup=args.realtime or 1.0,
                       cmd_timeout_s=args.cmd_timeout, delay_model=delay,
                       allow_vehicle_mismatch=args.allow_vehicle_mismatch)
    delay_note = None
    if target is not None:
        cfg.cpi, cfg.clock_hz = target.cpi.nominal, target.clock_hz  # as the flight clock (_target_setup)
        cfg.hello_timeout_s = max(cfg.hello_timeout_s, 180.0)
        cfg.cmd_timeout_s = max(cfg.cmd_timeout_s, 120.0)  # the profiler slows emulation tenfold
        flight_args = [*emulated_lease_args(cfg.cmd_timeout_s), *flight_args]
        if delay == "estimated":
            delay_note = (f"control delay: estimated target time = instructions x CPI {target.cpi.nominal:g} "
                          f"(rvd_pil/qemu/targets.toml, {target.cpu}) / {target.clock_hz / 1e6:.0f} MHz")
    progress = Progress(args.quiet)

    interrupted = []

    def on_started(server, proc):
        def stop(signum, frame):
            interrupted.append(signum)
            server.stop()
        signal.signal(signal.SIGINT, stop)
        signal.signal(signal.SIGTERM, stop)

    meta = {} if target is None else {"target": target.name, "build": target.build_name, "cpu": target.cpu,
                                      "arch": target.arch, "clock_hz": target.clock_hz, "mode": "user"}
    if args.guidance is not None:
        from rvd_pil.host_sim.guidance_build import LawBuildError, build_native

        try:
            law_exe, manifest = build_native(args.guidance)
        except LawBuildError as exc:
            raise CliError(str(exc)) from None
        if exe is None:
            exe = str(law_exe)
        flight_args = manifest.flight_args() + flight_args
        meta["guidance_law"] = {"name": manifest.name, "folder": str(manifest.folder), "executable": exe}
    try:
        summary, run_dir = run_pil(
            args.scenario, seed=args.seed, truth=args.truth,
            sensor_noise=not (args.ideal or args.no_sensor_noise), thrust_noise=not (args.ideal or args.no_thrust_noise),
            impulsive=args.ideal or args.impulsive, flight_exe=None if flight_command else exe, flight_args=flight_args,
            runner=args.runner, flight_command=flight_command, config=cfg, run_dir=run_dir, on_step=progress,
            on_started=on_started, meta=meta,
        )
    except (FileNotFoundError, FileExistsError, FlightLaunchError) as exc:
        raise CliError(str(exc)) from None
    progress.done()
    if summary.end.startswith(("flight software refused the configuration", "vehicle mismatch")):
        source = argv[:split][0] if argv[:split] and not argv[0].startswith("-") else args.scenario.name
        print(f"rvd-run: {source}: {summary.end} (run record {run_dir})", file=sys.stderr)
        return 2
    import json

    meta = json.loads((run_dir / "meta.json").read_text())
    failure = _flight_failure(run_dir, summary, meta.get("flight_exit_code"))
    if failure:
        print(f"rvd-run: {failure}", file=sys.stderr)
    cycles_csv = None
    if profile is not None and summary.telemetry is not None and (profile.exists() or profile.with_name(profile.name + ".gz").exists()):
        from rvd_pil.qemu import cycles

        print("rvd-run: pricing the solves with the cycle model (llvm-mca)", file=sys.stderr)
        try:
            cycles_csv = cycles.price_run(profile, Path(exe), cycles.CycleModel(target), run_dir / "cycles.csv")
        except Exception as exc:  # the run stands without the estimate; say why
            print(f"rvd-run: cycle model failed: {type(exc).__name__}: {exc}", file=sys.stderr)
    print(f"scenario {args.scenario.name}: {summary.end} after {summary.steps} steps, "
          f"t = {summary.t_s:.0f} s, final distance to the port {summary.final_range_to_port_m:.3f} m")
    print(summary.table())
    if summary.safety:
        print(f"safety (truth): {_safety_line(summary.safety)}")
    if summary.hello is not None:
        h = summary.hello
        print(f"flight software: {h.arch} {h.cpu_model}, {h.compiler}; horizons {tuple(h.horizon)}")
    if target is not None:
        print(f"target: {target.name} ({target.description}), {target.cpu} at {target.clock_hz / 1e6:.0f} MHz, "
              f"under {target.qemu_user} -cpu {target.qemu_cpu}")
    if delay_note:
        print(delay_note)
    for line in _times(run_dir, summary, target, cycles_csv):
        print(line)
    if summary.nav_resends or summary.rejected_messages or summary.late_commands:
        print(f"link: {summary.nav_resends} nav resends, {summary.late_commands} late commands, "
              f"{summary.rejected_messages} rejected messages")
    dropped = {**{f"host {k}": v for k, v in summary.discarded.items() if v},
               **{f"flight {k}": v for k, v in summary.flight_discarded.items() if v and k != "nav_duplicates"}}
    if summary.stale_commands or summary.future_commands:
        dropped.update({"host stale cmds": summary.stale_commands, "host future cmds": summary.future_commands})
    if dropped:
        print("dropped inputs: " + ", ".join(f"{k} {v}" for k, v in dropped.items()))
    if summary.invalid_commands:
        print(f"flight faults: {summary.invalid_commands} invalid command(s), not applied (see events.csv)")
    print("depends on this host's speed: " + "; ".join(f"{k} = {v}" for k, v in summary.host_speed_dependent.items()))
    from rvd_pil.host_sim.record import record_digest

    print(f"run record: {run_dir} (digest without clock readings {record_digest(run_dir)[:16]})")
    if failure:
        return 1
    return 0 if summary.reached else (130 if interrupted else 1)


if __name__ == "__main__":
    sys.exit(main())
