"""The first approach solve starts from the look-ahead iterate of the last rendezvous steps (the approach QP
at the entry state the rendezvous plan predicts). Checked in closed loop against the impulsive CW plant:
the rendezvous steps before the entry ran the look-ahead; the entry's solve reaches the optimum of the
entry QP (Clarabel, an independent interior point solver) and the plan of the same loop flown without the
look-ahead; it needs at most 60 % of the iterations of a cold solve of the same QP by the same solver."""
import numpy as np
import pytest

from rvd_pil import flight_sw as fsw
from support.guidance_geometry import solve_clarabel


def closed_loop(p, case, steps, noise_m=0.0, seed=0):
    """The guidance against the impulsive CW plant (Gaussian noise of noise_m on the position it is given,
    when asked): yields (step, command, guidance) after each step."""
    g = fsw.Guidance(p)
    c = fsw.dissertation_case(case)
    rng = np.random.default_rng(seed)
    x, t, n = np.array(c["x0"], float), 0.0, p.mean_motion_rad_s()
    for k in range(steps):
        seen = x + np.r_[rng.normal(0.0, noise_m, 3), 0.0, 0.0, 0.0] if noise_m > 0.0 else x
        cmd = g.step(fsw.NavInput(k, t, seen, c["q_lvlh_body"], c["omega_body_rad_s"]))
        yield k, cmd, g
        x = fsw.cw_stm(n, cmd.period_s) @ (x + np.r_[0.0, 0.0, 0.0, cmd.dv_cmd_mps])
        t += cmd.period_s


def fly_into_approach(p, case, approach_steps=3):
    """Closed loop until `approach_steps` approach commands have been given; the commands, and the guidance
    right after the entry step with its entry QP."""
    cmds, entry = [], None
    for k, cmd, g in closed_loop(p, case, 400):
        cmds.append(cmd)
        if cmd.phase == fsw.Phase.Approach and entry is None:
            entry = (k, g.last_qp(fsw.Phase.Approach))
        if entry is not None and k - entry[0] + 1 >= approach_steps:
            return cmds, entry
    raise AssertionError("never reached the approach phase")


def interior_point_approach(approach_n):
    # The approach on the interior point (the default approach solver is the dual active-set method,
    # flight_sw/solver/README.md, tested below).
    p = fsw.GuidanceParams()
    p.approach.N = approach_n
    p.approach.solver_active_set_max_inputs = 0
    return p


@pytest.mark.parametrize("case,approach_n", [(1, 15), (2, 15), (1, 30), (1, 5)])
def test_first_approach_solve_starts_from_the_lookahead(case, approach_n):
    p = interior_point_approach(approach_n)
    cold = interior_point_approach(approach_n)
    cold.approach_lookahead_steps = 0
    cmds, (k, qp) = fly_into_approach(p, case)
    cmds_cold, (k_cold, qp_cold) = fly_into_approach(cold, case)
    assert k == k_cold  # the look-ahead changes no rendezvous command

    # The rendezvous step before the entry ran it; without the look-ahead nothing did.
    assert cmds[k - 1].phase == fsw.Phase.Rendezvous and cmds[k - 1].lookahead_iterations > 0
    assert all(c.lookahead_iterations == 0 for c in cmds_cold)
    assert all(c.lookahead_iterations == 0 for c in cmds[k:])

    entry = cmds[k]
    assert entry.status == fsw.StepStatus.Ok and entry.solver_status == "solved"
    # The same optimum as an independent solver's on the entry QP, and as the loop flown without the look-ahead.
    status, u_ref, _ = solve_clarabel(qp)
    assert status == "Solved"
    u_max = p.approach.u_max_mps
    np.testing.assert_allclose(entry.dv_cmd_mps, np.clip(u_ref[0][:3], -u_max, u_max), atol=1e-6)
    for a, b in zip(cmds[k:], cmds_cold[k:]):
        np.testing.assert_allclose(a.dv_cmd_mps, b.dv_cmd_mps, atol=1e-6)

    # Fewer iterations than a cold solve of the entry QP by the same solver at the flight tolerance
    # (the loop without the look-ahead solves it cold: the same count).
    cold_solve = fsw.solve_ocp_qp(**qp, tol=1e-8, max_iter=200, mode="interior_point")
    assert cold_solve.status == "solved"
    assert cmds_cold[k].iterations == cold_solve.iterations
    assert entry.iterations <= 0.6 * cold_solve.iterations, (entry.iterations, cold_solve.iterations)


@pytest.mark.parametrize("case,approach_n", [(1, 5), (1, 15), (2, 15), (1, 30)])
def test_lookahead_for_the_active_set(case, approach_n):
    """With the approach on the dual active-set method (the default) the rendezvous step before the
    entry solves the approach QP at the predicted entry state; the entry's solve starts from that
    working set: the same plan as the loop flown without the look-ahead and as Clarabel on the entry
    QP, with at most half the row changes of that loop's cold entry solve."""
    p = fsw.GuidanceParams()
    p.approach.N = approach_n
    cold = fsw.GuidanceParams()
    cold.approach.N = approach_n
    cold.approach_lookahead_steps = 0
    cmds, (k, qp) = fly_into_approach(p, case)
    cmds_cold, (k_cold, _) = fly_into_approach(cold, case)
    assert k == k_cold
    ahead = cmds[k - 1]
    assert ahead.phase == fsw.Phase.Rendezvous and ahead.lookahead_status == "solved"
    assert ahead.lookahead_iterations == 0 and ahead.lookahead_active_set_changes > 0
    assert all(c.lookahead_active_set_changes == 0 for c in cmds_cold)
    entry = cmds[k]
    assert entry.status == fsw.StepStatus.Ok and entry.solver_status == "solved" and entry.iterations == 0
    status, u_ref, _ = solve_clarabel(qp)
    assert status == "Solved"
    u_max = p.approach.u_max_mps
    np.testing.assert_allclose(entry.dv_cmd_mps, np.clip(u_ref[0][:3], -u_max, u_max), atol=1e-6)
    for a, b in zip(cmds[k:], cmds_cold[k:]):
        np.testing.assert_allclose(a.dv_cmd_mps, b.dv_cmd_mps, atol=1e-6)
    assert cmds_cold[k].active_set_changes > 0
    assert entry.active_set_changes <= 0.5 * cmds_cold[k].active_set_changes, \
        (entry.active_set_changes, cmds_cold[k].active_set_changes)


def fly_into_docking(p, case, noise_m=0.0):
    """Closed loop until the first docking command; the commands and the guidance right after it."""
    cmds = []
    for _, cmd, g in closed_loop(p, case, 600, noise_m):
        cmds.append(cmd)
        if cmd.phase == fsw.Phase.Docking:
            return cmds, g
    raise AssertionError("never reached the docking phase")


@pytest.mark.parametrize("case,docking_n,noise_m", [(1, 5, 0.0), (1, 12, 0.05), (2, 30, 0.0), (3, 12, 0.05)])
def test_docking_rows_are_ready_before_the_first_docking_solve(case, docking_n, noise_m):
    """The guidance compresses the docking QP's rows for its docking solver in an earlier step (the
    phase's rows depend on the target's attitude alone), so the first docking solve keeps them (a
    turning target's, Case 3, take new values in place): it does not compress its rows itself, where
    a fresh solver given the same QP does. Its plan is the fresh solver's and Clarabel's."""
    p = fsw.GuidanceParams()
    p.docking.N = docking_n
    cmds, g = fly_into_docking(p, case, noise_m)
    first = cmds[-1]
    assert first.status == fsw.StepStatus.Ok and first.solver_status == "solved"
    assert first.iterations == 0 and first.active_set_changes > 0  # the active set answered, cold
    assert not first.rows_compressed
    qp = g.last_qp(fsw.Phase.Docking)
    fresh = fsw.solve_ocp_qp(**qp, tol=1e-8)
    assert fresh.status == "solved" and fresh.rows_compressed
    np.testing.assert_allclose(first.dv_cmd_mps, fresh.u[0], atol=1e-9)
    status, u_ref, _ = solve_clarabel(qp)
    assert status == "Solved"
    u_max = p.docking.u_max_mps
    np.testing.assert_allclose(first.dv_cmd_mps, np.clip(u_ref[0][:3], -u_max, u_max), atol=1e-6)
