"""Safety of the guidance step through the Python binding: NaN/Inf or absurd navigation input, an infeasible
QP and a spent time budget give a safe action and a status saying why; nothing ever commands NaN."""
import math

import numpy as np
import pytest

from rvd_pil import flight_sw as fsw
from support.guidance_geometry import VBAR

FAR = np.array([140.0, -1580.0, 60.0, -0.9, -0.32, 0.0])


def finite_and_bounded(cmd, p):
    u_max = p.phase(cmd.phase).u_max_mps
    assert np.all(np.isfinite(cmd.dv_cmd_mps)) and np.all(np.isfinite(cmd.dv_alloc_mps))
    assert np.all(np.isfinite(cmd.pulse_s)) and np.all(cmd.pulse_s >= 0)
    assert np.abs(cmd.dv_cmd_mps).max() <= u_max + 1e-12
    assert cmd.pulse_s.max() <= fsw.max_pulse_s(u_max, p.thrusters) + 1e-12


@pytest.mark.parametrize("bad", [
    [math.nan, -1580, 60, -0.9, -0.32, 0],
    [140, -1580, 60, -0.9, math.inf, 0],
    [2e6, -1580, 60, -0.9, -0.32, 0],        # 2000 km: not a relative state of this mission
    [140, -1580, 60, 400.0, -0.32, 0],       # 400 m/s
], ids=["nan", "inf", "far", "fast"])
def test_invalid_state_without_a_plan_gives_zero_thrust(bad):
    p = fsw.GuidanceParams()
    g = fsw.Guidance(p)
    cmd = g.step(fsw.NavInput(0, 0.0, bad, VBAR))
    assert cmd.status == fsw.StepStatus.InvalidState
    assert cmd.fallback == fsw.Fallback.ZeroThrust
    assert not np.any(cmd.dv_cmd_mps) and not np.any(cmd.pulse_s)
    assert not cmd.solved and cmd.solver_status == "not_run"  # (not a solver's verdict on the input)
    finite_and_bounded(cmd, p)


def test_invalid_state_after_a_solve_uses_the_shifted_plan():
    p = fsw.GuidanceParams()
    g = fsw.Guidance(p)
    first = g.step(fsw.NavInput(0, 0.0, FAR, VBAR))
    assert first.status == fsw.StepStatus.Ok
    plan = [np.clip(u[:3], -p.rendezvous.u_max_mps, p.rendezvous.u_max_mps) for u in fsw.solve_ocp_qp(
        **fsw.build_phase_qp(p, fsw.Phase.Rendezvous, FAR, VBAR), max_iter=300).u[:3]]
    np.testing.assert_allclose(first.dv_cmd_mps, plan[0], atol=1e-6)
    for k in (1, 2):
        cmd = g.step(fsw.NavInput(k, 30.0 * k, [math.nan] * 6, VBAR))
        assert cmd.status == fsw.StepStatus.InvalidState and cmd.fallback == fsw.Fallback.ShiftedPlan
        assert cmd.plan_age == k
        np.testing.assert_allclose(cmd.dv_cmd_mps, plan[k], atol=1e-6)


def test_bad_attitude_is_invalid():
    g = fsw.Guidance(fsw.GuidanceParams())
    assert g.step(fsw.NavInput(0, 0.0, FAR, [0.3, 0, 0, 0])).status == fsw.StepStatus.InvalidState
    assert g.step(fsw.NavInput(0, 0.0, FAR, [math.nan, 0, 0, 1])).status == fsw.StepStatus.InvalidState
    assert g.step(fsw.NavInput(0, 0.0, FAR, VBAR, [0, 0, 5.0])).status == fsw.StepStatus.InvalidState


def test_infeasible_qp_is_recovered_or_falls_back():
    x = [0, -40, 0, 0, 2.0, 0]  # through the overshoot plane next period, whatever the thrusters do
    p = fsw.GuidanceParams()
    g = fsw.Guidance(p)
    g.reset(fsw.Phase.Approach)
    cmd = g.step(fsw.NavInput(0, 0.0, x, VBAR))
    assert cmd.solver_status == "infeasible"
    assert cmd.status == fsw.StepStatus.Recovered and cmd.recovery_status == "solved"
    assert cmd.dv_cmd_mps[1] == pytest.approx(-p.approach.u_max_mps)  # full braking along the axis
    finite_and_bounded(cmd, p)
    p.recovery = False
    g = fsw.Guidance(p)
    g.reset(fsw.Phase.Approach)
    cmd = g.step(fsw.NavInput(0, 0.0, x, VBAR))
    assert cmd.solver_status == "infeasible" and cmd.status == fsw.StepStatus.ZeroThrust
    assert not np.any(cmd.dv_cmd_mps)


def test_time_budget_spent_gives_the_shifted_plan():
    g = fsw.Guidance(fsw.GuidanceParams())
    assert g.step(fsw.NavInput(0, 0.0, FAR, VBAR)).status == fsw.StepStatus.Ok
    cmd = g.step(fsw.NavInput(1, 30.0, FAR, VBAR), time_limit_us=1e-3)
    assert cmd.solver_status == "time_limit" and cmd.status == fsw.StepStatus.ShiftedPlan


def test_garbage_stream_never_yields_nan_or_a_crash():
    rng = np.random.default_rng(7)
    p = fsw.GuidanceParams()
    g = fsw.Guidance(p)
    specials = [math.nan, math.inf, -math.inf, 1e300, -1e300, 0.0]
    statuses = set()
    for k in range(150):
        x = np.r_[rng.uniform(-3000, 3000, 3), rng.normal(0, 1, 3)]
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        w = rng.normal(0, 0.01, 3)
        roll = rng.random()
        if roll < 0.2:
            x[rng.integers(6)] = rng.choice(specials)
        elif roll < 0.3:
            q = rng.normal(size=4) * rng.choice([0.0, 2.0, math.nan])
        elif roll < 0.4:
            x *= 1e4
        cmd = g.step(fsw.NavInput(k, 30.0 * k, x, q, w), time_limit_us=float(rng.choice([0.0, 1.0, 5e4])))
        finite_and_bounded(cmd, p)
        statuses.add(cmd.status)
    assert fsw.StepStatus.InvalidState in statuses and fsw.StepStatus.Ok in statuses


def test_bad_parameters_raise_value_error():
    p = fsw.GuidanceParams()
    p.approach.u_max_mps = -1.0
    p.keepout_radius_m = math.nan
    with pytest.raises(ValueError, match="approach.u_max_mps") as e:
        fsw.Guidance(p)
    assert "keepout_radius_m" in str(e.value)
    with pytest.raises(ValueError):
        fsw.run_closed_loop(p, FAR)


def test_the_approach_entry_counts_the_motion_of_a_turning_corridor():
    """With the entry braking check on, the rendezvous hands over only when the approach can stop the
    motion towards each corridor face. The faces turn with the target (Case 3: 0.15 deg/s about body z, the
    corridor along LVLH +y), so the motion that counts is v - omega x rho: a chaser at rest 194 m out and
    about 9 m inside the face the turning corridor sweeps towards it must wait; at rest before a still
    target, or moving with the turning corridor, it enters."""
    case = fsw.dissertation_case(3)
    q, omega = case["q_lvlh_body"], case["omega_body_rad_s"]
    p = fsw.GuidanceParams()
    p.margins.approach_entry_brake_fraction = 0.5
    rho = np.array([40.0, 190.0, 0.0])
    with_corridor = np.cross(omega, rho)  # body z is LVLH z in this attitude
    assert np.linalg.norm(with_corridor) > 0.5  # m/s: more than the approach can stop within 9 m at half its authority

    def phase_after_one_step(v, rate):
        return fsw.Guidance(p).step(fsw.NavInput(0, 0.0, np.r_[rho, v], q, rate)).phase

    assert phase_after_one_step(np.zeros(3), omega) == fsw.Phase.Rendezvous
    assert phase_after_one_step(np.zeros(3), np.zeros(3)) == fsw.Phase.Approach
    assert phase_after_one_step(with_corridor, omega) == fsw.Phase.Approach
    assert phase_after_one_step(-with_corridor, np.zeros(3)) == fsw.Phase.Rendezvous  # the same relative motion
