"""The 2-D scenarios of Dong, Ghiglino et al., "Fast model predictive control with moving obstacle
avoidance" (test cases A and B, Table 2: the SPOT air-bearing table), flown through the PIL harness
(rvd-run's run_pil: host_sim's planar truth over Zenoh against the native flight executable), with and
without their obstacles, ideal and disturbed; our figures beside what the paper states.

    python -m rvd_pil.bench.obstacles_dong2d [--cases a,b] [--seeds 1]

Ideal: the planar truth without noise, impulsive burns, no control delay. Disturbed: sensor noise
(1 mm, 1 mm/s, 0.1 deg, 0.1 deg/s), the Gauss-Markov thrust error, finite burns and the flight
computer's step time as control delay (rvd-run's default set-up). Total impulse = m sum |dv|_2 over
the periods (and the 1-norm an axis-thruster set burns); the torque impulse = sum |tau| Ts.
The paper gives trajectories (Figs. 6, 7) and the solvers' mean computation times (Fig. 5), no
numbers for the 2-D runs; it states that every solver docks, with and without the obstacles, and that
with obstacles its custom solvers (ISNM, Fast MPC) command the lowest total impulse.
"""
from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

import numpy as np

from rvd_pil.host_sim import scenario
from rvd_pil.host_sim.pil import run_pil
from rvd_pil.host_sim.record import load_run
from rvd_pil.host_sim.server import ServerConfig

PUBLISHED = ("published (Figs. 5-7, no values in the text): every solver docks with and without the obstacles; "
             "with them the custom solvers command the lowest total impulse")


def fly(sc, *, ideal: bool, seed: int, out: Path) -> dict:
    cfg = ServerConfig(delay_model="none" if ideal else "reported")
    summary, run_dir = run_pil(sc, seed=seed, truth="planar", sensor_noise=not ideal, thrust_noise=not ideal,
                               impulsive=ideal, config=cfg, run_dir=out / f"{sc.name}-{'ideal' if ideal else f'seed{seed}'}")
    meta, steps = load_run(run_dir)
    mass = sc.chaser.mass_kg
    dv = steps[["dv_x_mps", "dv_y_mps", "dv_z_mps"]].to_numpy(dtype=float)
    dv = dv[np.isfinite(dv).all(axis=1)]
    torque = steps["torque_z_nm"].to_numpy(dtype=float) if "torque_z_nm" in steps else np.zeros(0)
    period = steps["period_s"].to_numpy(dtype=float)
    ok = np.isfinite(torque) & np.isfinite(period)
    solve = steps["solve_time_us"].to_numpy(dtype=float)
    solve = solve[np.isfinite(solve) & (solve > 0)]
    law = run_dir / "law_values.csv"
    radius = np.nan
    if law.exists():
        import pandas as pd

        v = pd.read_csv(law)
        r = v[v["name"] == "holding_radius_m"]["value"]
        radius = float(r.min()) if len(r) else np.nan
    fig = summary.safety.get("figures", {})
    clear = {i: o["min_clearance"] for i, o in (fig.get("obstacles") or {}).items()}
    return {"end": summary.end, "docked": summary.docked, "t_s": summary.t_s, "verdict": summary.safety.get("verdict"),
            "impulse2_Ns": mass * float(np.linalg.norm(dv, axis=1).sum()), "impulse1_Ns": mass * float(np.abs(dv).sum()),
            "torque_impulse_Nms": float(np.sum(np.abs(torque[ok]) * period[ok])), "clearance": clear,
            "contact": fig.get("contact"), "solve_us": solve, "run_dir": run_dir, "holding_min_m": radius}


def line(label: str, r: dict) -> str:
    c = ", ".join(f"obstacle {i} {v:.3f}" for i, v in r["clearance"].items()) or "no obstacles"
    contact = r["contact"]
    at = (f"; at contact {100 * contact['lateral_offset_m']:.1f} cm off the axis, {1000 * contact['relative_speed_mps']:.1f} "
          "mm/s" if contact else "")
    s = r["solve_us"]
    times = f"; solve median {np.median(s) / 1e3:.2f} ms, max {s.max() / 1e3:.2f} ms" if len(s) else ""
    return (f"  {label:<36} {r['end']} at t = {r['t_s']:.0f} s, safety {r['verdict']}, holding radius down to "
            f"{r['holding_min_m']:.3f} m; total impulse "
            f"{r['impulse2_Ns']:.3f} N s (1-norm {r['impulse1_Ns']:.3f}), torque impulse {r['torque_impulse_Nms']:.4f} "
            f"N m s; min clearance in truth {c}{at}{times}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", default="a,b")
    ap.add_argument("--seeds", type=int, default=1, help="disturbed runs per case (noise seeds 1..N)")
    ap.add_argument("--out", default=None, help="run records here (default: a temporary folder)")
    args = ap.parse_args(argv)
    print(PUBLISHED)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out) if args.out else Path(tmp)
        for case in args.cases.split(","):
            sc = scenario.load(f"dong_2d_case_{case.strip().lower()}")
            print(f"test case {case.strip().upper()} ({sc.description})")
            for with_obstacles in (False, True):
                s = sc if with_obstacles else sc.replace(obstacles=(), name=f"{sc.name}_free")
                what = "with obstacles" if with_obstacles else "without obstacles"
                print(line(f"{what}, ideal", fly(s, ideal=True, seed=0, out=out)))
                for seed in range(1, args.seeds + 1):
                    print(line(f"{what}, disturbed seed {seed}", fly(s, ideal=False, seed=seed, out=out)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
