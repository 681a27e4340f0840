"""The dual active-set path of the converged mode (flight_sw/solver/active_set.cpp: the condensed QP,
Goldfarb-Idnani / DAQP style) against ProxSuite on docking and approach QPs: feasible ones, ones made
infeasible through the dynamics and input limits by a reach row (an LP finds the reach), approach QPs
whose soft cone rows are violated at the optimum (a linear penalty below the rows' multipliers), and
closed-loop QPs of the guidance. Every solve is checked to have been answered by the active-set
method (rows changed, no interior-point iteration), so these tests see that path and no other."""
import dataclasses

import numpy as np
import pytest

from rvd_pil import flight_sw
from support.qp_forms import (OcpQpData, approach_qp, docking_qp, from_dict, solve_clarabel, solve_proxsuite,
                              with_reach_row)

GENERATORS = {"approach": approach_qp, "docking": docking_qp}


def make(phase: str, N: int, seed: int) -> OcpQpData:
    return GENERATORS[phase](N, np.random.default_rng(seed))


def reference(qp: OcpQpData):
    for eps in (1e-10, 1e-9, 1e-8):
        ref = solve_proxsuite(qp, eps_abs=eps, max_iter=20000)
        if ref.status in ("solved", "infeasible"):
            return ref
    # ProxSuite reaches its cap on some infeasible QPs with soft rows (the docking stop plane's slacks
    # among them): Clarabel's certificate answers there.
    clarabel = solve_clarabel(qp)
    return clarabel if clarabel.status in ("solved", "infeasible") else ref


def by_active_set(res) -> bool:
    # No interior-point iteration; rows changed (or none had to: the unconstrained optimum is feasible).
    return res.iterations == 0 and (res.active_set_changes > 0 or res.status == "solved")


def agrees(qp: OcpQpData, res, ref) -> None:
    assert res.status == ref.status == "solved", (res.status, ref.status)
    assert abs(res.objective - ref.objective) <= 1e-6 * max(1.0, abs(ref.objective)), (res.objective, ref.objective)
    assert res.objective == pytest.approx(qp.objective(res.x, list(res.u)), rel=1e-12, abs=1e-9)
    assert qp.violation(res.x, list(res.u)) <= 1e-7
    assert res.primal_residual <= 1e-7
    assert res.dual_residual <= 1e-7 * max(1.0, abs(ref.objective))  # multipliers and pi consistent


def solve_with(qp: OcpQpData, bulk: int):
    """One cold solve by an OcpSolver whose active-set method takes up to `bulk` violated rows
    besides the most violated one per primal point (Settings::active_set_bulk; 0: one at a time)."""
    s = flight_sw.OcpSolver(qp.nx, qp.nu, qp.nc, qp.ns if qp.idxs else None, tol=1e-8, warm_start=False)
    s.active_set_bulk = bulk
    return s.solve(*qp.args(), **qp.kw())


@pytest.mark.parametrize("bulk", [0, 4, 8])
@pytest.mark.parametrize("N", [5, 12, 30])
@pytest.mark.parametrize("phase", list(GENERATORS))
def test_matches_proxsuite(phase, N, bulk):
    for seed in range(4):
        qp = make(phase, N, 100 * N + seed)
        res = solve_with(qp, bulk)
        assert by_active_set(res), (res.iterations, res.active_set_changes)
        agrees(qp, res, reference(qp))


@pytest.mark.parametrize("N", [5, 12, 30])
@pytest.mark.parametrize("phase", list(GENERATORS))
def test_infeasible_through_the_dynamics(phase, N):
    """A row 1 unit beyond what any plan reaches: infeasible by ProxSuite and by the active set's
    dual ray; 1 unit short of it: feasible, the same optimum as ProxSuite's."""
    rng = np.random.default_rng(2000 + N)
    base = make(phase, N, 3 * N + 7)
    stage = int(rng.integers(1, N + 1))
    direction = np.zeros(6)
    direction[int(rng.integers(0, 3))] = rng.choice([-1.0, 1.0])
    infeasible = with_reach_row(base, stage, direction, +1.0)
    assert solve_proxsuite(infeasible, eps_infeasible=1e-4, max_iter=20000).status == "infeasible"
    res = solve_with(infeasible, 0)
    assert res.status == "infeasible" and by_active_set(res)
    # Rows taken in bulk can leave the working set nearly dependent on such a QP: the method then
    # finds its rows not tight and hands the QP to the interior point, which must say the same.
    assert solve_with(infeasible, 4).status == "infeasible"
    feasible = with_reach_row(base, stage, direction, -1.0)
    for bulk in (0, 4):
        res = solve_with(feasible, bulk)
        assert by_active_set(res)
        agrees(feasible, res, reference(feasible))


@pytest.mark.parametrize("N", [5, 15, 30])
def test_violated_soft_rows(N):
    """Approach QPs whose set point lies 80 m outside the corridor, with a penalty below the pull
    of the cost: soft rows end at their penalty (multiplier = zs, violation > 0), the exact l1
    penalty; the slacks reported are the violations at the plan."""
    saturated = 0
    for seed in range(3):
        qp = approach_qp(N, np.random.default_rng(50 + seed))
        outside = np.array([80.0, -35.0, 0.0, 0.0, 0.0, 0.0])  # the cone's axis is -y, 20 deg half-angle
        qp.q = [-Q @ outside for Q in qp.Q]
        dist = -qp.x0[1]
        qp.x0 = np.array([0.35 * dist, -dist, 0.0, 0.3, 0.0, 0.0])  # at the corridor's edge, drifting out
        res = flight_sw.solve_ocp_qp(*qp.args(), **qp.kw())
        assert by_active_set(res)
        agrees(qp, res, reference(qp))
        for i in range(N + 1):
            rows = np.asarray(qp.idxs[i], int)
            viol = np.maximum(qp.C[i][rows] @ res.x[i] + qp.D[i][rows] @ res.u[i] - qp.d[i][rows], 0.0)
            np.testing.assert_allclose(res.s[i], viol, atol=1e-12)
            lam = np.asarray(res.lam[i])[rows]
            at_penalty = viol > 1e-6
            saturated += int(at_penalty.sum())
            np.testing.assert_allclose(lam[at_penalty], qp.zs[i][at_penalty], rtol=1e-9)
            assert np.all(lam <= qp.zs[i] * (1 + 1e-9)) and np.all(lam >= 0.0)
    assert saturated > 0  # the QPs do exercise rows at their penalty


def test_quadratic_soft_penalty_stays_on_the_interior_point():
    qp = approach_qp(5, np.random.default_rng(3))
    qp = OcpQpData(*qp.args()[:-1], qp.x0, qp.phase, qp.Ts, qp.idxs, qp.zs, [np.full(len(z), 0.5) for z in qp.zs])
    res = flight_sw.solve_ocp_qp(*qp.args(), **qp.kw())
    assert res.iterations > 0 and res.active_set_changes == 0
    agrees(qp, res, reference(qp))


def chain_qp(nx: int, N: int, rng: np.random.Generator) -> OcpQpData:
    """nx masses in a row driven by one force through the first (nu = 1), |u| <= 1 and |x_j| <= 2:
    many states per input."""
    A = np.eye(nx) + 0.05 * (np.eye(nx, k=1) + np.eye(nx, k=-1) - 2.0 * np.eye(nx))
    B = np.zeros((nx, 1))
    B[0, 0] = 0.1
    x0 = rng.uniform(-1.5, 1.5, nx)
    C_state = np.vstack([np.eye(nx), -np.eye(nx)])
    As, Bs, bs, Qs, qs, Rs, rs, Cs, Ds, ds = ([] for _ in range(10))
    for i in range(N + 1):
        nu = 1 if i < N else 0
        Qs.append(np.eye(nx)), qs.append(np.zeros(nx)), Rs.append(np.eye(nu)), rs.append(np.zeros(nu))
        C, D, d = C_state, np.zeros((2 * nx, nu)), np.full(2 * nx, 2.0)
        if nu:
            C = np.vstack([C, np.zeros((2, nx))])
            D = np.vstack([D, [[1.0], [-1.0]]])
            d = np.concatenate([d, [1.0, 1.0]])
            As.append(A), Bs.append(B), bs.append(np.zeros(nx))
        Cs.append(C), Ds.append(D), ds.append(d)
    return OcpQpData(As, Bs, bs, Qs, qs, Rs, rs, Cs, Ds, ds, x0)


@pytest.mark.parametrize("nx, by_active", [(60, True), (130, False)])
def test_many_states_per_input_go_to_the_interior_point(nx, by_active):
    """The active set keeps the products of every pair of stages' condensed columns, sum over
    i <= j of (nu_i + nx)(nu_j + nx) doubles: 0.24 M at nx = 60, N = 10, nu = 1, within its 1 M
    limit, and 1.13 M at nx = 130, above it. The second QP (10 inputs, within the input limit)
    goes to the interior point instead; both answers agree with ProxSuite."""
    qp = chain_qp(nx, 10, np.random.default_rng(nx))
    res = flight_sw.solve_ocp_qp(*qp.args(), tol=1e-8)
    assert by_active_set(res) == by_active, (res.iterations, res.active_set_changes)
    if not by_active:
        assert res.iterations > 0 and res.active_set_changes == 0
    agrees(qp, res, reference(qp))


@pytest.mark.parametrize("N", [5, 12, 30])
def test_the_arena_holds_the_condensed_qp(N):
    """One arena holds all the solver's working memory: with the active-set method (the guidance's
    docking shape, nx = 6, nu = 3) it is larger than the interior point's alone by at least what
    the condensed QP's largest arrays need, 8 bytes per double: the stage-pair products (sum over
    i <= j of (nu_i + nx)(nu_j + nx)), H^-1 and its Cholesky factor (n^2 each, n = 3 N inputs) and
    H^-1 Gamma_i' ((N + 1) n nx)."""
    nx, nu = 6, [3] * N + [0]
    nc = [16] * (N + 1)
    both = flight_sw.OcpSolver(nx, nu, nc, None)
    ipm = flight_sw.OcpSolver(nx, nu, nc, None, mode="interior_point")
    n, widths = sum(nu), [m + nx for m in nu]
    pairs = sum(widths[i] * widths[j] for i in range(N + 1) for j in range(i, N + 1))
    least = 8 * (pairs + 2 * n * n + (N + 1) * n * nx)
    assert both.workspace_bytes - ipm.workspace_bytes >= least
    assert ipm.workspace_bytes > 8 * (N + 1) * nx * nx  # the cost-to-go matrices at least


@pytest.mark.parametrize("phase", list(GENERATORS))
def test_rows_kept_with_more_nonzeros_than_a_period_has(phase):
    """setup() keeps the rows with its QP's nonzeros. A later QP whose nonzeros are among them takes
    its values in place, zeros included where a kept entry is zero now (a cone facet that lines up
    with an axis, a row switched off to 0 <= 1): here the rows are kept with every position entry
    nonzero, and the QP solved has one input bound of stage 1 switched off (a kept single-input row
    whose entry is zero now). The answers must be ProxSuite's for the QP solved."""
    for N in (5, 12):
        for seed in range(3):
            qp = make(phase, N, 700 + 10 * N + seed)
            D, d = [m.copy() for m in qp.D], [v.copy() for v in qp.d]
            box = next(r for r in range(D[1].shape[0]) if np.count_nonzero(D[1][r]) == 1 and not np.any(qp.C[1][r]))
            D[1][box] = 0.0
            d[1][box] = 1.0
            period = dataclasses.replace(qp, D=D, d=d)
            wide_C = [np.hstack([np.where(c[:, :3] == 0.0, 1.0, c[:, :3]), c[:, 3:]]) for c in qp.C]
            wide = dataclasses.replace(qp, C=wide_C)
            s = flight_sw.OcpSolver(qp.nx, qp.nu, qp.nc, qp.ns if qp.idxs else None, mode="converged", tol=1e-8,
                                    warm_start=False)
            s.setup(*wide.args()[:-1], **wide.kw())
            res = s.solve(*period.args(), **period.kw())
            assert by_active_set(res), (res.iterations, res.active_set_changes)
            agrees(period, res, reference(period))


def test_changed_dynamics_and_weights_are_condensed_again():
    """One solver, set up for one QP, then given QPs with other A, B, Q, R (another period, other
    weights): each answer is the optimum of the QP given, not of the one condensed at setup."""
    a = docking_qp(12, np.random.default_rng(1))
    b = docking_qp(12, np.random.default_rng(2), ts_s=4.0)
    b = OcpQpData(b.A, b.B, b.b, [3.0 * Q for Q in b.Q], b.q, [0.5 * R for R in b.R], *b.args()[6:-1], b.x0,
                  b.phase, b.Ts)
    solver = flight_sw.OcpSolver(a.nx, a.nu, a.nc, None, warm_start=False)
    solver.setup(*a.args()[:-1])
    for qp in (a, b, a, b):
        res = solver.solve(*qp.args())
        assert by_active_set(res)
        agrees(qp, res, reference(qp))


@pytest.fixture(scope="module")
def closed_loop_qps():
    """QPs the guidance solved in a closed loop of Case 3 (rotating target) at docking N = 5,
    approach N = 5 (the shortest horizons: where the active set is meant to be fast)."""
    params = flight_sw.GuidanceParams()
    params.approach.N, params.docking.N = 5, 5
    c = flight_sw.dissertation_case(3)
    run = flight_sw.run_closed_loop(params, c["x0"], c["q_lvlh_body"], c["omega_body_rad_s"], record_qps=True)
    assert run.docked, run.reason
    out = {}
    for rec in run.qps:
        phase = int(rec["phase"])
        if phase in (2, 3):
            out.setdefault(phase, []).append(from_dict(rec["qp"]))
    return out


@pytest.mark.parametrize("phase", [2, 3])
def test_closed_loop_qps(closed_loop_qps, phase):
    qps = closed_loop_qps[phase]
    rng = np.random.default_rng(phase)
    chosen = [qps[i] for i in sorted(rng.choice(len(qps), size=min(25, len(qps)), replace=False))]
    for qp in chosen:
        res = flight_sw.solve_ocp_qp(*qp.args(), **qp.kw(), tol=1e-8)
        assert by_active_set(res)
        agrees(qp, res, reference(qp))


def test_one_solver_along_a_closed_loop(closed_loop_qps):
    """One solver, as the guidance keeps it, fed the docking QPs of a turning target in flight order:
    the cone rows' values change every period on the same nonzeros (taken in place), a QP with other
    nonzeros prepares every row again, a NaN in a row is refused, and every answer is the optimum
    of the QP given. The first QP comes back after values taken in place: the copies that tell a
    stage unchanged must be those of the last QP, not of the last full preparation."""
    qps = closed_loop_qps[3][:12]
    first = qps[0]

    def solver_for(qp):  # as the guidance keeps one: set up once, the QP's soft rows (the stop plane) soft
        s = flight_sw.OcpSolver(qp.nx, qp.nu, qp.nc, qp.ns if qp.idxs else None, warm_start=False)
        s.setup(*qp.args()[:-1], **qp.kw())
        return s

    def rows_copied(qp):  # the QP with its own copies of C, D, d
        return dataclasses.replace(qp, C=[m.copy() for m in qp.C], D=[m.copy() for m in qp.D],
                                   d=[v.copy() for v in qp.d])

    solver = solver_for(first)
    assert any(not np.array_equal(a.C[1], b.C[1]) for a, b in zip(qps, qps[1:]))  # the rows do turn
    reshaped = rows_copied(first)
    reshaped.C[2][0, 5] += 1e-3  # a nonzero where the cone row had none
    bad = rows_copied(first)
    bad.C[2][0, 0] = np.nan
    # D is checked and taken in where it differs from the copy, with C turning as well: a NaN in an
    # input bound refused; an input bound scaled (the same half-space: the row's norm must follow).
    box = next(r for r in range(qps[1].D[1].shape[0]) if np.count_nonzero(qps[1].D[1][r]) == 1)
    bad_d = rows_copied(qps[1])
    bad_d.D[1][box][bad_d.D[1][box] != 0] = np.nan
    scaled = rows_copied(qps[2])
    scaled.D[1][box] *= 4.0
    scaled.d[1][box] *= 4.0
    # Every active row of a QP scaled by its own factor (the same half-spaces, other norms): the
    # entering row is picked by distance, so norms left stale would change the path.
    probe = flight_sw.solve_ocp_qp(*qps[3].args(), **qps[3].kw(), tol=1e-8)
    spread = rows_copied(qps[3])
    factor = 1.0
    for i, lam in enumerate(probe.lam):
        for r in np.flatnonzero(np.asarray(lam) > 0):
            factor *= 10.0
            spread.C[i][r] *= factor
            spread.D[i][r] *= factor
            spread.d[i][r] *= factor
    assert factor >= 100.0  # at least two active rows scaled
    for qp in qps[:6] + [qps[0], reshaped, bad, bad_d, scaled, spread] + qps[6:] + [qps[0]]:
        res = solver.solve(*qp.args(), **qp.kw())
        if qp is bad or qp is bad_d:
            assert res.status == "invalid_input"
            continue
        assert by_active_set(res)
        agrees(qp, res, reference(qp))
        # Values taken in place (row norms included) leave the solver where preparing every row
        # afresh does: the same row changes and the same answer, to the last bit.
        again = solver_for(qp).solve(*qp.args(), **qp.kw())
        assert again.active_set_changes == res.active_set_changes
        assert all(np.array_equal(a, b) for a, b in zip(again.u, res.u))


def unreachable_row_in_place(qp: OcpQpData) -> OcpQpData:
    """The QP with its last stage's first hard row replaced by one 1 m beyond the farthest radial
    position any plan reaches there (same shape: the same solver takes it)."""
    N, e0 = qp.N, np.eye(qp.nx)[0]
    j = int(np.flatnonzero(qp.hard_rows(N))[0])
    C, D, d = list(qp.C), list(qp.D), list(qp.d)
    C[N], D[N], d[N] = qp.C[N].copy(), np.zeros_like(qp.D[N]), qp.d[N].copy()
    C[N][j], d[N][j] = -e0, 1e9  # loose while the reach is measured
    loose = dataclasses.replace(qp, C=C, D=D, d=d)
    reach_row = with_reach_row(loose, stage=N, direction=e0, margin=1.0)
    d = list(d)
    d[N] = d[N].copy()
    d[N][j] = reach_row.d[N][-1]
    return dataclasses.replace(loose, d=d)


@pytest.mark.parametrize("phase", [2, 3])
def test_warm_start_along_a_closed_loop(closed_loop_qps, phase):
    """One warm-started solver fed a phase's QPs in flight order, shifted between periods as the
    guidance shifts it: it starts from the last working set, so it needs fewer row changes than
    the same solver cold, and every answer is still the optimum of the QP given. Then the warm
    start is made wrong on purpose (the QPs in reverse order, an infeasible QP in between, a
    reset): the answers stay the optimum, and the infeasible QP is called infeasible."""
    qps = closed_loop_qps[phase]
    first = qps[0]
    warm = flight_sw.OcpSolver(first.nx, first.nu, first.nc, first.ns if first.idxs else None, warm_start=True)
    cold = flight_sw.OcpSolver(first.nx, first.nu, first.nc, first.ns if first.idxs else None, warm_start=False)
    changes = {"warm": 0, "cold": 0}
    for k, qp in enumerate(qps):
        for name, solver in (("warm", warm), ("cold", cold)):
            res = solver.solve(*qp.args(), **qp.kw())
            assert by_active_set(res)
            changes[name] += res.active_set_changes
            if k % 3 == 0 or name == "warm":
                agrees(qp, res, reference(qp))
            solver.shift_warm_start()
    assert changes["warm"] <= 0.6 * changes["cold"], changes  # 0.55 (approach) and 0.20 (docking) here
    infeasible = unreachable_row_in_place(qps[len(qps) // 2])
    for qp in list(reversed(qps[-6:])) + [infeasible] + qps[:3]:
        res = warm.solve(*qp.args(), **qp.kw())
        ref = reference(qp)
        if qp is infeasible:
            assert res.status == ref.status == "infeasible", (res.status, ref.status)
        else:
            assert by_active_set(res)
            agrees(qp, res, ref)
        warm.shift_warm_start()
    warm.reset_warm_start()
    res = warm.solve(*qps[0].args(), **qps[0].kw())
    agrees(qps[0], res, reference(qps[0]))


def rows_scaled(qp: OcpQpData, rng: np.random.Generator) -> OcpQpData:
    """The same QP with every row g'z <= d multiplied by its own factor in [0.1, 10]: the feasible set
    and the optimum do not change; a soft row's penalty per unit of the scaled violation is divided
    by the factor (zs / f, Zs / f^2), so its cost does not change either."""
    out = dataclasses.replace(qp)
    out.C, out.D, out.d = [], [], []
    out.zs = None if qp.idxs is None else []
    out.Zs = None if qp.idxs is None else []
    for i in range(qp.N + 1):
        f = rng.uniform(0.1, 10.0, qp.C[i].shape[0])
        out.C.append(f[:, None] * qp.C[i])
        out.D.append(f[:, None] * qp.D[i])
        out.d.append(f * qp.d[i])
        if qp.idxs is not None:
            fs = f[np.asarray(qp.idxs[i], int)]
            out.zs.append(np.asarray(qp.zs[i]) / fs)
            out.Zs.append(np.asarray(qp.Zs[i]) / fs ** 2)
    return out


@pytest.mark.parametrize("phase", list(GENERATORS))
def test_row_scaling_leaves_the_path_unchanged(phase, closed_loop_qps):
    """The entering row is the one farthest outside its half-space (violation over the row's norm in
    the condensed metric), so multiplying rows by positive factors changes neither the plan nor the
    sequence of working sets: the same number of changes and the same inputs. (Taking the largest
    violation instead lets a row's scale decide which row enters.)"""
    rng = np.random.default_rng(7)
    loop = closed_loop_qps[2 if phase == "approach" else 3]
    qps = [make(phase, N, 500 + N) for N in (5, 12, 30)] + loop[:: max(1, len(loop) // 8)]
    changed = 0
    for qp in qps:
        res = flight_sw.solve_ocp_qp(*qp.args(), **qp.kw(), tol=1e-8)
        scaled = rows_scaled(qp, rng)
        res_s = flight_sw.solve_ocp_qp(*scaled.args(), **scaled.kw(), tol=1e-8)
        assert by_active_set(res) and by_active_set(res_s)
        assert res_s.active_set_changes == res.active_set_changes
        u, u_s = np.concatenate(list(res.u)), np.concatenate(list(res_s.u))
        assert np.allclose(u_s, u, rtol=1e-8, atol=1e-10 * max(1.0, np.abs(u).max()))
        assert res_s.objective == pytest.approx(res.objective, rel=1e-9, abs=1e-9)
        changed += res.active_set_changes
    assert changed > 0  # the QPs needed working sets


def test_bulk_outside_its_range_is_refused():
    qp = make("docking", 5, 7)
    s = flight_sw.OcpSolver(qp.nx, qp.nu, qp.nc, qp.ns if qp.idxs else None, tol=1e-8, warm_start=False)
    for bad in (-1, 33):
        with pytest.raises(ValueError, match=r"active_set_bulk must be in 0\.\.32"):
            s.active_set_bulk = bad
    s.active_set_bulk = 32  # the largest allowed value solves as any other
    res = s.solve(*qp.args(), **qp.kw())
    assert by_active_set(res)
    agrees(qp, res, reference(qp))
    phase = flight_sw.GuidanceParams().docking
    with pytest.raises(ValueError, match=r"solver_active_set_bulk must be in 0\.\.32"):
        phase.solver_active_set_bulk = 33
    assert phase.solver_active_set_bulk == 4  # unchanged by the refused value
