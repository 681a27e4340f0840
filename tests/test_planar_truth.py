"""The planar truth (an air-bearing table, Dong, Ghiglino et al.'s eq. 4: m x'' = F_x, m y'' = F_y,
I theta'' = tau) against closed-form motion: free rotation at a constant rate, rotation under a constant
torque held from the burn start, translation under a constant force (finite burn) and an impulse;
and the planar scenario's table-frame states turned into the relative ones."""
import math

import numpy as np
import pytest

from rvd_pil.host_sim import scenario as scenarios
from rvd_pil.host_sim.simulator import Simulator

BASE = {
    "name": "table", "dynamics": "planar", "timeout_s": 100.0,
    "planar": {"target_table": [1.0, 0.5, 30.0, 0.02, -0.01, 2.0], "chaser_table": [3.0, 1.5, 45.0, 0.0, 0.01, 3.0],
               "chaser_inertia_kgm2": 0.25, "torque_max_nm": 0.02},
    "chaser": {"mass_kg": 16.0}, "thrusters": {"force_n": 0.15, "minimum_impulse_bit_s": 0.01},
    "guidance": {},
}


def table(**changes):
    d = {**BASE, **changes}
    return scenarios.from_dict(d, source="test")


def sim(**kw):
    return Simulator(table(), seed=3, sensor_noise=False, thrust_noise=False, **kw)


def test_table_frame_states_become_relative_ones():
    s = table(obstacles=[{"id": 1, "frame": "table", "semi_axes_m": [0.47, 0.47, 0.47],
                          "position_lvlh_m": [2.0, 2.5, 0.0], "velocity_lvlh_mps": [0.0, -0.005, 0.0]}])
    assert s.is_planar
    assert s.chaser.position_lvlh_m == pytest.approx((2.0, 1.0, 0.0))
    assert s.chaser.velocity_lvlh_mps == pytest.approx((-0.02, 0.02, 0.0))
    assert (s.target.initial_angle_deg, s.target.spin_rate_deg_s) == (30.0, 2.0)
    o = s.obstacles[0]
    assert o.position_lvlh_m == pytest.approx((1.0, 2.0, 0.0)) and o.velocity_lvlh_mps == pytest.approx((-0.02, 0.005, 0.0))
    # What stays orbital stays as it was: no planar keys in an orbital scenario's record.
    assert "planar" not in scenarios.load("case1_vbar").to_dict()


@pytest.mark.parametrize("bad, why", [
    ({"chaser": {"mass_kg": 16.0, "position_lvlh_m": [1.0, 0.0, 0.0]}}, "chaser_table"),
    ({"guidance": {"relative_motion": "clohessy_wiltshire"}}, "double_integrator"),
    ({"planar": {**BASE["planar"], "torque_max_nm": 0.0}}, "torque_max_nm"),
    ({"obstacles": [{"id": 1, "semi_axes_m": [0.3, 0.3, 0.3], "position_lvlh_m": [0.0, 1.5, 0.0], "motion": "cw"}]},
     "constant velocity"),
])
def test_a_planar_scenario_that_contradicts_itself_is_refused_in_one_line(bad, why):
    with pytest.raises(scenarios.ScenarioError, match=why):
        table(**bad)


def test_free_rotation_at_a_constant_rate_and_free_translation():
    s = sim(impulsive=True)
    assert s.truth == "planar" and s.mean_motion_rad_s == 0.0
    x0 = s.truth_lvlh()
    for _ in range(7):
        s.apply_command(np.zeros(6), 2.0)
    t = 14.0
    angle, rate = s.chaser_attitude()
    assert angle == pytest.approx(math.radians(45.0 + 3.0 * t), abs=1e-12)
    assert rate == pytest.approx(math.radians(3.0), abs=1e-15)
    assert s.truth_lvlh() == pytest.approx(np.r_[x0[:3] + t * x0[3:], x0[3:]], abs=1e-12)


def test_rotation_under_a_torque_held_from_the_burn_start():
    s = sim()
    tau, period, delay = 0.015, 2.0, 0.3
    r = s.apply_command(np.zeros(6), period, delay_s=delay, torque_nm=tau)
    alpha = tau / 0.25
    w0, a0 = math.radians(3.0), math.radians(45.0)
    burn = period - delay
    assert r.attitude_after[1] == pytest.approx(w0 + alpha * burn, rel=1e-14)
    assert r.attitude_after[0] == pytest.approx(a0 + w0 * period + 0.5 * alpha * burn ** 2, rel=1e-14)
    with pytest.raises(ValueError, match="torque_nm"):
        s.apply_command(np.zeros(6), period, torque_nm=0.021)  # beyond the scenario's 0.02 N m


def test_translation_under_a_constant_force_and_under_an_impulse():
    pulse, period, F, m = 1.5, 2.0, 0.15, 16.0
    s = sim()
    x0 = s.truth_lvlh()
    s.apply_command([pulse, 0, 0, 0, 0, 0], period)  # +x thruster for 1.5 s of 2 s
    a = F / m
    expect_x = x0[0] + x0[3] * period + 0.5 * a * pulse ** 2 + a * pulse * (period - pulse)
    assert s.truth_lvlh()[0] == pytest.approx(expect_x, abs=1e-13)
    assert s.truth_lvlh()[3] == pytest.approx(x0[3] + a * pulse, abs=1e-15)
    i = sim(impulsive=True)
    i.apply_command([0, 0, 0, pulse, 0, 0], period)  # -y, as one impulse at the period start
    assert i.truth_lvlh()[1] == pytest.approx(x0[1] + (x0[4] - a * pulse) * period, abs=1e-13)


def test_the_planar_truth_is_the_only_truth_of_a_planar_scenario():
    assert Simulator(table(), truth="nonlinear").truth == "planar"
    with pytest.raises(ValueError, match="planar scenario"):
        Simulator(scenarios.load("case1_vbar"), truth="planar")
    with pytest.raises(ValueError, match="planar truth only"):
        Simulator(scenarios.load("case1_vbar"), truth="cw").apply_command(np.zeros(6), 30.0, torque_nm=0.01)


def test_the_attitude_sensor_reports_the_chaser_angle_with_its_noise():
    d = {**BASE, "planar": {**BASE["planar"], "sigma_angle_deg": 0.5, "sigma_rate_deg_s": 0.0}}
    errors = []
    for seed in range(400):
        s = Simulator(scenarios.from_dict(d, source="test"), seed=seed, thrust_noise=False)
        m = s.measure()
        q = m.chaser_q_lvlh
        assert q[1] == 0.0 and q[2] == 0.0 and m.chaser_omega_rad_s[2] == pytest.approx(math.radians(3.0))
        errors.append(2.0 * math.atan2(q[3], q[0]) - math.radians(45.0))
    assert np.std(errors) == pytest.approx(math.radians(0.5), rel=0.15)
    # Switching the attitude noise on leaves the position noise's draws as they were.
    quiet = Simulator(table(), seed=7, thrust_noise=False).measure()
    noisy = Simulator(scenarios.from_dict(d, source="test"), seed=7, thrust_noise=False).measure()
    assert np.array_equal(quiet.position_lvlh_m, noisy.position_lvlh_m)
