"""flight_sw's Fast MPC solver from Python, against ProxSuite and against constructions whose answer
is known (reachability LPs, barrier theory). QPs are MPC-like: CW dynamics, nx = 6, 3 thrust inputs
plus slack inputs, box and halfspace rows, horizons 5..45."""
import math
import re
from pathlib import Path

import numpy as np
import pytest

from rvd_pil import flight_sw
from rvd_pil.bench.noisy_loops import noisy_loop
from support.qp_forms import (
    PHASES, OcpQpData, approach_qp, docking_qp, from_dict, load_qp_set, random_mpc_qp, rendezvous_qp,
    save_qp_set, solve_clarabel, solve_proxsuite, with_reach_row)

GENERATORS = {"random": random_mpc_qp, **PHASES}


def make(phase: str, N: int, seed: int) -> OcpQpData:
    return GENERATORS[phase](N, np.random.default_rng(seed))


def reference(qp: OcpQpData):
    """ProxSuite at eps_abs 1e-10; on the few QPs where it cannot get there within its iteration
    cap, at 1e-9, then 1e-8 (the objective comparison tolerance, 1e-6 relative, covers these)."""
    for eps in (1e-10, 1e-9, 1e-8):
        ref = solve_proxsuite(qp, eps_abs=eps, max_iter=20000)
        if ref.status in ("solved", "infeasible"):
            return ref
    return ref


def min_slack(qp: OcpQpData, x, u) -> float:
    return min(float(np.min(qp.d[i] - qp.C[i] @ x[i] - qp.D[i] @ u[i])) for i in range(qp.N + 1) if qp.nc[i])


@pytest.mark.parametrize("N", [5, 15, 30, 45])
@pytest.mark.parametrize("phase", list(GENERATORS))
def test_converged_matches_proxsuite(phase, N):
    for seed in (N, N + 100):
        qp = make(phase, N, seed)
        ref = reference(qp)
        res = flight_sw.solve_ocp_qp(*qp.args(), **qp.kw(), tol=1e-8)
        assert res.status == ref.status, f"seed {seed}: ours {res.status}, ProxSuite {ref.status}"
        if ref.status != "solved":
            continue
        assert abs(res.objective - ref.objective) <= 1e-6 * max(1.0, abs(ref.objective))
        assert qp.violation(res.x, res.u) <= 1e-7
        assert res.objective == pytest.approx(qp.objective(res.x, res.u), rel=1e-12, abs=1e-9)
        assert res.primal_residual <= 1e-7
        assert res.iterations <= 40


@pytest.mark.parametrize("N", [5, 30])
@pytest.mark.parametrize("phase", list(GENERATORS))
def test_infeasibility_verdict(phase, N):
    """A row demanding more than the reachable set (found by an LP) by 1 unit makes the QP infeasible
    through the dynamics; 1 unit less keeps it feasible. ProxSuite's verdict (its default
    thresholds) on the infeasible ones and its objective on the feasible ones must agree with ours."""
    rng = np.random.default_rng(1000 + N)
    base = make(phase, N, 7 * N + 1)
    assert solve_proxsuite(base).status == "solved"
    stage = int(rng.integers(1, N + 1))
    direction = np.zeros(6)
    direction[int(rng.integers(0, 3))] = rng.choice([-1.0, 1.0])

    infeasible = with_reach_row(base, stage, direction, +1.0)
    assert solve_proxsuite(infeasible, eps_infeasible=1e-4, max_iter=20000).status == "infeasible"
    assert flight_sw.solve_ocp_qp(*infeasible.args(), **infeasible.kw()).status == "infeasible"
    assert flight_sw.solve_ocp_qp(*infeasible.args(), **infeasible.kw(), mode="fixed_barrier", max_iter=60).status == "infeasible"

    feasible = with_reach_row(base, stage, direction, -1.0)
    ref = reference(feasible)
    res = flight_sw.solve_ocp_qp(*feasible.args(), **feasible.kw())
    assert ref.status == res.status == "solved"
    assert abs(res.objective - ref.objective) <= 1e-6 * max(1.0, abs(ref.objective))


def test_violated_initial_state_row_is_infeasible_at_once():
    qp = docking_qp(12, np.random.default_rng(0))
    x0 = qp.x0.copy()
    x0[3] = 0.5  # radial speed above the 0.1 m/s bound: a stage-0 row of x0 alone
    res = flight_sw.solve_ocp_qp(*qp.args()[:-1], x0, **qp.kw())
    assert res.status == "infeasible" and res.iterations == 0


@pytest.mark.parametrize("kappa", [1e-2, 1e-4])
@pytest.mark.parametrize("phase", list(GENERATORS))
def test_fixed_barrier_within_barrier_bound(phase, kappa):
    """The exact minimiser of f - kappa sum log(d - Gz) on the dynamics has duality gap m kappa
    (m rows), so 0 <= f - f* <= m kappa; its iterates satisfy every row strictly."""
    qp = make(phase, 15, 42)
    ref = reference(qp)
    assert ref.status == "solved"
    res = flight_sw.solve_ocp_qp(*qp.args(), **qp.kw(), mode="fixed_barrier", barrier=kappa, max_iter=100)
    assert res.status == "solved"
    assert min_slack(qp, res.x, res.u) > 0.0
    assert res.primal_residual <= 1e-8  # dynamics; the inequalities hold strictly
    m = sum(qp.nc)
    slack = 1e-7 * max(1.0, abs(ref.objective))
    assert -slack <= res.objective - ref.objective <= m * kappa + slack


def closed_loop_iterations(qp: OcpQpData, mode: str, steps: int = 8, noise_m: float = 1e-3):
    """Iterations of a warm-started solver and of cold solves over a closed loop: the plant takes
    the plan's first thrust (plus a navigation error), the plan's tail is the next warm start."""
    rng = np.random.default_rng(5)
    solver = flight_sw.OcpSolver(qp.nx, qp.nu, qp.nc, qp.ns if qp.idxs else None, mode=mode, barrier=1e-3, max_iter=60)
    x = qp.x0.copy()
    warm = cold = 0
    for step in range(steps):
        args = qp.args()[:-1] + (x,)
        r = solver.solve(*args, **qp.kw())
        c = flight_sw.solve_ocp_qp(*args, **qp.kw(), mode=mode, barrier=1e-3, max_iter=60)
        assert r.status == c.status
        if r.status == "infeasible":  # the noisy plant left the docking cone: the loop ends
            break
        assert r.status == "solved"
        # Fixed barrier: both meet the barrier problem to tolerance; f may differ a little more
        # along weakly curved (slack) directions.
        assert r.objective == pytest.approx(c.objective, rel=1e-6 if mode == "interior_point" else 1e-5)
        if step > 0:
            warm += r.iterations
            cold += c.iterations
        x = qp.A[0] @ x + qp.B[0][:, :3] @ np.asarray(r.u[0])[:3]
        x[:3] += noise_m * rng.standard_normal(3)
        solver.shift_warm_start()
    return warm, cold


@pytest.mark.parametrize("mode", ["interior_point", "fixed_barrier"])
@pytest.mark.parametrize("phase", ["docking", "approach", "rendezvous"])
def test_warm_start_needs_fewer_iterations(phase, mode):
    """Summed over closed loops at horizons 5, 15 and 30 (two initial states each): single periods
    can go either way, the total must drop. (The interior point: the converged mode's active-set
    method on these sizes starts cold.)"""
    warm = cold = 0
    for N in (5, 15, 30):
        for seed in (N, N + 1):
            w, c = closed_loop_iterations(make(phase, N, seed), mode)
            warm += w
            cold += c
    assert warm < cold, (warm, cold)


def test_result_layout_and_reusable_solver():
    qp = rendezvous_qp(15, np.random.default_rng(2))
    res = flight_sw.solve_ocp_qp(*qp.args(), **qp.kw())
    assert res.status == "solved"
    assert res.x.shape == (16, 6) and np.array_equal(res.x[0], qp.x0)
    assert len(res.u) == 16 and res.u[15].shape == (0,) and res.u[3].shape == (3,)
    assert res.pi.shape == (15, 6) and len(res.lam) == 16
    # The terminal cone penalty is 4 soft rows: their slacks are the violations of H rho_N <= 0.
    H = qp.C[15][:4]
    assert len(res.s) == 16 and res.s[15].shape == (4,) and res.s[3].shape == (0,)
    np.testing.assert_allclose(res.s[15], np.maximum(H @ res.x[15], 0.0), atol=1e-6)
    assert res.solve_time_us > 0
    solver = flight_sw.OcpSolver(6, qp.nu, qp.nc, qp.ns if qp.idxs else None)
    assert solver.N == 15
    again = solver.solve(*qp.args(), **qp.kw())
    assert again.objective == pytest.approx(res.objective, rel=1e-12)
    docking = docking_qp(5, np.random.default_rng(0))
    assert flight_sw.solve_ocp_qp(*docking.args(), **docking.kw()).u[5].shape == (0,)


@pytest.mark.parametrize("mode", ["converged", "interior_point", "fixed_barrier"])
def test_solve_time_splits_into_update_iterations_and_output(mode):
    """Info's parts of the solve time add up to it, for every method (docking by the active set in
    converged mode); an input rejected before any iteration is all update."""
    qp = docking_qp(12, np.random.default_rng(4))
    solver = flight_sw.OcpSolver(6, qp.nu, qp.nc, qp.ns if qp.idxs else None, mode=mode, warm_start=False)
    for _ in range(3):
        res = solver.solve(*qp.args(), **qp.kw())
        assert res.status == "solved"
        assert (res.active_set_changes > 0) == (mode == "converged") and (res.iterations > 0) != (mode == "converged")
        parts = (res.update_time_us, res.iterate_time_us, res.output_time_us)
        assert min(parts) >= 0.0 and res.iterate_time_us > 0.0
        assert sum(parts) == pytest.approx(res.solve_time_us, rel=1e-9, abs=1e-9)
    x0 = qp.x0.copy()
    x0[2] = np.nan
    bad = solver.solve(*qp.args()[:-1], x0, **qp.kw())
    assert bad.status == "invalid_input"
    assert bad.iterate_time_us == 0.0 and bad.output_time_us == 0.0
    assert bad.update_time_us == bad.solve_time_us > 0.0


def stationarity_residual(qp: OcpQpData, res) -> float:
    """Inf-norm of the gradient of the Lagrangian at the returned iterate, written out here:
    R u + r + B'pi + D'lam (inputs), Q x + q + A'pi_i - pi_{i-1} + C'lam (states x_1..x_N)."""
    worst = 0.0
    for i in range(qp.N + 1):
        x, u, lam = np.asarray(res.x[i]), np.asarray(res.u[i]), np.asarray(res.lam[i])
        gu = qp.R[i] @ u + qp.r[i] + (qp.D[i].T @ lam if len(lam) else 0.0)
        gx = qp.Q[i] @ x + qp.q[i] + (qp.C[i].T @ lam if len(lam) else 0.0)
        if i < qp.N:
            gu = gu + qp.B[i].T @ res.pi[i]
            gx = gx + qp.A[i].T @ res.pi[i]
        if i > 0:
            worst = max(worst, float(np.abs(gx - res.pi[i - 1]).max()))
        if len(u):
            worst = max(worst, float(np.abs(gu).max()))
    return worst


@pytest.mark.parametrize("phase", ["docking", "approach", "rendezvous"])
def test_dual_residual_is_the_stationarity_of_the_returned_iterate(phase):
    """The reported dual residual equals the KKT stationarity recomputed from the returned x, u, pi
    and lambda, both far from the optimum (2 interior-point iterations) and at it (the active set's
    answer), where it is below the tolerance."""
    qp = make(phase, 10, 3)
    early = flight_sw.solve_ocp_qp(*qp.args(), **qp.kw(), max_iter=2, mode="interior_point")
    assert early.status == "max_iter"
    assert early.dual_residual == pytest.approx(stationarity_residual(qp, early), rel=1e-6)
    assert early.dual_residual > 1e-4  # two iterations are far from stationary: the figure measures something
    done = flight_sw.solve_ocp_qp(*qp.args(), **qp.kw(), tol=1e-8)
    assert done.status == "solved"
    scale = max(1.0, max(np.abs(r).max() for r in qp.q))
    assert stationarity_residual(qp, done) <= 1e-8 * scale
    # At the optimum both figures sit near the rounding floor, where two summation orders (ours and
    # numpy's BLAS) differ by rounding: 2.55e-11 against 2.18e-11 on this QP with one numpy build.
    assert done.dual_residual == pytest.approx(stationarity_residual(qp, done), rel=1e-3, abs=1e-11 * scale)


def test_nan_gives_invalid_input():
    qp = approach_qp(5, np.random.default_rng(1))
    qp.Q[2] = qp.Q[2].copy()
    qp.Q[2][1, 1] = np.nan
    assert flight_sw.solve_ocp_qp(*qp.args(), **qp.kw()).status == "invalid_input"
    x0 = qp.x0.copy()
    x0[0] = np.inf
    clean = approach_qp(5, np.random.default_rng(1))
    assert flight_sw.solve_ocp_qp(*clean.args()[:-1], x0, **clean.kw()).status == "invalid_input"


def test_shape_errors_raise_value_error():
    qp = docking_qp(5, np.random.default_rng(0))
    args = list(qp.args())
    bad_B = list(qp.B)
    bad_B[2] = np.zeros((6, 2))
    with pytest.raises(ValueError, match=r"D\[2\]|B\[2\]|R\[2\]"):
        flight_sw.solve_ocp_qp(*args[:1], bad_B, *args[2:])
    with pytest.raises(ValueError, match="N\\+1"):
        flight_sw.solve_ocp_qp(*args[:3], qp.Q[:-1], *args[4:])
    with pytest.raises(ValueError, match="x0"):
        flight_sw.solve_ocp_qp(*args[:-1], np.zeros(5))
    bad_d = list(qp.d)
    bad_d[1] = np.zeros(3)
    with pytest.raises(ValueError, match=r"d\[1\]"):
        flight_sw.solve_ocp_qp(*args[:9], bad_d, args[10])
    with pytest.raises(ValueError, match="mode"):
        flight_sw.solve_ocp_qp(*args, mode="fast")
    with pytest.raises(ValueError):
        flight_sw.solve_ocp_qp(*args[:1], [np.zeros((6, 3, 2))] * 5, *args[2:])
    solver = flight_sw.OcpSolver(6, qp.nu, qp.nc, qp.ns if qp.idxs else None)
    other = docking_qp(6, np.random.default_rng(0))
    with pytest.raises(ValueError, match="dimensions"):
        solver.solve(*other.args())


def test_back_solves_per_factorisation_stay_within_the_documented_bound():
    """The deadline monitor's bound (fast_mpc.hpp): at most 1 + (2 + max_correctors)(1 +
    max_refinements) back-solves per factorisation, 16 with the defaults (3 correctors, 2
    refinements), on the rendezvous QPs of two closed loops (Case 1 and Case 3, the rotating target),
    each solved cold and then warm from its own answer shifted one stage."""
    bound = 1 + (2 + 3) * (1 + 2)
    params = flight_sw.GuidanceParams()
    params.rendezvous.N, params.approach.N, params.docking.N = 30, 15, 12
    qps = []
    for case in (1, 3):
        c = flight_sw.dissertation_case(case)
        run = flight_sw.run_closed_loop(params, c["x0"], c["q_lvlh_body"], c["omega_body_rad_s"], record_qps=True)
        qps += [from_dict(rec["qp"], "rendezvous") for rec in run.qps if int(rec["phase"]) == 1]
    assert len(qps) >= 20
    worst = 0.0
    for qp in qps:
        solver = flight_sw.OcpSolver(6, qp.nu, qp.nc, qp.ns if qp.idxs else None, mode="interior_point")
        for _ in range(2):
            res = solver.solve(*qp.args(), **qp.kw())
            assert res.status in ("solved", "infeasible") and res.iterations > 0  # (the loops record infeasible ones too)
            assert res.back_solves <= bound * res.iterations
            worst = max(worst, res.back_solves / res.iterations)
            solver.shift_warm_start()
    assert worst > 2.0  # correctors or refinements ran somewhere: the bound was exercised


def test_time_limit_reports_time_limit():
    qp = random_mpc_qp(45, np.random.default_rng(3))
    res = flight_sw.solve_ocp_qp(*qp.args(), **qp.kw(), time_limit_us=1e-3)  # 1 ns: spent before the first check
    assert res.status == "time_limit"
    assert np.all(np.isfinite(res.x))


def test_qp_set_file_roundtrip(tmp_path):
    rng = np.random.default_rng(4)
    qps = [rendezvous_qp(5, rng), docking_qp(4, rng), random_mpc_qp(6, rng)]
    path = tmp_path / "set.npz"
    save_qp_set(path, qps)
    back = load_qp_set(path)
    assert [q.phase for q in back] == ["rendezvous", "docking", "random"]
    for a, b in zip(qps, back):
        assert a.nu == b.nu and a.nc == b.nc and a.Ts == b.Ts
        for name in ("A", "B", "b", "Q", "q", "R", "r", "C", "D", "d"):
            for x, y in zip(getattr(a, name), getattr(b, name)):
                assert np.array_equal(x, y)
        assert flight_sw.solve_ocp_qp(*b.args(), **b.kw()).objective == flight_sw.solve_ocp_qp(*a.args(), **a.kw()).objective
    np.savez(tmp_path / "bad.npz", n_qps=np.array(1), **{"qp0/N": np.array(2)})
    with pytest.raises(ValueError, match="x0"):
        load_qp_set(tmp_path / "bad.npz")


def test_the_rendezvous_cold_start_takes_the_input_bounds_at_their_slack():
    """The rendezvous' first QP, from a kilometre or more out, solved cold: its rows' slacks start at
    their residuals down to the rendezvous' floor of 0.1 (an input bound of 0.18 m/s at u = 0 holds
    with slack 0.18, where the solver's default floor of 1 starts it at 1). On 40 random starts'
    first QPs at N = 30: the same verdicts and answers as Clarabel either way, fewer iterations in all
    and no more at most with the floor of 0.1; and the guidance's first step takes exactly the
    iterations of that setting (it passes the floor to its solver)."""
    from rvd_pil.host_sim.scenario import random_scenario
    p = flight_sw.GuidanceParams()
    p.rendezvous.N = 30
    assert p.rendezvous.solver_cold_slack_floor == 0.1 and p.approach.solver_cold_slack_floor == 1.0
    assert flight_sw.OcpSolver(6, [3, 0], [1, 1]).cold_slack_floor == 1.0  # the solver's own default
    with pytest.raises(ValueError):
        flight_sw.OcpSolver(6, [3, 0], [1, 1]).cold_slack_floor = 0.0
    case = flight_sw.dissertation_case(1)
    its = {1.0: [], 0.1: []}
    for seed in range(300, 340):
        sc = random_scenario(seed)
        g = flight_sw.Guidance(p)
        cmd = g.step(flight_sw.NavInput(0, 0.0, np.r_[sc.chaser.position_lvlh_m, sc.chaser.velocity_lvlh_mps],
                                        case["q_lvlh_body"], case["omega_body_rad_s"]))
        assert cmd.phase == flight_sw.Phase.Rendezvous
        qp = from_dict(g.last_qp(flight_sw.Phase.Rendezvous), "rendezvous")
        ref = solve_clarabel(qp)
        for floor in its:
            s = flight_sw.OcpSolver(qp.nx, qp.nu, qp.nc, qp.ns if qp.idxs else None, mode="interior_point",
                                    tol=1e-8, warm_start=False)
            s.cold_slack_floor = floor
            res = s.solve(*qp.args(), **qp.kw())
            assert res.status == ref.status, (seed, floor)
            if ref.status == "solved":
                assert res.objective == pytest.approx(ref.objective, rel=1e-6, abs=1e-6), (seed, floor)
            its[floor].append(res.iterations)
        if cmd.status == flight_sw.StepStatus.Ok:
            assert cmd.iterations == its[0.1][-1], seed
    assert sum(its[0.1]) < sum(its[1.0]) and max(its[0.1]) <= max(its[1.0]), its


def test_the_noisy_loops_turn_a_spinning_target_as_the_guidance_predicts_it(monkeypatch):
    """bench.noisy_loops gives the guidance the target's attitude at each step's time: Case 3's as the
    host simulator's target model has it (a spin about body z = LVLH z), and as the C++ closed loop
    flies it (every step of run_closed_loop's Case 3)."""
    from rvd_pil.host_sim.frames import quaternion_after
    given = []
    real_nav = flight_sw.NavInput
    monkeypatch.setattr(flight_sw, "NavInput", lambda k, t, x, q, w: given.append((t, np.array(q))) or real_nav(k, t, x, q, w))
    for k, _, _ in noisy_loop(3, (15, 5, 5), 0, 0.02, 0.03, max_steps=12):
        pass
    monkeypatch.undo()
    assert len(given) == 12 and given[-1][0] > 300.0
    for t, q in given:
        assert np.abs(q - quaternion_after(flight_sw.dissertation_case(3)["q_lvlh_body"],
                                         flight_sw.dissertation_case(3)["omega_body_rad_s"], t)).max() == 0.0, t
    from rvd_pil.host_sim.frames import quaternion_about_z
    c = flight_sw.dissertation_case(3)
    rate = c["omega_body_rad_s"][2]
    assert rate > 0.0
    for t in (0.0, 30.0, 1234.5, 6000.0):
        q = quaternion_after(c["q_lvlh_body"], c["omega_body_rad_s"], t)
        truth = quaternion_about_z(math.pi / 2 + rate * t)
        assert min(np.abs(q - truth).max(), np.abs(q + truth).max()) < 1e-12, t
    run = flight_sw.run_closed_loop(flight_sw.GuidanceParams(), c["x0"], c["q_lvlh_body"], c["omega_body_rad_s"])
    for t, q_flown in zip(np.asarray(run.t_s), np.asarray(run.q_lvlh_body)):
        q = quaternion_after(c["q_lvlh_body"], c["omega_body_rad_s"], t)
        assert min(np.abs(q - q_flown).max(), np.abs(q + q_flown).max()) < 1e-9, t
    # a general axis: the turn is about the body axis (q (x) dq), not the LVLH one
    q0, w = np.array([0.9, 0.1, -0.3, 0.2]) / np.linalg.norm([0.9, 0.1, -0.3, 0.2]), np.array([0.01, -0.02, 0.005])
    a, b = quaternion_after(q0, w, 40.0), quaternion_after(quaternion_after(q0, w, 15.0), w, 25.0)
    assert np.abs(a - b).max() < 1e-12
    v_body = w / np.linalg.norm(w)  # the rotation axis is fixed in the body: the same in LVLH before and after
    rot = lambda q, v: (lambda w_, u: v + 2 * w_ * np.cross(u, v) + 2 * np.cross(u, np.cross(u, v)))(q[0], q[1:])
    assert np.abs(rot(q0, v_body) - rot(a, v_body)).max() < 1e-12


def test_separate_step_lengths_take_the_warm_start_through_a_turn_of_the_keep_out_planes():
    """Case 3's keep-out planes turn round where the cone's axis comes within reach: the shifted plan then
    violates most planes, and a row the new QP releases keeps a large dual from the plan that violated it.
    While the primal residual is large the primal and dual variables take their own step lengths
    (Settings::separate_steps_above); with one length, that dual's fall to zero held every step short.
    On the noisy closed loops' rendezvous QPs, solved warm as the guidance solves them: the same answers as
    Clarabel (and the same infeasibility verdicts), never more than one iteration more than with one step
    length, fewer in all, and at the turn two or more fewer."""
    assert math.isfinite(flight_sw.OcpSolver(6, [3, 0], [1, 1]).separate_steps_above)  # on by default
    totals, saved = {}, []
    for seed in range(4):
        qps = []
        for _, g, cmd in noisy_loop(3, (45, 30, 30), seed, 0.02, 0.03):
            if cmd.phase != flight_sw.Phase.Rendezvous:
                break
            qps.append(from_dict(g.last_qp(flight_sw.Phase.Rendezvous), "rendezvous"))
        assert len(qps) > 20
        its, statuses = {}, {}
        for name, above in (("one length", math.inf), ("separate", None)):
            s = flight_sw.OcpSolver(qps[0].nx, qps[0].nu, qps[0].nc, qps[0].ns if qps[0].idxs else None,
                                    mode="interior_point", tol=1e-8, warm_start=True)
            if above is not None:
                s.separate_steps_above = above
            its[name], statuses[name] = [], []
            for k, qp in enumerate(qps):
                res = s.solve(*qp.args(), **qp.kw())
                if name == "separate" and k % 3 == 0:  # (a sample; Clarabel: ProxSuite stalls on some of these)
                    ref = solve_clarabel(qp)
                    assert res.status == ref.status, (seed, k)
                    if ref.status == "solved":
                        assert res.objective == pytest.approx(ref.objective, rel=1e-6, abs=1e-6), (seed, k)
                its[name].append(res.iterations)
                statuses[name].append(res.status)
                s.shift_warm_start()
        # the same verdicts (the last periods before the approach entry are infeasible, the turning
        # corridor's planes re-centred on a fast chaser: the guidance flies its recovery QP there)
        assert statuses["separate"] == statuses["one length"], seed
        assert statuses["separate"].count("solved") > 0.6 * len(qps)
        one, sep = np.array(its["one length"][1:]), np.array(its["separate"][1:])  # the warm solves
        assert np.all(sep <= one + 1), (seed, one, sep)
        saved.append(int(np.max(one - sep)))
        for name, v in (("one length", one), ("separate", sep)):
            totals[name] = totals.get(name, 0) + int(v.sum())
    assert totals["separate"] < totals["one length"], totals
    assert sum(v >= 2 for v in saved) >= 2, saved  # the turn, in most loops


def test_bench_runs_on_a_qp_set_file(tmp_path, capsys):
    """The benchmark's table on a tiny QP-set file: every solver's row is there and agrees with
    the reference (no speed is asserted)."""
    from rvd_pil.bench import solvers
    rng = np.random.default_rng(8)
    path = tmp_path / "two.npz"
    save_qp_set(path, [docking_qp(5, rng), docking_qp(5, rng)])
    assert solvers.main(["--qp-set", str(path), "--repeats", "1", "--solvers", "flight_sw,proxsuite-sparse,daqp"]) == 0
    out = capsys.readouterr().out
    rows = [line.split() for line in out.splitlines() if line.startswith("docking")]
    assert [r[2] for r in rows] == ["flight_sw", "proxsuite-sparse", "daqp"]
    assert all(r[8] == "0/2" for r in rows), out  # objectives agree with the reference
    # flight_sw's time by part, set against DAQP's clock on the part that clock covers
    parts = [line.split() for line in out.splitlines() if line.startswith("  docking") and "iterations" in line]
    assert len(parts) == 1 and parts[0][2] == "flight_sw" and "daqp" in parts[0], out


def test_bench_with_cold_caches_evicts_them_before_every_timed_solve(tmp_path, capsys, monkeypatch):
    """--cold-cache: before each timed solve of each solver the evictor writes over a buffer at least
    twice the size of the last-level cache; the answers are checked as without it."""
    from rvd_pil.bench import solvers
    rng = np.random.default_rng(9)
    path = tmp_path / "two.npz"
    save_qp_set(path, [docking_qp(5, rng), docking_qp(5, rng)])
    calls, sizes = [], []
    evict = solvers.CacheEvictor.__call__

    def counted(self):
        calls.append(1)
        sizes.append(self.bytes)
        evict(self)

    monkeypatch.setattr(solvers.CacheEvictor, "__call__", counted)
    assert solvers.main(["--qp-set", str(path), "--repeats", "3", "--solvers", "flight_sw,daqp", "--cold-cache"]) == 0
    out = capsys.readouterr().out
    assert "caches: evicted before every timed solve" in out
    assert len(calls) == 2 * 2 * 3  # QPs x solvers x repeats
    llc = Path("/sys/devices/system/cpu/cpu0/cache/index3/size")
    if llc.exists():  # e.g. "32768K"
        text = llc.read_text().strip()
        assert sizes[0] >= 2 * int(text.rstrip("KMG")) * {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30}.get(text[-1], 1)
    rows = [line.split() for line in out.splitlines() if line.startswith("docking")]
    assert [r[2] for r in rows] == ["flight_sw", "daqp"] and all(r[8] == "0/2" for r in rows), out
    # each QP's first timed solve against its repeats, per solver, with DAQP's set against flight_sw's
    first = [line for line in out.splitlines() if line.startswith("  docking") and "iterations" not in line]
    assert len(first) == 1, out
    m = re.fullmatch(r"\s+docking\s+5\s+flight_sw (\S+) / (\S+), daqp (\S+) / (\S+) \((\S+) / (\S+)\)", first[0])
    assert m, first[0]
    f0, f1, d0, d1, r0, r1 = (float(v) for v in m.groups())
    assert min(f0, f1, d0, d1) > 0.0
    # the ratios are of the unrounded medians; the medians are printed to 0.05, the ratios to 0.005
    for r, d, f in ((r0, d0, f0), (r1, d1, f1)):
        assert abs(r - d / f) <= d / f * (0.05 / d + 0.05 / f) * 1.01 + 0.005, (r, d, f)


@pytest.mark.parametrize("phase", ["rendezvous", "approach"])
@pytest.mark.parametrize("N", [5, 30])
def test_soft_rows_equal_the_qp_with_explicit_slack_inputs(phase, N):
    """A soft row is the same as a slack input s >= 0 with the row's penalty (support.qp_forms.expand_soft):
    the same optimum, the same plan; the slacks reported are the violations at the returned plan."""
    from support.qp_forms import expand_soft
    qp = make(phase, N, 3 * N + 1)
    quad = [np.full(len(z), 0.5) for z in qp.zs]  # a quadratic penalty too
    qp = OcpQpData(*qp.args()[:-1], qp.x0, qp.phase, qp.Ts, qp.idxs, qp.zs, quad)
    soft = flight_sw.solve_ocp_qp(*qp.args(), **qp.kw())
    explicit = expand_soft(qp)
    slack = flight_sw.solve_ocp_qp(*explicit.args())
    assert soft.status == slack.status == "solved"
    assert soft.objective == pytest.approx(slack.objective, rel=1e-7)
    assert max(len(u) for u in soft.u) == 3  # the physical inputs only
    for i in range(N):
        # (the optimum is flat to ~sqrt(tol f / R): 1e-4 m/s is far below it mattering)
        np.testing.assert_allclose(soft.u[i], slack.u[i][:3], atol=1e-4)
    for i in range(N + 1):
        rows = np.asarray(qp.idxs[i], int)
        if len(rows):
            viol = np.maximum(qp.C[i][rows] @ soft.x[i] + qp.D[i][rows] @ soft.u[i] - qp.d[i][rows], 0.0)
            np.testing.assert_allclose(soft.s[i], viol, atol=1e-12)


def test_bench_tails_flies_each_phase_and_agrees_with_daqp(capsys):
    """--tails on one horizon set and one seed: a block per phase with the flown, cold, warm interior
    point and DAQP rows, every QP solved by each to the reference's objective (bad 0), the flown maximum
    located, and the repeated loop checked to fly the same commands (it raises otherwise). No speed is
    asserted."""
    from rvd_pil.bench import solvers
    solvers.closed_loop_tails(seeds=1, repeats=2, horizon_sets=((15, 5, 5),))
    out = capsys.readouterr().out
    rows = [line.split() for line in out.splitlines() if line.split()[:1] in (["rendezvous"], ["approach"], ["docking"])]
    assert [(r[0], r[1]) for r in rows[::5]] == [("rendezvous", "15"), ("approach", "5"), ("docking", "5")], out
    for block in (rows[i:i + 5] for i in range(0, len(rows), 5)):
        assert [" ".join(r[3:-5]) for r in block] == ["flown", "flight_sw cold", "interior point warm", "daqp cold",
                                                      "daqp warm"], out
        assert len({r[2] for r in block}) == 1 and int(block[0][2]) > 10  # the same steps for every solver
        assert all(r[-1] == "0" for r in block[1:]), out  # every solver gives the reference's answer
        for r in block:
            median, p99, peak = (float(v) for v in r[-5:-2])
            assert 0.0 < median <= p99 <= peak
    assert out.count("flown maximum: Case") == 3


def test_bench_tails_charges_a_wrong_answer_to_its_solver_only(capsys, monkeypatch):
    """Where two answers differ, the reference solver decides which is wrong: DAQP's objective made 1e-3
    too high counts on DAQP cold in every block, and on none of the flight_sw rows."""
    from rvd_pil.bench import solvers
    run_daqp = solvers.run_daqp

    def off(qp, forms):
        obj, status, t_us, setup = run_daqp(qp, forms)
        return obj + 1e-3 * max(1.0, abs(obj)), status, t_us, setup
    monkeypatch.setattr(solvers, "run_daqp", off)
    solvers.closed_loop_tails(seeds=1, repeats=1, horizon_sets=((15, 5, 5),))
    out = capsys.readouterr().out
    rows = [line.split() for line in out.splitlines() if line.split()[:1] in (["rendezvous"], ["approach"], ["docking"])]
    bad = {(r[0], " ".join(r[3:-5])): r[-1] for r in rows}
    for phase in ("rendezvous", "approach", "docking"):
        solves = next(r[2] for r in rows if r[0] == phase)
        assert bad[(phase, "daqp cold")] == solves, out
        assert bad[(phase, "flight_sw cold")] == bad[(phase, "interior point warm")] == "0", out
