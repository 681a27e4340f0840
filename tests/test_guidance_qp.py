"""The phase QP builders checked independently: each QP solved by ProxSuite (dense, from the lists the
builder returns) gives the same first delta-v as the Fast MPC solver and as the Guidance step itself,
and the constraint rows match geometry computed here (keep-out normals, pyramid faces, port)."""
import math

import numpy as np
import pytest

from rvd_pil import flight_sw as fsw
from rvd_pil.bench.noisy_loops import noisy_loop
from rvd_pil.host_sim.frames import quaternion_after
from support.guidance_geometry import DEG, RBAR, VBAR, in_pyramid, rotate, solve_clarabel, solve_proxsuite
from support.qp_forms import from_dict

# ---------------------------------------------------------------- the QPs checked
SPIN = np.array([0, 0, 0.25 * DEG])
ZERO = np.zeros(3)


def variant(**kw):
    p = fsw.GuidanceParams()
    for k, v in kw.items():
        obj = p
        *path, last = k.split("__")
        for part in path:
            obj = getattr(obj, part)
        setattr(obj, last, v)
    return p


CASES = [  # (id, params, phase, x, q, omega)
    ("rdv_far_vbar", variant(), fsw.Phase.Rendezvous, [140, -1580, 60, -0.9, -0.32, 0], VBAR, ZERO),
    ("rdv_far_rbar", variant(), fsw.Phase.Rendezvous, [140, -1580, 60, -0.9, -0.32, 0], RBAR, ZERO),
    ("rdv_sphere_side", variant(), fsw.Phase.Rendezvous, [-180, 150, 30, 0.4, 0.3, 0], VBAR, ZERO),
    ("rdv_rotating", variant(), fsw.Phase.Rendezvous, [300, -700, 0, -0.2, 0.4, 0], VBAR, SPIN),
    ("rdv_no_setpoint", variant(rendezvous_use_setpoint=False), fsw.Phase.Rendezvous, [-600, 900, 50, 0, 0, 0], VBAR, ZERO),
    ("rdv_N45_dare", variant(rendezvous__N=45, rendezvous__terminal_weight=fsw.TerminalWeight.Dare),
     fsw.Phase.Rendezvous, [140, -1580, 60, -0.9, -0.32, 0], VBAR, ZERO),
    ("app_vbar", variant(), fsw.Phase.Approach, [12, -190, 5, -0.05, 0.4, 0], VBAR, ZERO),
    ("app_rbar_N5", variant(approach__N=5), fsw.Phase.Approach, [150, 20, -4, -0.3, 0.1, 0], RBAR, ZERO),
    ("app_rotating_N30", variant(approach__N=30), fsw.Phase.Approach, [60, -170, 0, 0.2, 0.6, 0], VBAR, SPIN),
    ("dock_vbar", variant(), fsw.Phase.Docking, [0.5, -29, 0.3, 0.0, 0.02, 0], VBAR, ZERO),
    ("dock_rotating_N30", variant(docking__N=30), fsw.Phase.Docking, [1.0, -25, 0.0, 0.06, 0.05, 0], VBAR, SPIN),
]


@pytest.mark.parametrize("cid,params,phase,x,q,w", CASES, ids=[c[0] for c in CASES])
def test_first_input_agrees_with_proxsuite_fast_mpc_and_the_guidance(cid, params, phase, x, q, w):
    qp = fsw.build_phase_qp(params, phase, x, q, w)
    status, u_ref, _ = solve_proxsuite(qp)
    assert status == "PROXQP_SOLVED"
    fast = fsw.solve_ocp_qp(**qp, max_iter=300)
    assert fast.status == "solved"
    np.testing.assert_allclose(fast.u[0][:3], u_ref[0][:3], atol=1e-6)
    # The guidance builds the same QP internally: its command is the same first delta-v (clipped to the box).
    g = fsw.Guidance(params)
    g.reset(phase)
    cmd = g.step(fsw.NavInput(0, 0.0, x, q, w))
    if cmd.status == fsw.StepStatus.Ok:
        u_max = params.phase(phase).u_max_mps
        np.testing.assert_allclose(cmd.dv_cmd_mps, np.clip(u_ref[0][:3], -u_max, u_max), atol=1e-6)
    else:  # the guidance's own solver did not converge here: it must say so, not fake a command
        assert cmd.status in (fsw.StepStatus.ShiftedPlan, fsw.StepStatus.ZeroThrust)


def test_one_norm_rendezvous_is_an_lp_with_the_same_answer():
    p = variant(rendezvous_objective=fsw.RendezvousObjective.OneNorm)
    x = [140, -1580, 60, -0.9, -0.32, 0]
    qp = fsw.build_phase_qp(p, fsw.Phase.Rendezvous, x, VBAR)
    assert all(not np.any(Q) for Q in qp["Q"]) and all(not np.any(R) for R in qp["R"])
    status, u_ref, x_ref = solve_proxsuite(qp)
    assert status == "PROXQP_SOLVED"
    fast = fsw.solve_ocp_qp(**qp, max_iter=300)
    assert fast.status == "solved"
    # An LP may have several optima: compare the objectives (|Q e|_1 + |R u|_1 + cone penalty) of both.
    lp = from_dict(qp)
    assert lp.objective(fast.x, fast.u) == pytest.approx(lp.objective(np.vstack(x_ref), u_ref), rel=1e-6)
    assert np.abs(fast.u[0][:3]).max() <= p.rendezvous.u_max_mps + 1e-9


def test_recovery_qp_is_always_feasible_and_agrees_with_clarabel():
    # 40 m out on the V-bar closing at 2 m/s: the approach QP's overshoot plane cannot hold.
    p = fsw.GuidanceParams()
    x = [0, -40, 0, 0, 2.0, 0]
    nominal = fsw.build_phase_qp(p, fsw.Phase.Approach, x, VBAR)
    assert fsw.solve_ocp_qp(**nominal).status == "infeasible"
    assert solve_clarabel(nominal)[0] == "PrimalInfeasible"
    b = fsw.PhaseQp(fsw.Phase.Approach, p, recovery=True)
    qp = b.build(x, VBAR)
    status, u_ref, _ = solve_clarabel(qp)
    assert status == "Solved"
    fast = fsw.solve_ocp_qp(**qp, max_iter=400)
    assert fast.status == "solved"
    np.testing.assert_allclose(fast.u[0][:3], u_ref[0][:3], atol=1e-5)
    assert u_ref[0][1] == pytest.approx(-p.approach.u_max_mps, abs=1e-6)  # brakes along the axis at the limit


# ---------------------------------------------------------------- constraint rows against geometry
def test_keepout_normals_unit_and_turning_at_most_n_ts_per_step_towards_the_axis():
    p = fsw.GuidanceParams()
    n_ts = p.mean_motion_rad_s() * p.rendezvous.Ts_s
    for x, q, w in [([140, -1580, 60, -0.9, -0.32, 0], RBAR, ZERO), ([-250, 40, 0, 0, 0, 0], VBAR, ZERO),
                    ([300, -700, 0, -0.2, 0.4, 0], VBAR, SPIN), ([-120, -190, 0, 0, 0, 0], VBAR, ZERO)]:
        b = fsw.PhaseQp(fsw.Phase.Rendezvous, p)
        qp = b.build(x, q, w)
        normals = [np.asarray(x[:3]) / np.linalg.norm(x[:3])]
        for i in range(1, b.N + 1):
            row = b.keepout_row(i)
            nrm = -qp["C"][i][row, :3]
            assert np.linalg.norm(nrm) == pytest.approx(1.0, abs=1e-12)
            assert not np.any(qp["C"][i][row, 3:]) and not np.any(qp["D"][i][row])
            assert qp["d"][i][row] == pytest.approx(-min(p.keepout_radius_m, np.linalg.norm(x[:3])))
            normals.append(nrm)
        steps = [math.acos(min(1.0, a @ c)) for a, c in zip(normals, normals[1:])]
        assert max(steps) <= n_ts + 1e-12
        assert max(steps) - min(steps) < 1e-9  # equal steps
        # The normals turn in one plane (about one axis), towards the cone axis at t_N.
        axis_N = rotate(quaternion_after(q, w, b.N * b.Ts_s), [1.0, 0, 0])
        angle_to_axis = [math.acos(np.clip(v @ axis_N, -1, 1)) for v in normals]
        if b.keepout_natural_way:
            assert b.keepout_rotation_axis[2] < 0  # natural relative motion circulates about -z
        else:
            assert all(a2 <= a1 + 1e-12 for a1, a2 in zip(angle_to_axis, angle_to_axis[1:]))
        if b.keepout_total_rad <= b.N * n_ts:  # reachable within the horizon: the last plane is the axis
            np.testing.assert_allclose(normals[-1], axis_N, atol=1e-9)


def test_keepout_planes_do_not_swing_between_periods_on_a_noisy_start_opposite_the_port():
    """Case 1 starts on -y, opposite its +y port: every great circle to the axis is about as short, and the
    short way's turn (u0 x axis) swung by 35-80 degrees between periods with the noise on the chaser's few
    metres of x and z at 1.5 km, moving every keep-out plane of the plan (the interior point then needed
    twice its usual iterations). In closed loops with sensor noise and thrust error (CW plant) the planes'
    turn must move little from one period to the next while the axis is out of reach."""
    p = fsw.GuidanceParams()
    rows = fsw.PhaseQp(fsw.Phase.Rendezvous, p)
    cap = p.keepout_rate_cap_factor * p.mean_motion_rad_s() * p.rendezvous.Ts_s
    largest, periods = 0.0, 0
    for seed in range(4):
        previous = None
        for _, g, cmd in noisy_loop(1, (p.rendezvous.N, p.approach.N, p.docking.N), seed, 0.02, 0.03):
            if cmd.phase != fsw.Phase.Rendezvous:
                break
            qp = g.last_qp(fsw.Phase.Rendezvous)
            n1, n2 = (-np.asarray(qp["C"][i])[rows.keepout_row(i), :3] for i in (1, 2))
            turn = np.cross(n1, n2)
            at_cap = np.linalg.norm(turn) >= math.sin(0.99 * cap)  # out of reach: the planes turn at the cap
            if at_cap and previous is not None:
                largest = max(largest, math.degrees(math.acos(np.clip(turn @ previous / np.linalg.norm(turn), -1, 1))))
                periods += 1
            previous = turn / np.linalg.norm(turn) if at_cap else None
    assert periods >= 80  # the loops turned the planes at the cap for most of their rendezvous
    assert largest < 15.0, largest


@pytest.mark.parametrize("phase,half_deg", [(fsw.Phase.Rendezvous, 15.0), (fsw.Phase.Approach, 15.0), (fsw.Phase.Docking, 8.0)])
@pytest.mark.parametrize("q,w", [(VBAR, ZERO), (RBAR, ZERO), (VBAR, SPIN)], ids=["vbar", "rbar", "spin"])
def test_cone_rows_contain_the_axis_and_cut_at_the_half_angle(phase, half_deg, q, w):
    p = fsw.GuidanceParams()
    b = fsw.PhaseQp(phase, p)
    qp = b.build([5.0, -100.0, 3.0, 0, 0, 0], q, w)
    stages = [b.N] if phase == fsw.Phase.Rendezvous else range(1, b.N + 1)
    for i in stages:
        qi = quaternion_after(q, w, i * b.Ts_s)
        axis = rotate(qi, [1.0, 0, 0])
        apex = rotate(qi, np.asarray(p.port_body_m)) if phase == fsw.Phase.Docking else np.zeros(3)
        r0 = b.cone_row(i)
        H, d = qp["C"][i][r0:r0 + 4, :3], qp["d"][i][r0:r0 + 4]
        if phase != fsw.Phase.Docking:
            d = np.zeros(4)  # soft: H rho - s <= 0
        np.testing.assert_allclose(np.linalg.norm(H, axis=1), 1.0, atol=1e-12)
        assert np.all(H @ (apex + 50 * axis) - d < 0)  # the axis is inside
        assert np.all(H @ axis <= -math.sin(half_deg * DEG) + 1e-12)
        for side in (rotate(qi, [0, 1.0, 0]), rotate(qi, [0, 0, 1.0])):
            for sgn in (1, -1):
                for ang, inside in ((half_deg - 0.5, True), (half_deg + 0.5, False)):
                    pt = apex + 50 * (math.cos(ang * DEG) * axis + sgn * math.sin(ang * DEG) * side)
                    assert (np.max(H @ pt - d) <= 0) == inside
                    assert in_pyramid(qi, pt - apex, half_deg * DEG) == inside


def test_docking_tracks_the_rotating_port_and_bounds_velocity():
    p = fsw.GuidanceParams()
    b = fsw.PhaseQp(fsw.Phase.Docking, p)
    qp = b.build([1.0, -25, 0.0, 0.06, 0.05, 0], VBAR, SPIN)
    ref = np.asarray(b.reference)
    for i in range(b.N + 1):
        qi = quaternion_after(VBAR, SPIN, i * b.Ts_s)
        aim = rotate(qi, [0.5 + p.docking_setpoint_offset_m, 0, 0])  # no margins: the cone's apex is the port
        np.testing.assert_allclose(ref[i, :3], aim, atol=1e-12)
        np.testing.assert_allclose(ref[i, 3:], np.cross(rotate(VBAR, SPIN), aim), atol=1e-12)
        np.testing.assert_allclose(qp["q"][i], -qp["Q"][i] @ ref[i], atol=1e-9)
        if i >= 1:
            v = b.velocity_row(i)
            np.testing.assert_array_equal(qp["C"][i][v:v + 3, 3:], np.eye(3))
            np.testing.assert_array_equal(qp["C"][i][v + 3:v + 6, 3:], -np.eye(3))
            np.testing.assert_array_equal(qp["d"][i][v:v + 6], p.v_max_mps)


def test_the_docking_set_point_lies_inside_the_tightened_cone_and_the_plan_does_not_end_on_its_apex():
    """With a margin m the docking cone's rows H (rho - port) <= -m meet at an apex m / sin(8 deg) out along
    the axis, so the port itself lies outside them. The set point is docking_setpoint_offset_m beyond that
    apex, capped at 90 % of r3 (the docked distance). Planned from 1.2 m out and 2 cm off the axis, with
    ProxSuite: the plan ends inside r3 with at most one facet row tight on its last stages. Aimed at the apex instead
    (offset 0) the plan ends on it with all four facet rows tight on every late stage: four rows on three
    coordinates, which made the active set churn near the port."""
    half = 8.0 * DEG
    for margin, offset, expected_aim in ((0.0, 0.3, 0.3), (0.03, 0.1, 0.03 / math.sin(half) + 0.1),
                                         (0.04, 0.3, 0.45), (0.03, 0.0, 0.03 / math.sin(half))):
        p = variant(docking__N=30)
        p.margins.docking_cone_m = margin
        p.docking_setpoint_offset_m = offset
        b = fsw.PhaseQp(fsw.Phase.Docking, p)
        x0 = [0.02, -(0.5 + 1.2), 0.0, 0.0, 0.01, 0.0]  # VBAR: docking axis along LVLH -y, port at -0.5 y
        qp = b.build(x0, VBAR)
        port = rotate(VBAR, [0.5, 0, 0])
        axis = rotate(VBAR, [1.0, 0, 0])
        ref = np.asarray(b.reference)
        np.testing.assert_allclose(ref[:, :3], np.tile(port + expected_aim * axis, (b.N + 1, 1)), atol=1e-12)
        assert expected_aim <= 0.9 * p.dock_tolerance_m + 1e-12
        status, u, x = solve_proxsuite(qp)
        assert status == "PROXQP_SOLVED"
        last = range(b.N - 5, b.N + 1)
        slack = [-(np.asarray(qp["C"][i])[b.cone_row(i):b.cone_row(i) + 4] @ x[i]
                   - np.asarray(qp["d"][i])[b.cone_row(i):b.cone_row(i) + 4]) for i in last]
        tight = [int(np.sum(np.abs(s) < 1e-6)) for s in slack]
        if offset > 0:
            assert max(tight) <= 1, (margin, offset, tight)  # at most one facet holds it, not the apex
            assert np.linalg.norm(x[b.N][:3] - port) < p.dock_tolerance_m  # the plan docks on its way in
        else:
            assert tight[-5:] == [4] * 5, (margin, offset, tight)  # all four facets tight: on the apex


def test_the_docking_plan_stops_at_the_stop_plane_instead_of_coasting_into_the_tightened_apex():
    """The dissertation's docking weights (R / Q = 5e4) make braking dear and the set point cheap: from 0.6 m
    out, closing at 1.9 cm/s, 2.7 cm off the axis, with a 4.5 cm cone margin (the flight's usual), the plan
    without the stop plane coasts past the set point into the apex of the tightened cone (0.045 / sin 8 deg
    = 0.323 m from the port) and stops there on the facets, all four tight on a stage. With the plane (the
    default) it stops on the set point, docking_setpoint_offset_m beyond the apex, the plane's row holding
    it, with at most two facets tight on a stage (a corner of the cone's cut by the plane), never the
    apex. Solved by ProxSuite, so the behaviour is the QP's, not the solver's."""
    port, axis = rotate(VBAR, [0.5, 0, 0]), rotate(VBAR, [1.0, 0, 0])
    apex = 0.045 / math.sin(8.0 * DEG)
    aim = apex + fsw.GuidanceParams().docking_setpoint_offset_m
    x0 = [-0.011, -(0.5 + 0.6), -0.025, 0.0, 0.019, 0.0]  # VBAR: the docking axis is LVLH -y
    ends = {}
    for penalty in (1e4, 0.0):
        p = fsw.GuidanceParams()
        p.margins.docking_cone_m = 0.045
        p.docking_stop_penalty = penalty
        b = fsw.PhaseQp(fsw.Phase.Docking, p)
        qp = b.build(x0, VBAR)
        status, _, x = solve_proxsuite(qp)
        assert status == "PROXQP_SOLVED"
        axial = np.array([(np.asarray(x[i][:3]) - port) @ axis for i in range(b.N + 1)])
        tight = []
        for i in range(1, b.N + 1):
            c = b.cone_row(i)
            slack = np.asarray(qp["d"][i])[c:c + 4] - np.asarray(qp["C"][i])[c:c + 4] @ x[i]
            tight.append(int(np.sum(slack < 1e-6)))
        ends[penalty] = (axial, tight)
        if penalty > 0:
            on_plane = [abs(np.asarray(qp["C"][i])[b.stop_row(i)] @ x[i] - np.asarray(qp["d"][i])[b.stop_row(i)])
                        < 1e-8 for i in range(1, b.N + 1)]
            assert any(on_plane), on_plane  # the plane's row stops the plan (it then floats within 1 mm of it)
        else:
            assert b.stop_row(b.N) == -1
    axial, tight = ends[1e4]
    assert axial.min() > aim - 1e-3 and abs(axial[-1] - aim) < 1e-3, axial
    assert max(tight) <= 2, tight
    axial, tight = ends[0.0]
    assert abs(axial[-1] - apex) < 2e-3, axial  # coasted onto the tightened apex
    assert max(tight) >= 3, tight


def test_bad_input_to_the_builder_is_refused():
    p = fsw.GuidanceParams()
    with pytest.raises(ValueError):
        fsw.build_phase_qp(p, fsw.Phase.Docked, [0, -10, 0, 0, 0, 0])
    with pytest.raises(ValueError):
        fsw.build_phase_qp(p, fsw.Phase.Approach, [0, float("nan"), 0, 0, 0, 0])
    with pytest.raises(ValueError):
        fsw.build_phase_qp(p, fsw.Phase.Approach, [0, -10, 0, 0, 0, 0], [0, 0, 0, 0])
    p.docking.N = 0
    with pytest.raises(ValueError, match="docking.N"):
        fsw.build_phase_qp(p, fsw.Phase.Docking, [0, -10, 0, 0, 0, 0])
