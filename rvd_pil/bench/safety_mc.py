"""Monte Carlo safety check of the guidance under the dissertation's disturbances (its ch. 5 set-up).

    python -m rvd_pil.bench.safety_mc                      100 seeded random starts x 3 noise seeds
    python -m rvd_pil.bench.safety_mc --starts 10 --jobs 2 a smaller one
    python -m rvd_pil.bench.safety_mc --out DIR            where the run records go (default reports/safety_mc)
    python -m rvd_pil.bench.safety_mc --base case3_rotating --starts 20 --noise-seeds 1 --flight-args "--horizon 15,5,5"
        # random starts around Case 3's turning target, at short horizons

Every run is the native flight executable against the host simulator over Zenoh (rvd_pil.host_sim.pil.run_pil)
with the nonlinear truth (J2, drag), the Gauss-Markov thrust amplitude error, sensor noise (5 cm, 1 mm/s)
and finite burns: the default `rvd-run` set-up. Safety is judged on the truth by rvd_pil.host_sim.safety.

Runs are independent processes on `--jobs` local cores; each run's record lives in DIR/runs/<start>-<seed>
and a finished record is reused, so an interrupted study resumes where it stopped (a record left
unfinished by a kill is run again). The output folder belongs to one set-up: a different one is refused.

Prints, per start, the Δv and final time mean and spread across the noise seeds, the success rate, the
safety violations per limit and the worst figures (docking-cone excursion, |v|inf in docking, closest
axial distance in the approach phase), the approach phase's infeasible QPs, and the dissertation's
ch. 5 figures beside ours (the average across starts of the standard deviation over noise repeats:
4.25 m/s in Δv and 19.54 min in t_f, from 100 starts x 60 repeats). Figures, not pass/fail.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import shlex
import shutil
import sys
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

import numpy as np

DISSERTATION_CH5 = {"dv_std_mean_mps": 4.25, "tf_std_mean_min": 19.536}


def run_one(start: int, seed: int, run_dir: str, flight_exe: str | None, flight_args: tuple = (),
            base: str = "case1_vbar") -> dict:
    """One run (in a worker process); returns its row."""
    from rvd_pil.host_sim import scenario
    from rvd_pil.host_sim.pil import run_pil
    from rvd_pil.host_sim.server import ServerConfig

    path = Path(run_dir)
    if path.exists():
        shutil.rmtree(path)  # an unfinished record of a killed run
    cfg = ServerConfig(delay_model="none")
    summary, _ = run_pil(scenario.random_scenario(start, base), seed=seed, truth="nonlinear", sensor_noise=True,
                         thrust_noise=True, impulsive=False, flight_exe=flight_exe, flight_args=list(flight_args),
                         config=cfg, run_dir=path)
    return row_of(path)


def row_of(run_dir: Path) -> dict:
    """The figures of one finished run record."""
    from rvd_pil.host_sim.record import load_run

    meta, steps = load_run(run_dir)
    safety = meta.get("safety") or {}
    per = safety.get("per_limit", {})
    fig = safety.get("figures", {})
    approach = steps[steps["phase"] == 2] if "phase" in steps else steps.iloc[0:0]
    return {
        "run": run_dir.name, "start": meta["scenario_name"], "seed": meta["seed"], "end": meta.get("end"),
        "docked": bool(meta.get("docked")), "dv_mps": meta.get("dv_total_mps"), "tf_s": meta.get("t_end_s"),
        "verdict": safety.get("verdict"), "violations": safety.get("violations"),
        **{f"v_{name}": st["violations"] for name, st in per.items()},
        "initial_violations": safety.get("initial_violations", 0),
        "dock_cone_excursion_m": fig.get("max_docking_cone_excursion_m"),
        "dock_speed_inf_mps": fig.get("max_speed_inf_docking_mps"),
        "min_axial_approach_m": fig.get("min_axial_distance_approach_m"),
        "min_range_outside_corridor_m": fig.get("min_range_outside_corridor_m"),
        "approach_infeasible": int((approach["solver_status"] == 2).sum()) if len(approach) else 0,
        "approach_solves": int(len(approach)),
        "recovered": int((steps["guidance_status"] == 5).sum()) if "guidance_status" in steps else 0,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m rvd_pil.bench.safety_mc", description=__doc__.split("\n\n")[0])
    ap.add_argument("--starts", type=int, default=100, help="random starts random:1..N (default 100)")
    ap.add_argument("--noise-seeds", type=int, default=3, help="noise seeds per start (default 3)")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="parallel runs (default: all cores)")
    ap.add_argument("--out", default="reports/safety_mc", help="output folder (default reports/safety_mc)")
    ap.add_argument("--flight-sw", default=None, help="flight executable (default build/native)")
    ap.add_argument("--flight-args", default="", help='extra flight options, e.g. "--margins off" (an ablation)')
    ap.add_argument("--base", default="case1_vbar",
                    help="the scenario whose target, vehicles and orbit the random starts keep (default case1_vbar; "
                         "case3_rotating: a target turning at 0.15 deg/s)")
    args = ap.parse_args(argv)
    if args.starts < 1 or args.noise_seeds < 1 or args.jobs < 1:
        print("safety_mc: --starts, --noise-seeds and --jobs must be >= 1", file=sys.stderr)
        return 2
    from rvd_pil.host_sim import scenario
    from rvd_pil.host_sim.pil import find_flight_executable

    try:
        scenario.load(args.base)
    except scenario.ScenarioError as exc:  # a name or path that is no scenario: say so before any run starts
        print(f"safety_mc: --base {args.base}: {exc}", file=sys.stderr)
        return 2

    exe = str(find_flight_executable(args.flight_sw))
    out = Path(args.out)
    flight_args = tuple(shlex.split(args.flight_args))
    setup = {"kind": "rvd-pil safety Monte Carlo 1", "truth": "nonlinear", "noise": "sensor+thrust",
             "burns": "finite", "delay": "none", "flight_args": list(flight_args)}
    if args.base != "case1_vbar":  # (the earlier set-up files, all of case1_vbar, stay valid)
        setup["base"] = args.base
    setup_file = out / "setup.json"
    if setup_file.exists() and json.loads(setup_file.read_text()) != setup:
        print(f"safety_mc: {out} holds another set-up ({setup_file}); choose another --out", file=sys.stderr)
        return 2
    (out / "runs").mkdir(parents=True, exist_ok=True)
    setup_file.write_text(json.dumps(setup, indent=2) + "\n")

    todo, rows = [], []
    for start in range(1, args.starts + 1):
        for seed in range(args.noise_seeds):
            run_dir = out / "runs" / f"random_{start}-seed_{seed}"
            meta = run_dir / "meta.json"
            if meta.is_file() and json.loads(meta.read_text()).get("status") == "finished":
                rows.append(row_of(run_dir))
            else:
                todo.append((start, seed, str(run_dir)))
    print(f"safety_mc: {len(rows)} runs reused, {len(todo)} to run on {args.jobs} process(es)", file=sys.stderr)
    t0 = time.monotonic()
    done = 0
    # Spawned workers, not forked: a fork of a process with threads running (a Zenoh session's, when
    # the study is started from a process that flew runs before) can inherit a lock held mid-call and hang.
    with ProcessPoolExecutor(max_workers=args.jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        pending = {pool.submit(run_one, s, k, d, exe, flight_args, args.base) for s, k, d in todo}
        try:
            while pending:
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for f in finished:
                    rows.append(f.result())
                    done += 1
                rate = done / max(time.monotonic() - t0, 1e-9)
                eta = (len(todo) - done) / rate if rate > 0 else float("nan")
                print(f"\r  {done}/{len(todo)} runs  {rate * 3600:.0f} runs/h  ETA {eta / 60:.1f} min",
                      end="", file=sys.stderr, flush=True)
        except KeyboardInterrupt:
            for f in pending:
                f.cancel()
            print("\nsafety_mc: interrupted; finished runs are kept, run again to resume", file=sys.stderr)
            return 130
    print(file=sys.stderr)
    report(rows, out)
    return 0


def report(rows: list[dict], out: Path) -> None:
    import pandas as pd

    df = pd.DataFrame(rows).sort_values(["start", "seed"])
    df.to_csv(out / "runs.csv", index=False)
    per_start = df.groupby("start").agg(runs=("run", "size"), docked=("docked", "sum"),
                                        dv_mean=("dv_mps", "mean"), dv_std=("dv_mps", "std"),
                                        tf_mean_min=("tf_s", lambda s: s.mean() / 60), tf_std_min=("tf_s", lambda s: s.std() / 60),
                                        violations=("violations", "sum"))
    per_start.to_csv(out / "per_start.csv")
    n = len(df)
    limits = [c for c in df.columns if c.startswith("v_")]
    print(f"runs: {n}, starts: {df['start'].nunique()}, docked {int(df['docked'].sum())}/{n} "
          f"({100 * df['docked'].mean():.1f} %), safe {int((df['verdict'] == 'safe').sum())}/{n}, "
          f"unsafe {int((df['verdict'] == 'unsafe').sum())}/{n}")
    started = df[df["verdict"] == "started_unsafe"]
    if len(started):
        print(f"started unsafe (the random initial state is inside a limit, e.g. the keep-out sphere; the guidance "
              f"added no violation): {len(started)} runs of starts {sorted(started['start'].unique())}")
    print("violations per limit (runs with at least one / total episodes):")
    for c in limits:
        print(f"  {c[2:]:<18} {int((df[c] > 0).sum()):4d} runs  {int(df[c].sum()):5d} episodes")
    def worst(col, fn):
        s = df[col].dropna()
        return fn(s) if len(s) else float("nan")
    print(f"worst docking-cone excursion in truth: {100 * worst('dock_cone_excursion_m', np.max):+.2f} cm "
          f"(positive = outside; median run {100 * worst('dock_cone_excursion_m', np.median):+.2f} cm)")
    print(f"max |v|inf in docking: {1000 * worst('dock_speed_inf_mps', np.max):.2f} mm/s (v_max 100 mm/s)")
    print(f"closest axial distance in approach: {worst('min_axial_approach_m', np.min):.3f} m (r2 30 m)")
    print(f"approach QPs infeasible: {int(df['approach_infeasible'].sum())} of {int(df['approach_solves'].sum())} "
          f"({100 * df['approach_infeasible'].sum() / max(df['approach_solves'].sum(), 1):.2f} %); "
          f"recovered steps (all phases): {int(df['recovered'].sum())}")
    print(f"delta-v: mean {df['dv_mps'].mean():.2f} m/s; t_f mean {df['tf_s'].mean() / 60:.1f} min")
    if df.groupby("start").size().min() > 1:
        print(f"spread across noise seeds, averaged over starts (dissertation ch. 5 in brackets): "
              f"delta-v std {per_start['dv_std'].mean():.2f} m/s [{DISSERTATION_CH5['dv_std_mean_mps']}], "
              f"t_f std {per_start['tf_std_min'].mean():.2f} min [{DISSERTATION_CH5['tf_std_mean_min']}]")
    print(f"tables: {out / 'runs.csv'}, {out / 'per_start.csv'}")


if __name__ == "__main__":
    sys.exit(main())
