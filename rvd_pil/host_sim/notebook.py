"""The notebook API: one scenario, a campaign or a study from Python, with pandas DataFrames back.

    from rvd_pil.host_sim import notebook as rvd
    run = rvd.run_scenario("case1_vbar", truth="cw", ideal=True)     # like `rvd-run case1_vbar --truth cw --ideal`
    run.docked, run.summary.dv_total_mps
    run.steps            # one row per control step; phase, guidance_status, solver_status as categoricals
    run.solves()         # the guidance solves only, with the horizon of their phase as a number
    rvd.load_run("runs/…")                                             # the same from a record on disk
    rvd.run_campaign(["rpi3"], out="reports/pil")                      # like `make pil TARGET=rpi3`
    rvd.run_study("ch5_robustness", quick=True)                        # like `rvd-study ch5_robustness --quick`

The defaults are the command line's: nonlinear truth with every noise source and finite burns; the
control delay "none" with ideal=True, the estimated target time with a target, else the flight
computer's reported step time. docs/tutorial.md walks through it.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Sequence

import pandas as pd

from rvd_pil.host_sim.server import GUIDANCE_STATUS, PHASE_NAMES, SOLVER_STATUS, ServerConfig

#: Categorical column -> code -> name, from the link schema's meanings (rvd_pil/host_sim/server.py).
CATEGORIES = {"phase": PHASE_NAMES, "guidance_status": GUIDANCE_STATUS, "solver_status": SOLVER_STATUS}
_PHASE_INDEX = {"rendezvous": 0, "approach": 1, "docking": 2}


def categorize(steps: pd.DataFrame) -> pd.DataFrame:
    """The record's integer codes as named categoricals (phase 'rendezvous', solver_status 'solved', …);
    a code the table does not know keeps its number as its name. Returns a new DataFrame."""
    out = steps.copy()
    for col, names in CATEGORIES.items():
        if col not in out:
            continue
        codes = out[col]
        labels = [names.get(int(c), str(int(c))) if pd.notna(c) else None for c in codes]
        order = list(dict.fromkeys([*names.values(), *(x for x in labels if x is not None)]))
        out[col] = pd.Categorical(labels, categories=order, ordered=col == "phase")
    return out


@dataclass
class Run:
    """One run: its record directory, meta.json, steps (categoricals) and events, and the summary
    when it was run here (None when loaded from disk)."""
    dir: Path
    meta: dict
    steps: pd.DataFrame
    events: pd.DataFrame
    summary: object = None

    @property
    def docked(self) -> bool:
        return bool(self.meta.get("docked"))

    @property
    def horizons(self) -> tuple[int, int, int] | None:
        """(rendezvous, approach, docking) prediction horizons the flight software used."""
        h = (self.meta.get("flight_hello") or {}).get("horizon") or self.meta.get("horizons")
        return None if h is None else tuple(int(x) for x in h)

    @property
    def safety(self) -> str | None:
        """The safety monitor's verdict on the truth: 'safe', 'unsafe' or 'started_unsafe'."""
        return (self.meta.get("safety") or {}).get("verdict")

    def solves(self) -> pd.DataFrame:
        """The control steps with a guidance solve (phase rendezvous/approach/docking, solver run),
        with the horizon N of their phase as an integer column."""
        s = self.steps
        s = s[s["phase"].isin(list(_PHASE_INDEX)) & (s["solver_status"] != "not_run")].copy()
        h = self.horizons
        s["N"] = [h[_PHASE_INDEX[p]] if h else pd.NA for p in s["phase"]]
        return s


def load_run(run_dir: str | Path) -> Run:
    """A run record (rvd-run, run_scenario, a campaign's runs/…) as a Run."""
    from rvd_pil.host_sim.record import load_events, load_run as _load

    meta, steps = _load(run_dir)
    return Run(dir=Path(run_dir), meta=meta, steps=categorize(steps), events=load_events(run_dir))


def run_scenario(scenario, *, truth: str = "nonlinear", ideal: bool = False, seed: int = 0,
                 sensor_noise: bool | None = None, thrust_noise: bool | None = None, impulsive: bool | None = None,
                 delay: str | None = None, target: str | None = None, cpu: str | None = None,
                 flight_sw: str | None = None, flight_args: Sequence[str] = (), cycle_model: bool = True,
                 out: str | Path | None = None, cmd_timeout_s: float = 10.0) -> Run:
    """Run one scenario processor-in-the-loop, as `rvd-run` does, and return the Run.

    scenario: a shipped name ("case1_vbar"), a TOML path, "random:<seed>" or a Scenario.
    ideal: no sensor or thruster noise and impulsive burns (each also settable on its own).
    delay: "none" | "reported" | "estimated" (default: none when ideal, estimated with a target,
    else reported). target / cpu: run under QEMU as that flight computer (rvd_pil/qemu/targets.toml) with
    the instruction counter and, with cycle_model, the block profiler priced into cycles.csv.
    flight_args: options for the flight executable (e.g. ["--horizon", "45,15,12"]).
    out: the record directory (default runs/<time>-<scenario>-<id>).
    Raises rvd_pil.host_sim.pil.FlightLaunchError or FileNotFoundError before anything runs when the
    flight executable cannot run; a flight process that fails shows in run.meta["end"]."""
    from rvd_pil.host_sim import cli
    from rvd_pil.host_sim import scenario as scenarios
    from rvd_pil.host_sim.pil import default_run_dir, run_pil

    scen = scenario
    if isinstance(scenario, (str, Path)):
        text = str(scenario)
        scen = (scenarios.random_scenario(int(text.split(":", 1)[1])) if text.startswith("random:")
                else scenarios.load(text))
    run_dir = Path(out) if out else default_run_dir(scen.name)
    flight_command = profile = tgt = None
    exe = flight_sw
    if target:
        ns = SimpleNamespace(target=target, cpu=cpu, flight_sw=flight_sw, no_cycle_model=not cycle_model)
        tgt, exe, flight_command, profile = cli._target_setup(ns, run_dir)
    elif cpu:
        raise ValueError("cpu needs a target")
    delay = delay or ("none" if ideal else "estimated" if tgt is not None else "reported")
    cfg = ServerConfig(cmd_timeout_s=cmd_timeout_s, delay_model=delay)
    meta = None
    if tgt is not None:
        cfg.cpi, cfg.clock_hz = tgt.cpi.nominal, tgt.clock_hz
        cfg.hello_timeout_s, cfg.cmd_timeout_s = max(cfg.hello_timeout_s, 180.0), max(cfg.cmd_timeout_s, 120.0)
        flight_args = [*cli.emulated_lease_args(cfg.cmd_timeout_s), *flight_args]
        meta = {"target": tgt.name, "build": tgt.build_name, "cpu": tgt.cpu, "arch": tgt.arch,
                "clock_hz": tgt.clock_hz, "mode": "user"}
    summary, run_dir = run_pil(
        scen, seed=seed, truth=truth,
        sensor_noise=not ideal if sensor_noise is None else sensor_noise,
        thrust_noise=not ideal if thrust_noise is None else thrust_noise,
        impulsive=ideal if impulsive is None else impulsive,
        flight_exe=None if flight_command else exe, flight_args=list(flight_args), flight_command=flight_command,
        config=cfg, run_dir=run_dir, meta=meta)
    if profile is not None and summary.telemetry is not None:
        from rvd_pil.qemu import cycles

        cycles.price_run(profile, Path(exe), cycles.CycleModel(tgt), run_dir / "cycles.csv")
    run = load_run(run_dir)
    run.summary = summary
    return run


@dataclass
class CampaignResult:
    """A campaign folder's verdict, statistics, checks and runs as DataFrames, and its report."""
    out: Path
    verdict: pd.DataFrame
    stats: pd.DataFrame
    checks: pd.DataFrame
    runs: pd.DataFrame
    report: Path
    extra: dict = field(default_factory=dict)


def load_campaign(out: str | Path) -> CampaignResult:
    """The DataFrames of a campaign folder whose report was written (report.json)."""
    out = Path(out)
    rep = json.loads((out / "report.json").read_text())
    verdict = pd.DataFrame(rep["verdict"])
    stats = pd.DataFrame(rep["stats"])
    for df in (verdict, stats):
        if "phase" in df:
            df["phase"] = pd.Categorical(df["phase"], categories=list(_PHASE_INDEX), ordered=True)
    runs = pd.DataFrame(rep["runs"])
    return CampaignResult(out=out, verdict=verdict, stats=stats, checks=pd.DataFrame(rep.get("check_table", [])),
                          runs=runs, report=out / "report.html", extra={"provenance": rep.get("provenance")})


def run_campaign(targets: Sequence[str] = ("q7s", "rpi3"), *, out: str | Path = "reports/pil", cpu: str | None = None,
                 scenarios: Sequence[str] | None = None, full: bool = False, checks: bool = True,
                 system_mode: bool = True, replace: bool = False) -> CampaignResult:
    """Run the PIL campaign of `make pil` (rvd_pil/bench/campaign.py) into `out`, write its report and
    return its DataFrames. A folder holding another campaign is refused
    (rvd_pil.bench.campaign.CampaignConflict) unless replace=True; the same settings resume."""
    from rvd_pil.bench import campaign

    argv = ["--targets", ",".join(targets), "--out", str(out)]
    argv += ["--cpu", cpu] if cpu else []
    argv += ["--scenarios", ",".join(scenarios)] if scenarios else []
    argv += (["--full"] if full else []) + ([] if checks else ["--no-checks"]) + ([] if system_mode else ["--no-system"])
    spec, out_path, _, _ = campaign.parse_args(argv + (["--replace"] if replace else []))
    campaign.claim(out_path, spec, replace)
    rc = campaign.main(argv)  # the folder is claimed by these settings now: main resumes it
    if rc != 0:
        raise RuntimeError(f"campaign into {out} failed (exit code {rc}); see its output above")
    return load_campaign(out_path)


def run_study(study, *, quick: bool = False, jobs: int | None = None, dask: str | None = None,
              out: str | Path | None = None, progress: bool = False):
    """Run a study file (rvd_pil/studies/*.toml or a path) as `rvd-study` does and return its StudyResult:
    .runs (one row per grid point), .summary (per sweep point), .solves (per guidance solve of a
    timing study), .tables; phase and status columns as categoricals."""
    from rvd_pil.studies import run_study as _run_study

    result = _run_study(study, quick=quick, jobs=jobs, dask=dask, out=out, progress=progress, say=lambda *_: None)
    for df in (result.runs, result.summary, result.solves):
        for col, names in CATEGORIES.items():
            if col in df and pd.api.types.is_numeric_dtype(df[col]):
                df[col] = categorize(df[[col]])[col].to_numpy()
        if "phase" in df and df["phase"].dtype == object:
            df["phase"] = pd.Categorical(df["phase"], categories=list(dict.fromkeys(
                [*PHASE_NAMES.values(), *df["phase"].dropna().unique()])))
    return result
