"""Can a start stay out of the keep-out sphere at all? The best any guidance could do, for a few starts.

    python -m rvd_pil.bench.keepout_reachability                 # random:226 and random:492 (ch. 4 study)
    python -m rvd_pil.bench.keepout_reachability --starts 34,83 --periods 10

For each seeded random start (the ch. 4 distribution, rvd_pil.host_sim.scenario.random_scenario): the CW
motion from its initial state with one impulse per rendezvous period, each within the phase's input box
(|dv|inf <= u_max, Table 3.1), chosen to maximise the least distance to the target's centre over the first
periods (sampled 15 times per period). A local optimiser (SLSQP) from several random initial guesses, so
the figure is a lower bound of the best achievable least range (found, not proven optimal): well below r1,
no guidance is likely to keep this start outside the sphere (it may still enter inside the approach
corridor, which the monitor allows). Prints
figures; asserts nothing.
"""
from __future__ import annotations

import argparse

import numpy as np
from scipy.optimize import minimize

from rvd_pil import flight_sw
from rvd_pil.host_sim import scenario
from rvd_pil.host_sim.cw import cw_stm


def best_least_range(x0: np.ndarray, n: float, u_max: float, period_s: float, periods: int, guesses: int) -> float:
    steps = [cw_stm(n, t) for t in np.linspace(0.0, period_s, 16)[1:]]

    def ranges(u: np.ndarray) -> np.ndarray:
        x, out = x0.copy(), [np.linalg.norm(x0[:3])]
        for k in range(periods):
            x = x.copy()
            x[3:] += u[3 * k:3 * k + 3]
            out.extend(np.linalg.norm((p @ x)[:3]) for p in steps)
            x = steps[-1] @ x
        return np.array(out)

    best = -np.inf
    for g in range(guesses):
        z0 = np.concatenate((np.random.default_rng(g).uniform(-u_max, u_max, 3 * periods), [0.0]))
        res = minimize(lambda z: -z[-1], z0, method="SLSQP", options={"maxiter": 300},
                       bounds=[(-u_max, u_max)] * (3 * periods) + [(0.0, None)],
                       constraints=[{"type": "ineq", "fun": lambda z: ranges(z[:-1]) - z[-1]}])
        best = max(best, float(ranges(res.x[:-1]).min()))
    return best


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--starts", default="226,492", help="comma-separated random start seeds")
    ap.add_argument("--periods", type=int, default=8, help="rendezvous periods looked at")
    ap.add_argument("--guesses", type=int, default=12, help="random initial guesses per start")
    args = ap.parse_args(argv)
    p = flight_sw.GuidanceParams()
    u_max, period_s, r1 = p.rendezvous.u_max_mps, p.rendezvous.Ts_s, p.keepout_radius_m
    print(f"input box |dv|inf <= {u_max} m/s per {period_s:g} s period, keep-out radius r1 = {r1:g} m")
    for seed in (int(s) for s in args.starts.split(",")):
        s = scenario.random_scenario(seed)
        x0 = np.concatenate((s.chaser.position_lvlh_m, s.chaser.velocity_lvlh_mps))
        best = best_least_range(x0, s.orbit.mean_motion_rad_s, u_max, period_s, args.periods, args.guesses)
        verdict = "no input sequence found that stays outside r1" if best < r1 else "stays outside r1"
        print(f"random:{seed}: start {np.linalg.norm(x0[:3]):.1f} m at {np.linalg.norm(x0[3:]):.2f} m/s; best least "
              f"range over {args.periods * period_s:g} s {best:.1f} m: {verdict}")


if __name__ == "__main__":
    main()
