"""The PIL campaign behind `make pil`: the flight software cross-built for each target, run under QEMU
against host_sim over Zenoh (lockstep), and turned into a report.

    python -m rvd_pil.bench.campaign                        quick default: q7s and rpi3
    python -m rvd_pil.bench.campaign --targets beaglebone   one target (TARGET=beaglebone make pil)
    python -m rvd_pil.bench.campaign --targets q7s --cpu cortex-a8     swap the emulated CPU model
    python -m rvd_pil.bench.campaign --full                 more scenarios (100 random starts, as ch. 6)
    python -m rvd_pil.bench.campaign --scenarios case1_crossing_obstacle,dong_2d_case_a --horizon-sets scenario
                                                    named scenarios (or TOML paths), each at its own horizons

Per target:
  1. cross-build the static flight executable (cross/, rvd_pil/qemu/targets.toml);
  2. checks: Case 1 in the ideal setting (CW truth, no noise, impulsive, no delay) natively and twice
     under QEMU: delta-v agreement, instruction counts and cycle estimates identical run to run;
  3. user mode + instruction counter + block profiler (rvd_pil/qemu/plugin/): every (scenario x horizon
     set) run, nonlinear truth (J2, drag), thruster and sensor noise, control delay = estimated
     target time (instructions x the cycle model's mean CPI on the ideal Case 1 run); the flight
     software takes its deadlines on the same target time (--target-clock: that CPI, the target's clock);
     each run's solves priced by the cycle model (rvd_pil/qemu/cycles.py) into its cycles.csv; the cache
     model runs in the ideal Case 1, the timing runs borrow its per-block miss rates;
  4. the cycle model's microbenchmarks for the target's CPU (rvd_pil/bench/microbench/) beside the
     published figures;
  5. system mode (where QEMU has a machine): Case 1 twice with -icount: in-guest solve times identical;
with rpi3 (and checks): the external anchor, OSQP's generated code for its quadcopter MPC example
estimated for the Pi 3B beside the published figures (rvd_pil/bench/osqp_anchor.py);
then rvd_pil/bench/report.py writes the report (HTML + PNG + CSV/JSON).

Runs already finished with the same executable and settings are reused: a stopped campaign resumes.
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from rvd_pil import paths
from rvd_pil.host_sim import scenario as scenarios
from rvd_pil.host_sim.pil import find_flight_executable, run_pil
from rvd_pil.host_sim.server import ServerConfig
from rvd_pil.qemu.semihosting_link import HOST_ZENOH_ID

# Horizon sets (rendezvous, approach, docking): together they cover the dissertation's ch. 6 test plan
# (rendezvous 15/30/45, approach 5/15/30, docking 5/12/30) in three runs per scenario.
HORIZON_SETS = ((15, 5, 5), (30, 15, 12), (45, 30, 30))
DEFAULT_HORIZONS = (30, 15, 12)
# A plug-in law's checks stop the ideal Case 1 here (simulated seconds) unless told otherwise: a law
# whose ideal run never leaves the rendezvous (the QOCOGEN peer: its QPs with large multipliers fail,
# examples/guidance/README.md) flies it to the 12000 s timeout, 400 steps of up to 3.4 s of emulation
# each; 3000 s is a hundred rendezvous steps (Ts 30 s), enough to compare two runs' counts step by step.
PLUGIN_CHECK_TIMEOUT_S = 3000.0


@dataclass
class Spec:
    targets: list[str]
    cpu: str | None = None
    scenarios: list[str] = field(default_factory=lambda: ["case1_vbar", "random:1", "random:2"])
    # Horizon sets flown per scenario; an empty list flies each scenario at its own horizons (its
    # [guidance] table's, else the flight software's defaults) without --horizon.
    horizon_sets: list[tuple[int, int, int]] = field(default_factory=lambda: list(HORIZON_SETS))
    truth: str = "nonlinear"
    noise: bool = True
    seed: int = 0
    checks: bool = True
    system_mode: bool = True
    cmd_timeout_s: float = 120.0
    # The checks' ideal Case 1 ends at this simulated time instead of the scenario's timeout: a law whose
    # ideal run never docks would otherwise fly it for 12000 s (the check is about identical counts).
    check_timeout_s: float | None = None
    # Every timing run ends at this simulated time (None: the scenario's timeout): for a law too slow to
    # fly whole scenarios under emulation, measured on their beginning.
    flight_time_s: float | None = None
    guidance: str | None = None  # a plug-in guidance law's folder (law.toml): flown instead of the built-in MPC


def _scenario(label: str):
    if label.startswith("random:"):
        return scenarios.random_scenario(int(label.split(":", 1)[1]))
    return scenarios.load(label)


def _scenario_horizons(label: str) -> tuple[int, int, int]:
    """The horizons a scenario flies without --horizon: its [guidance] table's, else the defaults."""
    g = getattr(_scenario(label), "guidance", {}) or {}
    return tuple(int(g.get(f"{p}.N", g.get("phases.N", d))) for p, d in zip(("rendezvous", "approach", "docking"), DEFAULT_HORIZONS))


def _shown(path: Path) -> Path:
    """A build product's path as the log shows it: relative to the checkout when it is in one."""
    root = paths.checkout()
    return path.relative_to(root) if root is not None and path.is_relative_to(root) else path


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]


def _finished(run_dir: Path, fingerprint: str) -> bool:
    meta = run_dir / "meta.json"
    if not meta.exists():
        return False
    try:
        m = json.loads(meta.read_text())
    except json.JSONDecodeError:
        return False
    return m.get("status") == "finished" and m.get("campaign_fingerprint") == fingerprint


def _mean_cpi(cycles_csv: Path) -> float:
    """Nominal cycles over instructions of every priced solve of a run."""
    import csv

    with cycles_csv.open() as f:
        rows = list(csv.DictReader(f))
    insns = sum(float(r["instructions"]) for r in rows)
    if not insns:
        raise RuntimeError(f"{cycles_csv}: no counted solves to take a CPI from")
    return sum(float(r["cycles_nominal"]) for r in rows) / insns


def _fresh(run_dir: Path) -> None:
    """A run directory is written once: clear an unfinished or outdated one before re-running it."""
    if run_dir.exists():
        for p in sorted(run_dir.rglob("*"), reverse=True):
            p.unlink() if p.is_file() else p.rmdir()
        run_dir.rmdir()


class Campaign:
    def __init__(self, spec: Spec, out: Path):
        self.spec, self.out = spec, out
        self.runs_dir = out / "runs"
        self.log_lines: list[str] = []
        self.t0 = time.monotonic()
        self.owned: list[str] = []  # every run directory of this campaign (run or reused), for the report
        self.law_args: list[str] = []     # a plug-in law's parameter defaults (its manifest)
        self.native_exe: Path | None = None
        if spec.guidance:
            from rvd_pil.host_sim.guidance_build import build_native

            self.native_exe, manifest = build_native(spec.guidance)
            self.law_args = manifest.flight_args()
            self.say(f"guidance law {manifest.name} from {manifest.folder}: {_shown(self.native_exe)}")

    def say(self, text: str) -> None:
        line = f"[{time.monotonic() - self.t0:6.0f} s] {text}"
        print(line, flush=True)
        self.log_lines.append(line)

    # -- one run ---------------------------------------------------------------------------------
    def run(self, run_dir: Path, scenario_label: str, *, fingerprint: str, flight_command=None, runner=(),
            flight_exe=None, flight_args=(), ideal=False, config: ServerConfig | None = None,
            flight_endpoint=None, meta=None, timeout_s: float | None = None) -> dict:
        self.owned.append(str(run_dir.relative_to(self.out)))
        if timeout_s is not None:  # a run cut short is another run than the whole one
            fingerprint = hashlib.sha256(f"{fingerprint}cut{timeout_s}".encode()).hexdigest()[:16]
        if _finished(run_dir, fingerprint):
            self.say(f"  reuse  {run_dir.relative_to(self.out)}")
            return json.loads((run_dir / "meta.json").read_text())
        _fresh(run_dir)
        spec = self.spec
        cfg = config or ServerConfig()
        cfg.cmd_timeout_s = spec.cmd_timeout_s
        cfg.hello_timeout_s = 180.0
        kw = dict(truth="cw", sensor_noise=False, thrust_noise=False, impulsive=True) if ideal else dict(
            truth=spec.truth, sensor_noise=spec.noise, thrust_noise=spec.noise, impulsive=False)
        if ideal:
            cfg.delay_model = "none"
        t0 = time.monotonic()
        steps = [0]

        def progress(k, summary, cmd):
            steps[0] = k + 1
            if k % 50 == 0 and k:
                print(f"           ... step {k}, {time.monotonic() - t0:5.1f} s", flush=True)

        if flight_exe is None and flight_command is None and not runner:
            flight_exe = self.native_exe
        scn = _scenario(scenario_label)
        if timeout_s is not None:
            scn = dataclasses.replace(scn, timeout_s=min(scn.timeout_s, timeout_s))
        summary, _ = run_pil(scn, seed=spec.seed, **kw, flight_exe=flight_exe,
                             flight_args=[*self.law_args, *flight_args], runner=runner, flight_command=flight_command,
                             flight_endpoint=flight_endpoint, config=cfg, run_dir=run_dir, on_step=progress,
                             meta={"campaign_fingerprint": fingerprint, "scenario_label": scenario_label,
                                   **(meta or {})})
        self.say(f"  {summary.end:<8} {run_dir.relative_to(self.out)}: {summary.steps} steps, "
                 f"dv {summary.dv_total_mps:.3f} m/s, {time.monotonic() - t0:.1f} s wall")
        return json.loads((run_dir / "meta.json").read_text())

    # -- one target ------------------------------------------------------------------------------
    def target(self, name: str) -> dict:
        from rvd_pil.host_sim.cli import emulated_lease_args
        from rvd_pil.qemu import build, cycles, plugin, system, targets, user

        spec = self.spec
        t = targets.load(name, cpu=spec.cpu)
        model = cycles.CycleModel(t)
        self.say(f"{t.name}: {t.arch} {t.cpu} at {t.clock_hz / 1e6:.0f} MHz (cycle model: {model.engine} "
                 f"{model.entry.get('mca_cpu', t.cpu)}, {len(model.corrections)} corrections), building the flight executable")
        if spec.guidance:  # the plug-in law, statically, by the same cross toolchain
            from rvd_pil.host_sim.guidance_build import build_cross

            exe, _ = build_cross(spec.guidance, t)
        else:
            exe = build.cross_build(t)
        self.say(f"{t.name}: {_shown(exe.path)} ({exe.size_bytes / 1024:.0f} KiB, static)")
        lib = plugin.build(download=True)
        profile_lib = plugin.build_profile(download=False)
        tdir = self.runs_dir / t.build_name
        tdir.mkdir(parents=True, exist_ok=True)
        base = {"target": t.name, "build": t.build_name, "cpu": t.cpu, "arch": t.arch, "clock_hz": t.clock_hz,
                "cpi": asdict(t.cpi), "exe_size_bytes": exe.size_bytes, "exe_sha": _sha(exe.path),
                "block_profile": {"cache": model.cache_geometry, "cache_scope": "solves"}}
        fp_base = json.dumps([base, spec.truth, spec.noise, spec.seed], sort_keys=True)

        def user_mode(run_dir: Path, plugin_log: Path, cpi: float, cache: bool = True):
            # The flight's deadlines on target time at the CPI of the run's control delay (the
            # counter answers its clock reads): the emulator's speed then decides nothing.
            counter = plugin.InsnCounter(log=plugin_log, library=lib)
            profiler = plugin.BlockProfiler(out=run_dir.with_suffix(".blocks"),
                                            cache=model.cache_geometry if cache else None, library=profile_lib)
            clock = user.target_clock_args(cpi, t.clock_hz)
            lease = emulated_lease_args(spec.cmd_timeout_s)  # a heavy step outlasts the default lease
            return lambda args: user.command(t, exe.path, [*args, *clock, *lease], plugin=[counter, profiler])

        def priced(run_dir: Path, miss_rates_from: Path | None = None) -> Path:
            return cycles.price_run(run_dir.with_suffix(".blocks"), exe.path, model, run_dir / "cycles.csv",
                                    miss_rates_from=miss_rates_from)

        info = {"target": base, "runs": [], "checks": {},
                "cycle_model": {"cpu": model.cpu, "engine": model.engine, "fingerprint": model.fingerprint(),
                                "calibrated": bool(model.calibration)}}
        delay_cpi, delay_source = t.cpi.nominal, "registry CPI (rvd_pil/qemu/targets.toml)"
        # 2. ideal Case 1: native once, QEMU user mode twice (first: its CPI sets the timing runs' delay)
        if spec.checks:
            cut = spec.check_timeout_s
            ideal_meta = {**base, "horizons": DEFAULT_HORIZONS, "kind": "check", "check_timeout_s": cut}
            native_dir = self.runs_dir / "native" / "case1-ideal"
            fp = hashlib.sha256(f"native{_sha(self.native_exe or find_flight_executable())}".encode()).hexdigest()[:16]
            native = self.run(native_dir, "case1_vbar", fingerprint=fp, ideal=True, timeout_s=cut,
                              meta={"target": "host", "mode": "native", "kind": "check", "horizons": DEFAULT_HORIZONS,
                                    "check_timeout_s": cut})
            reps = []
            for rep in (1, 2):
                run_dir = tdir / f"case1-ideal-{rep}"
                fp = hashlib.sha256(f"{fp_base}ideal{rep}clock{delay_cpi}".encode()).hexdigest()[:16]
                # Every byte both sides send repeats in the two runs (run id, link key, both ZenohIDs
                # and sequence numbers), so the flight's allocations, and with them the addresses
                # the cache model sees in the solves, are the same in both.
                reps.append(self.run(run_dir, "case1_vbar", fingerprint=fp, ideal=True, timeout_s=cut,
                                     flight_command=user_mode(run_dir, run_dir.with_suffix(".insns"), delay_cpi),
                                     flight_args=["--session-seed", "1"],
                                     config=ServerConfig(run_id="case1-ideal", zenoh_id=HOST_ZENOH_ID,
                                                         link_key=CHECK_LINK_KEY, zenoh_lease_ms=60000),
                                     meta={**ideal_meta, "mode": "user",
                                           "flight_clock": {"cpi": delay_cpi, "clock_hz": t.clock_hz,
                                                            "cpi_source": delay_source}}))
                priced(run_dir)
                info["runs"].append(str(run_dir.relative_to(self.out)))
            info["checks"]["native_vs_qemu"] = {"native_dv_mps": native.get("dv_total_mps"),
                                                "qemu_dv_mps": [r.get("dv_total_mps") for r in reps],
                                                "native_steps": native.get("steps"),
                                                "qemu_steps": [r.get("steps") for r in reps],
                                                "runs": [str(native_dir.relative_to(self.out)),
                                                         *[f"runs/{t.build_name}/case1-ideal-{i}" for i in (1, 2)]]}
            delay_cpi = round(_mean_cpi(tdir / "case1-ideal-1" / "cycles.csv"), 2)
            delay_source = f"cycle model, mean nominal CPI of {t.build_name}/case1-ideal-1"
            self.say(f"{t.name}: cycle model CPI {delay_cpi} on the ideal Case 1 (registry guess {t.cpi.nominal}): "
                     "the timing runs' control delay uses it")
        info["delay_cpi"] = {"cpi": delay_cpi, "source": delay_source}
        # 3. the timing campaign. The cache model (a callback per memory access: several times the
        # emulation time of a solve) ran in the ideal Case 1; these runs borrow its per-block miss
        # rates (without checks: the first run of the campaign runs it).
        reference = tdir / "case1-ideal-1" if spec.checks else None
        for horizon_set in spec.horizon_sets or [None]:
            for label in spec.scenarios:
                horizons = horizon_set or _scenario_horizons(label)
                hlabel = "N" + "-".join(map(str, horizons)) if horizon_set else "Nscenario"
                run_dir = tdir / f"{Path(label).stem if label.endswith('.toml') else label.replace(':', '')}-{hlabel}"
                cache = reference is None
                fp = hashlib.sha256(f"{fp_base}{label}{horizons}{delay_cpi}{cache}".encode()).hexdigest()[:16]
                cfg = ServerConfig(delay_model="estimated", cpi=delay_cpi, clock_hz=t.clock_hz)
                self.run(run_dir, label, fingerprint=fp, timeout_s=spec.flight_time_s,
                         flight_command=user_mode(run_dir, run_dir.with_suffix(".insns"), delay_cpi, cache=cache),
                         flight_args=["--horizon", ",".join(map(str, horizons))] if horizon_set else [], config=cfg,
                         meta={**base, "mode": "user", "horizons": horizons, "kind": "timing",
                               "flight_time_s": spec.flight_time_s,
                               "delay_cpi": delay_cpi, "delay_cpi_source": delay_source,
                               "flight_clock": {"cpi": delay_cpi, "clock_hz": t.clock_hz, "cpi_source": delay_source},
                               "memory_term": "cache model" if cache else
                               f"miss rates of {reference.relative_to(self.out)}"})
                priced(run_dir, None if cache else reference / "cycles.miss-rates.json")
                reference = reference or run_dir
                info["runs"].append(str(run_dir.relative_to(self.out)))
        # 4. the cycle model's microbenchmarks for this CPU
        if spec.checks:
            from rvd_pil.bench.microbench import run as microbench

            try:
                results = [asdict(r) | {"within": r.within} for r in microbench.measure(model.cpu)]
            except (KeyError, RuntimeError) as exc:  # a CPU without microbenchmark support: say so
                results = [{"cpu": model.cpu, "error": str(exc)}]
            (self.out / f"microbench-{model.cpu}.json").write_text(json.dumps(results, indent=1))
            ok = sum(1 for r in results if r.get("within"))
            n_pub = sum(1 for r in results if r.get("within") is not None)
            self.say(f"{t.name}: microbenchmarks {ok}/{n_pub} within the published figures' tolerance "
                     f"({len(results) - n_pub} without a usable published figure)")
        if not spec.checks:
            return info
        # 5. system mode, twice
        if spec.system_mode and t.system_note:
            self.say(f"{t.name}: no system mode: {t.system_note}")
        if spec.system_mode and t.system is not None:
            img = system.image(t)
            for rep in (1, 2):
                run_dir = tdir / f"case1-ideal-system-{rep}"
                initrd = tdir / "initrd.cpio"
                if not initrd.exists() or initrd.stat().st_mtime < exe.path.stat().st_mtime:
                    system.program_initrd(img, exe.path, initrd)
                fp = hashlib.sha256(f"{fp_base}system{rep}{img.kernel_version}semihosting".encode()).hexdigest()[:16]

                def launch(args, img=img, initrd=initrd):
                    return system.command(t, img, initrd, args, net=False, semihosting=True)

                self._system_run(run_dir, fp, launch, {**ideal_meta, "mode": "system", "kernel": img.kernel_version})
                info["runs"].append(str(run_dir.relative_to(self.out)))
            info["checks"]["system_mode"] = [str((tdir / f"case1-ideal-system-{i}").relative_to(self.out)) for i in (1, 2)]
        return info

    def _system_run(self, run_dir: Path, fp: str, launch, meta: dict) -> dict:
        """System mode, with the link through semihosting (rvd_pil/qemu/semihosting_link.py): the guest
        clock stands still while the host computes, so two runs give the same in-guest times."""
        from rvd_pil.qemu import semihosting_link

        flight_command = semihosting_link.flight_command(launch, run_dir.parent / "semihosting-link")
        # Everything the guest receives is the same byte for byte in both runs: the run id (in the
        # keys and on the kernel command line) and the host's ZenohID (Zenoh derives the initial
        # sequence numbers from the two ZenohIDs; the guest's own comes from its kernel's RNG, which
        # is seeded identically when its inputs are); a long host lease keeps Zenoh's keep-alives,
        # sent on the host's clock when its link idles, out of the run. The PMU counts the solves'
        # user-mode instructions in the guest, where the plugin cannot.
        return self.run(run_dir, "case1_vbar", fingerprint=fp, ideal=True, flight_command=flight_command,
                        timeout_s=self.spec.check_timeout_s,
                        meta={**meta, "link": "semihosting"},
                        flight_args=["--pmu-instructions"],
                        config=ServerConfig(run_id="case1-system", zenoh_id=semihosting_link.HOST_ZENOH_ID,
                                            zenoh_lease_ms=60000))


# The reproducibility checks' link key: fixed so that the two runs send the same bytes (a check run,
# not a flight: any key works, a secret one is not needed).
CHECK_LINK_KEY = hashlib.sha256(b"rvd-pil reproducibility check").digest()


def parse_args(argv=None) -> tuple[Spec, Path, bool]:
    ap = argparse.ArgumentParser(prog="python -m rvd_pil.bench.campaign", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__.split("\n\n", 1)[1])
    ap.add_argument("--targets", default="q7s,rpi3", help="comma-separated targets of rvd_pil/qemu/targets.toml (default q7s,rpi3)")
    ap.add_argument("--cpu", default=None, help="override the emulated CPU model (e.g. cortex-a8)")
    ap.add_argument("--scenarios", default=None,
                    help="comma-separated scenario names, TOML paths or random:<seed> (obstacle and planar scenarios too)")
    ap.add_argument("--horizon-sets", default="all", choices=("all", "default", "scenario"),
                    help="horizons per scenario: all three sets (15/5/5, 30/15/12, 45/30/30; default), the default "
                         "30/15/12 only, or each scenario's own (its [guidance] table's), e.g. for the obstacle scenarios")
    ap.add_argument("--full", action="store_true", help="Case 1-3 and 20 random starts (long)")
    ap.add_argument("--truth", choices=("nonlinear", "cw"), default="nonlinear")
    ap.add_argument("--no-noise", action="store_true")
    ap.add_argument("--no-checks", action="store_true", help="skip the determinism and native-vs-QEMU checks")
    ap.add_argument("--no-system", action="store_true", help="skip QEMU system mode")
    ap.add_argument("--flight-time-s", type=float, default=None, metavar="S",
                    help="end every timing run at S seconds of simulated time (default: the scenario's timeout): "
                         "a law too slow to fly whole scenarios under emulation, measured on their beginning")
    ap.add_argument("--check-timeout-s", type=float, default=None, metavar="S",
                    help="end the checks' ideal Case 1 runs (native and twice under QEMU) at S seconds of simulated "
                         f"time (default: {PLUGIN_CHECK_TIMEOUT_S:g} s for a --guidance law, whose ideal run may never "
                         "dock, the whole run for the built-in MPC; 0: the whole run)")
    ap.add_argument("--out", default=str(paths.reports_root() / "pil"),
                    help="campaign directory (default reports/pil in the checkout, or in the current folder)")
    ap.add_argument("--report-only", action="store_true", help="rebuild the report from the runs in --out")
    ap.add_argument("--replace", action="store_true",
                    help="--out holds a campaign with other settings: delete its runs and start afresh")
    ap.add_argument("--guidance", default=None, metavar="PATH",
                    help="a plug-in guidance law's folder (law.toml and sources), built for every target and flown "
                         "instead of the built-in MPC")
    a = ap.parse_args(argv)
    if a.flight_time_s is not None and not a.flight_time_s > 0:
        ap.error(f"--flight-time-s must be > 0 seconds, got {a.flight_time_s}")
    if a.check_timeout_s is not None and not a.check_timeout_s >= 0:
        ap.error(f"--check-timeout-s must be >= 0 seconds (0: the whole run), got {a.check_timeout_s}")
    check_cut = (PLUGIN_CHECK_TIMEOUT_S if a.guidance else None) if a.check_timeout_s is None else (a.check_timeout_s or None)
    spec = Spec(targets=[t for t in a.targets.split(",") if t], cpu=a.cpu, truth=a.truth, noise=not a.no_noise,
                checks=not a.no_checks, system_mode=not a.no_system, check_timeout_s=check_cut,
                flight_time_s=a.flight_time_s,
                guidance=str(Path(a.guidance).resolve()) if a.guidance else None)  # one campaign, however named
    if a.full:
        spec.scenarios = ["case1_vbar", "case2_rbar", "case3_rotating"] + [f"random:{i}" for i in range(1, 21)]
    if a.scenarios:
        spec.scenarios = [s for s in a.scenarios.split(",") if s]
    if a.horizon_sets == "default":
        spec.horizon_sets = [DEFAULT_HORIZONS]
    elif a.horizon_sets == "scenario":
        spec.horizon_sets = []
    return spec, Path(a.out), a.report_only, a.replace


def _spec_key(spec: dict) -> dict:
    """The settings that make two campaigns the same campaign (JSON round trip: tuples become lists;
    a setting left unset is the same as one a campaign of an older version did not have)."""
    return {k: v for k, v in json.loads(json.dumps(spec)).items() if v is not None}


def claim(out: Path, spec: Spec, replace: bool = False) -> None:
    """Make `out` this campaign's folder. A folder holding another campaign (other targets, scenarios,
    horizons, truth, noise or checks) is refused, unless `replace` deletes its runs: the report of a
    folder never mixes the runs of two campaigns. The same settings resume (finished runs are reused)."""
    path = out / "campaign.json"
    if path.exists():
        try:
            old = json.loads(path.read_text()).get("spec")
        except (json.JSONDecodeError, AttributeError):
            old = None
        if old is not None and _spec_key(old) != _spec_key(asdict(spec)):
            if not replace:
                diff = sorted(k for k in set(old) | set(asdict(spec)) if _spec_key(old).get(k) != _spec_key(asdict(spec)).get(k))
                raise CampaignConflict(f"{out} holds a campaign with other settings ({', '.join(diff)} differ): "
                                       "choose another --out, or pass --replace to delete its runs")
    elif (out / "runs").exists() and any((out / "runs").rglob("meta.json")) and not replace:
        raise CampaignConflict(f"{out}/runs holds run records of no known campaign (no campaign.json): "
                               "choose another --out, or pass --replace to delete them")
    if replace and (out / "runs").exists():
        _fresh(out / "runs")
    out.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"spec": asdict(spec), "status": "running"}, indent=1))


class CampaignConflict(Exception):
    pass


def main(argv=None) -> int:
    from rvd_pil.qemu import targets

    spec, out, report_only, replace = parse_args(argv)
    unknown = [t for t in spec.targets if t not in targets.names()]
    if unknown:
        print(f"unknown target(s) {unknown}; known: {', '.join(targets.names())}", file=sys.stderr)
        return 2
    from rvd_pil.qemu import cycles

    for name in spec.targets:  # every target needs a cycle model for its CPU: refuse before starting
        t = targets.load(name, cpu=spec.cpu)
        if t.emulated and t.cpu not in cycles.models():
            print(f"{name}: no cycle model for CPU {t.cpu} in rvd_pil/qemu/cycle_models.toml (LLVM has no llvm-mca "
                  f"model for it and none is stated); CPUs with one: {', '.join(cycles.models())}", file=sys.stderr)
            return 2
    for label in spec.scenarios:
        try:
            _scenario(label)
        except Exception as exc:  # a typo in a scenario name must stop the campaign before it starts
            print(f"scenario {label!r}: {exc}", file=sys.stderr)
            return 2
    if not report_only:
        try:
            claim(out, spec, replace)
        except CampaignConflict as exc:
            print(f"campaign: {exc}", file=sys.stderr)
            return 2
    camp = Campaign(spec, out)
    campaign = {"spec": asdict(spec), "status": "finished", "targets": {}}
    if not report_only:
        camp.say(f"campaign -> {out}: targets {spec.targets}, scenarios {spec.scenarios}, "
                 f"horizon sets {spec.horizon_sets}")
        for name in spec.targets:
            campaign["targets"][name] = camp.target(name)
        if spec.checks and "rpi3" in spec.targets and spec.cpu is None:
            # the external anchor: OSQP's generated code on a Raspberry Pi 3B (rvd_pil/bench/osqp_anchor.py)
            from rvd_pil.bench import osqp_anchor

            res = osqp_anchor.run(out, opts=("-O2",))
            camp.say(f"OSQP anchor: {res['summary']}")
        campaign["runs"] = list(dict.fromkeys(camp.owned))
        (out / "campaign.json").write_text(json.dumps(campaign, indent=1))
    from rvd_pil.bench import report

    index = report.write(out)
    camp.say(f"report: {index}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
