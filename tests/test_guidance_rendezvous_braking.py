"""The rendezvous braking curve: a short rendezvous horizon must not close on the keep-out sphere faster
than the chaser can still stop before it.

A 15-stage rendezvous (Ts 30 s) sees 450 s ahead. While its keep-out planes still turn ahead of the
chaser the plan can slide round them at speed; once the chaser's direction meets the docking axis the
planes stop turning and the braking distance has to fit. Random start 136 round the turning target
(Case 3's target, vehicles and orbit) closed at 2.9 m/s, met infeasible phase QPs for 12 periods and
ended 25 m inside the sphere, under the dissertation's disturbances.
"""
import numpy as np

from rvd_pil import flight_sw as fsw
from rvd_pil.host_sim import scenario
from rvd_pil.host_sim.pil import run_pil
from rvd_pil.host_sim.record import load_run
from rvd_pil.host_sim.server import GUIDANCE_STATUS, ServerConfig
from support.qp_forms import from_dict, solve_clarabel

DISTURBED = dict(truth="nonlinear", sensor_noise=True, thrust_noise=True, impulsive=False)
SHORT_RENDEZVOUS = ("--horizon", "15,5,5")
RECOVERED = next(k for k, name in GUIDANCE_STATUS.items() if name == "recovered")  # the phase QP was infeasible


def rendezvous_plan(fraction, x0, N=15):
    """The rendezvous QP at x0 (a still target, body x along LVLH +y) with the curve at `fraction`
    of the braking authority, and its planned states: (qp, states)."""
    p = fsw.GuidanceParams()
    p.rendezvous.N = N
    p.margins.rendezvous_brake_fraction = fraction
    b = fsw.PhaseQp(fsw.Phase.Rendezvous, p)
    q = np.array([np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])  # body x -> LVLH +y
    qp = b.build(np.asarray(x0, float), q)
    r = fsw.solve_ocp_qp(**qp, tol=1e-9, max_iter=200)
    assert r.status == "solved", r.status
    return qp, np.asarray(r.x)


def stop_distance_m(closing_mps, dv_per_period_mps, ts_s):
    """How far a chaser closing at c travels when it brakes by dv every period of ts (impulsive, a
    decrement at each sample): ts (c^2 / 2 dv + c / 2) for the last partial period included."""
    c = max(closing_mps, 0.0)
    return ts_s * (c * c / (2.0 * dv_per_period_mps) + c / 2.0)


def test_the_rendezvous_plan_closes_on_each_keep_out_plane_no_faster_than_it_can_stop_before_it():
    """1000 m out on the docking axis, closing at 2.5 m/s. With the curve at 75 %, at every planned stage
    the chaser can still stop before that stage's keep-out plane braking at 75 % of the largest delta-v per
    period the input box allows along the plane's normal, or it closes slowly enough to stop within half
    the horizon (where the plan sees the whole braking and its keep-out rows hold it). Without the curve
    the plan closes faster than even all of the authority can stop, beyond what the horizon shows."""
    x0 = [0.0, 1000.0, 0.0, 0.0, -2.5, 0.0]
    ts = fsw.GuidanceParams().rendezvous.Ts_s
    for fraction, must_stop in ((0.75, True), (0.0, False)):
        qp, x = rendezvous_plan(fraction, x0)
        C, d = qp["C"], qp["d"]
        N = len(C) - 1
        u_box = np.asarray(qp["d"][1])[:3]  # the box's upper bounds on stage 1's inputs (symmetric box)
        overrun = []
        for i in range(1, N + 1):
            row = 6 if i < N else 0  # the keep-out plane: n' rho >= r, written -n' rho <= -r
            n = -np.asarray(C[i])[row, :3]
            r = -float(np.asarray(d[i])[row])
            assert abs(np.linalg.norm(n) - 1.0) < 1e-9
            closing, distance = -n @ x[i, 3:], n @ x[i, :3] - r
            assert distance >= -1e-6  # the plan keeps the plane itself
            authority = np.min(u_box / np.maximum(np.abs(n), 1e-12))  # pure braking along n within the box
            braking = 0.75 * authority if must_stop else authority  # without the curve: all of it
            seen_whole = closing <= 0.5 * N * braking + 1e-9  # stops within half the horizon
            overrun.append(0.0 if must_stop and seen_whole else stop_distance_m(closing, braking, ts) - distance)
        if must_stop:
            assert max(overrun) <= 1e-6, overrun
        else:
            assert max(overrun) > 10.0, overrun  # metres past the plane before it could stop


def disturbed_run(tmp_path, start, flight_args=()):
    scen = scenario.random_scenario(start, "case3_rotating")
    return run_pil(scen, seed=0, **DISTURBED, config=ServerConfig(delay_model="none"),
                   run_dir=tmp_path / f"{scen.name}-{len(flight_args)}", flight_args=list(SHORT_RENDEZVOUS + flight_args))


def assert_docked_safely(summary):
    assert summary.end == "docked", summary.end
    violated = {name: st for name, st in summary.safety["per_limit"].items() if st["violations"]}
    assert summary.safety["verdict"] == "safe" and not violated, violated


def test_a_fast_closing_rendezvous_at_a_short_horizon_brakes_before_the_keep_out_sphere(tmp_path, flight_exe):
    """Random start 136 round the turning target at 15 / 5 / 5, disturbed (nonlinear truth with J2 and drag,
    sensor noise, thrust error, finite burns), native flight executable over Zenoh, judged on the truth.
    With the curve it docks safely and every rendezvous QP is feasible; with the curve off the same run
    meets infeasible rendezvous QPs and the monitor finds the chaser inside the keep-out sphere."""
    summary, run_dir = disturbed_run(tmp_path, 136)
    assert_docked_safely(summary)
    _, steps = load_run(run_dir)
    rendezvous = steps[steps["phase"] == 1]
    assert len(rendezvous) > 20
    assert int((rendezvous["guidance_status"] == RECOVERED).sum()) == 0

    summary, run_dir = disturbed_run(tmp_path, 136, ("--set", "margins.rendezvous_brake_fraction=0"))
    assert summary.safety["per_limit"]["keepout"]["violations"] > 0
    _, steps = load_run(run_dir)
    assert int(((steps["phase"] == 1) & (steps["guidance_status"] == RECOVERED)).sum()) > 0


def test_the_braking_curve_does_not_hold_a_far_chaser_off(tmp_path, flight_exe):
    """Random start 166 (2.4 km out) with the same curve bounded by each plane's distance from the chaser
    now instead of the range: a plane turned far ahead lies close to the chaser's position, its row forbade
    closing on it, and the plan pushed away from the target for good (480 km after 12000 s). Bounded by the
    range, it docks."""
    summary, _ = disturbed_run(tmp_path, 166)
    assert_docked_safely(summary)


def test_the_interior_point_solves_rendezvous_qps_whose_closing_speed_rows_hold_on_many_stages():
    """With the braking curve the closing-speed rows hold on up to 14 of 15 stages at once, with multipliers
    of 1e4-1e6 and costates as large. The interior point measured its dual residual against the cost
    gradient alone (1e3 here): rounding in terms a thousand times larger kept it above 1e-8 of that while
    the gap shrank, until the barrier weights (1e19) broke the factorisation (numerical_error, the guidance
    then flies the shifted plan). In-process closed loops (CW plant, the disturbed margins) that met it:
    every rendezvous QP solved cold by the interior point must match Clarabel, and no step of the loops
    may end in numerical_error."""
    p = fsw.GuidanceParams()
    p.rendezvous.N, p.approach.N, p.docking.N = 15, 5, 5
    e = fsw.ErrorModel()
    e.sigma_position_m, e.sigma_velocity_mps, e.thrust_error_sigma = 0.05, 0.001, 0.0462
    p.margins = fsw.derive_margins(e, p)
    many_tight = 0
    for base, start in (("case1_vbar", 49), ("case3_rotating", 137)):
        scen = scenario.random_scenario(start, base)
        x0 = np.r_[scen.chaser.position_lvlh_m, scen.chaser.velocity_lvlh_mps]
        half = np.deg2rad(scen.target.initial_angle_deg) / 2
        q = [np.cos(half), 0.0, 0.0, np.sin(half)]
        w = [0.0, 0.0, np.deg2rad(scen.target.spin_rate_deg_s)]
        r = fsw.run_closed_loop(p, x0, q, w, record_qps=True)
        assert r.docked, r.reason
        assert "numerical_error" not in set(r.solver_status)
        for rec in r.qps:
            if rec["phase"] != fsw.Phase.Rendezvous:
                continue
            qp = from_dict(rec["qp"], "rendezvous")
            ours = fsw.solve_ocp_qp(*qp.args(), **qp.kw(), mode="interior_point")
            assert ours.status == "solved", (base, start, rec["step"], ours.status)
            reference = solve_clarabel(qp)
            assert reference.status == "solved", (base, start, rec["step"], reference.status)
            assert abs(ours.objective - reference.objective) <= 1e-7 * abs(reference.objective), (base, start, rec["step"])
            # stages beyond the first whose non-box rows (keep-out plane, closing speed) carry > 1e4
            tight = sum(1 for lam in ours.lam[1:] if len(lam) > 6 and np.max(np.abs(lam[6:])) > 1e4)
            many_tight += tight >= 10
    assert many_tight >= 10  # the loops do reach the regime this is about
