"""rvd-run: run one scenario processor-in-the-loop with the flight executable.

    rvd-run case1_vbar                           nonlinear truth (J2, drag), thruster and sensor noise
    rvd-run case1_vbar --truth cw --ideal        CW truth, no noise, impulsive burns (exact reference)
    rvd-run random:7                             a seeded random scenario (dissertation ch. 4 distribution)
    rvd-run case3_rotating --runner "qemu-arm -cpu cortex-a9" --flight-sw build/cross/q7s/flight_sw/rvd_flight_sw
    rvd-run case1_vbar -- --horizon 45,15,12     everything after -- goes to the flight software

It starts the host's Zenoh session and the flight software, shows progress, prints a summary
(delta-v and time per phase, docked or why not, what was dropped from the link, which settings
depend on this host's speed) and writes the run record (runs/<time>-<scenario>/). With --ideal the
control delay is "none" unless --delay says otherwise, so the run uses no wall-clock reading:
three runs give the same record digest.
"""
from __future__ import annotations

import argparse
import signal
import sys
import time

from host_sim import scenario as scenarios
from host_sim.server import PHASE_NAMES, ServerConfig


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
    ap.add_argument("--flight-sw", default=None, help="flight executable (default: build/native or $RVD_FLIGHT_SW)")
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
    return "; ".join([head] + (["worst: " + ", ".join(worst)] if worst else []) + figures)


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    split = argv.index("--") if "--" in argv else len(argv)
    args = build_parser().parse_args(argv[:split])
    flight_args = argv[split + 1:]
    delay = args.delay or ("none" if args.ideal else "reported")
    cfg = ServerConfig(mode=args.zenoh_mode, lockstep=args.realtime is None, speedup=args.realtime or 1.0,
                       cmd_timeout_s=args.cmd_timeout, delay_model=delay,
                       allow_vehicle_mismatch=args.allow_vehicle_mismatch)
    progress = Progress(args.quiet)
    from host_sim.pil import run_pil  # after argument errors, so --help stays fast

    interrupted = []

    def on_started(server, proc):
        def stop(signum, frame):
            interrupted.append(signum)
            server.stop()
        signal.signal(signal.SIGINT, stop)
        signal.signal(signal.SIGTERM, stop)

    meta = {}
    if args.guidance is not None:
        from host_sim.guidance_build import LawBuildError, build_native

        try:
            exe, manifest = build_native(args.guidance)
        except LawBuildError as exc:
            print(f"rvd-run: {exc}", file=sys.stderr)
            return 2
        if args.flight_sw is None:
            args.flight_sw = str(exe)
        flight_args = manifest.flight_args() + flight_args
        meta["guidance_law"] = {"name": manifest.name, "folder": str(manifest.folder), "executable": args.flight_sw}
    try:
        summary, run_dir = run_pil(
            args.scenario, seed=args.seed, truth=args.truth,
            sensor_noise=not (args.ideal or args.no_sensor_noise), thrust_noise=not (args.ideal or args.no_thrust_noise),
            impulsive=args.ideal or args.impulsive, flight_exe=args.flight_sw, flight_args=flight_args,
            runner=args.runner, config=cfg, run_dir=args.out, on_step=progress, on_started=on_started, meta=meta,
        )
    except FileNotFoundError as exc:
        print(f"rvd-run: {exc}", file=sys.stderr)
        return 2
    progress.done()
    if summary.end.startswith(("flight software refused the configuration", "vehicle mismatch")):
        source = argv[:split][0] if argv[:split] and not argv[0].startswith("-") else args.scenario.name
        print(f"rvd-run: {source}: {summary.end} (run record {run_dir})", file=sys.stderr)
        return 2
    print(f"scenario {args.scenario.name}: {summary.end} after {summary.steps} steps, "
          f"t = {summary.t_s:.0f} s, final distance to the port {summary.final_range_to_port_m:.3f} m")
    print(summary.table())
    if summary.safety:
        print(f"safety (truth): {_safety_line(summary.safety)}")
    if summary.hello is not None:
        h = summary.hello
        print(f"flight software: {h.arch} {h.cpu_model}, {h.compiler}; horizons {tuple(h.horizon)}")
    if summary.telemetry is not None:
        t = summary.telemetry
        for i, ph in enumerate(("rendezvous", "approach", "docking")):
            if t.steps[i]:
                print(f"  {ph:<10} {t.steps[i]:4d} solves  mean {t.mean_solve_us[i]:9.1f} us  "
                      f"max {t.max_solve_us[i]:9.1f} us (step {t.max_step[i]})  overruns {t.overruns[i]}")
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
    from host_sim.record import record_digest

    print(f"run record: {run_dir} (digest without clock readings {record_digest(run_dir)[:16]})")
    return 0 if summary.docked else (130 if interrupted else 1)


if __name__ == "__main__":
    sys.exit(main())
