"""Solver work per guidance step in noisy in-process closed loops: `flight_sw.Guidance` against the
impulsive CW plant (Case 3's target turning at its spin rate), with Gaussian noise on the state it
is given (position sigma noise_scale x (0.2 m + 0.2 % of the range), velocity sigma noise_scale x
2 mm/s) and a per-axis thrust error on every commanded delta-v. Cases 1-3 of the dissertation,
`--seeds` seeds each, at the three horizon sets. Per horizon: the warm solves' mean, median, p99
and max work, the first (cold) solve's mean / max, and the solves of 13 or more; then the work in
all. The work is the rendezvous' interior-point iterations (`--phase rendezvous`, the default) or
the docking active set's row changes (`--phase docking`, the loop flown until docked).
Prints figures; asserts nothing.

    python -m rvd_pil.bench.noisy_loops                                   # noise 0.02, thrust error 3 %
    python -m rvd_pil.bench.noisy_loops --noise-scale 0.1 --thrust-error 0 --seeds 6 --show-above 20
    python -m rvd_pil.bench.noisy_loops --phase docking --seeds 4
"""
from __future__ import annotations

import argparse

import numpy as np

from rvd_pil import flight_sw as fsw
from rvd_pil.host_sim.frames import quaternion_after

HORIZON_SETS = ((15, 5, 5), (30, 15, 12), (45, 30, 30))


def noisy_loop(case: int, horizons: tuple[int, int, int], seed: int, noise_scale: float, thrust_error: float,
               max_steps: int = 600):
    """One seeded loop, step by step: yields (step, guidance, command) until docked or max_steps. The
    same arguments fly the same loop (the noise is seeded; the guidance is deterministic)."""
    rng = np.random.default_rng(seed)
    p = fsw.GuidanceParams()
    p.rendezvous.N, p.approach.N, p.docking.N = horizons
    g = fsw.Guidance(p)
    c = fsw.dissertation_case(case)
    x, t, n = np.array(c["x0"], float), 0.0, p.mean_motion_rad_s()
    for k in range(max_steps):
        rho = np.linalg.norm(x[:3])
        seen = x + np.r_[rng.normal(0.0, noise_scale * (0.2 + 0.002 * rho), 3), rng.normal(0.0, noise_scale * 0.002, 3)]
        q = quaternion_after(c["q_lvlh_body"], c["omega_body_rad_s"], t)  # a spinning target turns as time goes on
        cmd = g.step(fsw.NavInput(k, t, seen, q, c["omega_body_rad_s"]))
        if cmd.status == fsw.StepStatus.Docked:
            return
        yield k, g, cmd
        dv = np.asarray(cmd.dv_cmd_mps) * (1.0 + rng.normal(0.0, thrust_error, 3))
        x = fsw.cw_stm(n, cmd.period_s) @ (x + np.r_[0.0, 0.0, 0.0, dv])
        t += cmd.period_s


def phase_work(case: int, horizons: tuple[int, int, int], seed: int, noise_scale: float, thrust_error: float,
               phase: str, max_steps: int = 600) -> list[tuple[int, int, str]]:
    """(step, work, guidance status) of every step of `phase` in one loop: interior-point iterations in
    the rendezvous, active-set row changes in docking."""
    want = fsw.Phase.Rendezvous if phase == "rendezvous" else fsw.Phase.Docking
    out = []
    for k, _, cmd in noisy_loop(case, horizons, seed, noise_scale, thrust_error, max_steps):
        if want == fsw.Phase.Rendezvous and cmd.phase != want:
            break
        if cmd.phase == want:
            work = cmd.iterations if want == fsw.Phase.Rendezvous else cmd.active_set_changes
            out.append((k, work, str(cmd.status).split(".")[-1]))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--noise-scale", type=float, default=0.02, help="sensor noise scale (default 0.02)")
    ap.add_argument("--thrust-error", type=float, default=0.03, help="per-axis thrust error sigma, fraction (default 0.03)")
    ap.add_argument("--seeds", type=int, default=6, help="seeds per case and horizon set (default 6)")
    ap.add_argument("--show-above", type=int, default=0, help="list every solve of more work than this")
    ap.add_argument("--phase", choices=("rendezvous", "docking"), default="rendezvous",
                    help="rendezvous: interior-point iterations (default); docking: active-set row changes")
    a = ap.parse_args(argv)
    if a.noise_scale < 0 or a.thrust_error < 0 or a.seeds < 1:
        ap.error("--noise-scale and --thrust-error must be >= 0, --seeds >= 1")
    unit = "iterations" if a.phase == "rendezvous" else "row changes"
    print(f"{a.phase} {unit}; noise scale {a.noise_scale}, thrust error {a.thrust_error:.0%}, Cases 1-3 x {a.seeds} seeds")
    total = 0
    for hz in HORIZON_SETS:
        n_phase = hz[0] if a.phase == "rendezvous" else hz[2]
        warm, first = [], []
        for case in (1, 2, 3):
            for seed in range(a.seeds):
                steps = phase_work(case, hz, seed, a.noise_scale, a.thrust_error, a.phase)
                if not steps:
                    print(f"  case {case} N {n_phase} seed {seed}: no {a.phase} step")
                    continue
                total += sum(it for _, it, _ in steps)
                first.append(steps[0][1])
                warm += [it for _, it, _ in steps[1:]]
                for k, it, status in steps:
                    if a.show_above and it > a.show_above:
                        print(f"  case {case} N {n_phase} seed {seed} step {k}: {it} {unit} ({status})")
        w = np.array(warm)
        print(f"N {n_phase:2d}: warm mean {w.mean():.2f}, median {np.median(w):.0f}, p99 {np.percentile(w, 99):.0f}, "
              f"max {w.max()}; first {np.mean(first):.1f} / {max(first)}; >= 13: {(w >= 13).sum()} of {len(w)}")
    print(f"{unit} in all: {total}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
