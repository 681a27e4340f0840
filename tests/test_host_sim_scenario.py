"""Scenarios (TOML files, validation, the Monte Carlo generator) and the target attitude/port."""

import dataclasses
import math

import numpy as np
import pytest
from scipy import stats
from scipy.linalg import expm

from rvd_pil.host_sim import constants as k
from rvd_pil.host_sim.scenario import ScenarioError, available, from_toml, load, random_scenario
from rvd_pil.host_sim.simulator import Simulator


def rotate(q, v):
    """v rotated by unit quaternion q = (w, x, y, z): q (0, v) q*, Hamilton product written out."""
    w, x, y, z = q
    u = np.array([x, y, z])
    return v + 2.0 * np.cross(u, np.cross(u, v) + w * v)


def test_shipped_scenarios_hold_table_3_2_and_the_case_geometry():
    assert {"case1_vbar", "case2_rbar", "case3_rotating"} <= set(available())
    # sec. 3.6.1: the cones' axis "along the velocity (y-axis) direction"; Case 3 starts like Case 1.
    expected_port = {"case1_vbar": (0.0, 0.5, 0.0), "case2_rbar": (0.5, 0.0, 0.0), "case3_rotating": (0.0, 0.5, 0.0)}
    for name, port in expected_port.items():
        s = load(name)
        assert s.chaser.position_lvlh_m == (140.0, -1580.0, 60.0)
        assert s.chaser.velocity_lvlh_mps == (-0.90, -0.32, 0.0)
        assert s.timeout_s == 200 * 60
        assert (s.chaser.mass_kg, s.target.mass_kg, s.chaser.drag_coefficient, s.target.drag_coefficient) == (14, 14, 1.4, 2.0)
        assert s.thrusters.force_n == 0.5 and s.thrusters.minimum_impulse_bit_s == 0.010
        assert s.thrust_error.eta_w == pytest.approx(3 / math.sqrt(600), rel=1e-15)
        target = Simulator(s).target_state()
        np.testing.assert_allclose(target.port_position_lvlh_m, port, atol=1e-15)
        np.testing.assert_allclose(rotate(target.q_lvlh_body, np.array([0.5, 0.0, 0.0])), port, atol=1e-15)
    assert load("case3_rotating").target.spin_rate_deg_s == 0.15


def test_rotating_target_port_turns_at_the_spin_rate_with_consistent_velocity():
    sim = Simulator("case3_rotating", truth="cw", thrust_noise=False, sensor_noise=False)
    omega = math.radians(0.15)
    # after 600 s at 0.15 deg/s the port has turned by 90 deg about +z, from +y to -x
    sim.advance(600.0)
    state = sim.target_state()
    np.testing.assert_allclose(state.port_position_lvlh_m, [-0.5, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(state.omega_body_rad_s, [0.0, 0.0, omega], rtol=1e-15)
    assert np.linalg.norm(state.q_lvlh_body) == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_allclose(rotate(state.q_lvlh_body, np.array([0.5, 0.0, 0.0])), state.port_position_lvlh_m,
                               atol=1e-15)
    # velocity = derivative of position (central difference)
    h = 1e-3
    p_plus = sim.target_state(sim.t_s + h).port_position_lvlh_m
    p_minus = sim.target_state(sim.t_s - h).port_position_lvlh_m
    np.testing.assert_allclose(state.port_velocity_lvlh_mps, (p_plus - p_minus) / (2 * h), atol=1e-11)
    # measurement carries the same attitude
    m = sim.measure()
    np.testing.assert_array_equal(m.q_lvlh_body, state.q_lvlh_body)
    # range to the port vs to the CoM
    rho = sim.truth_lvlh()[0:3]
    assert sim.range_to_com_m() == pytest.approx(np.linalg.norm(rho), rel=1e-15)
    assert sim.range_to_port_m() == pytest.approx(np.linalg.norm(rho - [-0.5, 0, 0]), rel=1e-15)


def test_load_from_path_and_clear_errors(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text('name = "mine"\n[orbit]\naltitude_m = 400e3\n[chaser]\nposition_lvlh_m = [0.0, -300.0, 0.0]\n')
    s = load(path)
    assert s.name == "mine" and s.orbit.altitude_m == 400e3 and s.chaser.position_lvlh_m == (0.0, -300.0, 0.0)
    assert s.chaser.velocity_lvlh_mps == (-0.90, -0.32, 0.0)  # defaults for what is left out
    assert load(str(path)).orbit.mean_motion_rad_s == pytest.approx(math.sqrt(k.MU_EARTH_M3_S2 / (k.R_EARTH_M + 400e3) ** 3))

    with pytest.raises(ScenarioError, match="available: .*case1_vbar"):
        load("case9")
    with pytest.raises(ScenarioError, match="does not exist"):
        load(tmp_path / "missing.toml")
    with pytest.raises(ScenarioError, match=r"unknown key\(s\) \['altitude'\]"):
        from_toml('name = "x"\n[orbit]\naltitude = 5e5\n')
    with pytest.raises(ScenarioError, match="unknown key"):
        from_toml('name = "x"\n[orbitt]\naltitude_m = 5e5\n')
    with pytest.raises(ScenarioError, match="list of 3 numbers"):
        from_toml('name = "x"\n[chaser]\nposition_lvlh_m = [1.0, 2.0]\n')
    with pytest.raises(ScenarioError, match="mass_kg must be > 0"):
        from_toml('name = "x"\n[target]\nmass_kg = 0.0\n')
    with pytest.raises(ScenarioError, match="expected a number"):
        from_toml('name = "x"\ntimeout_s = "long"\n')
    with pytest.raises(ScenarioError, match="missing 'name'"):
        from_toml('timeout_s = 5.0\n')
    with pytest.raises(ScenarioError, match="not valid TOML"):
        from_toml('name = \n')


def test_random_scenarios_follow_the_monte_carlo_distribution():
    base = load("case1_vbar")
    n = base.orbit.mean_motion_rad_s
    scenarios = [random_scenario(seed, base=base) for seed in range(2000)]
    pos = np.array([s.chaser.position_lvlh_m for s in scenarios])
    vel = np.array([s.chaser.velocity_lvlh_mps for s in scenarios])
    rng_m = np.linalg.norm(pos, axis=1)
    assert rng_m.min() >= 150.0 and rng_m.max() <= 2500.0
    assert stats.kstest(rng_m, stats.uniform(150.0, 2350.0).cdf).pvalue > 1e-3  # uniform range
    unit = pos / rng_m[:, None]
    assert np.all(np.abs(unit.mean(axis=0)) < 0.06)  # isotropic: mean direction ~ 0 (sd 0.013)
    np.testing.assert_allclose((unit**2).mean(axis=0), 1 / 3, atol=0.03)
    # stable relative orbit velocity, written here from the CW closed-orbit conditions
    stable = np.column_stack((0.5 * n * pos[:, 1], -2.0 * n * pos[:, 0], np.zeros(len(pos))))
    perturbation = vel - stable
    np.testing.assert_allclose(perturbation.std(axis=0), 0.5, rtol=0.05)
    assert np.all(np.abs(perturbation.mean(axis=0)) < 0.05)
    # reproducible, and the rest of the scenario is the base
    assert random_scenario(17, base=base) == random_scenario(17, base=base)
    assert dataclasses.replace(scenarios[3], name=base.name, chaser=base.chaser, description=base.description) == base
    with pytest.raises(ValueError):
        random_scenario(-1)


def test_stable_velocity_gives_a_closed_target_centred_cw_orbit():
    """Independent check of rvd_pil.host_sim.cw.drift_free_velocity: over one orbit the CW motion returns
    to its start, and it is centred on the target (mean position over the orbit ~ 0)."""
    from rvd_pil.host_sim.cw import drift_free_velocity
    n = load("case1_vbar").orbit.mean_motion_rad_s
    a = np.zeros((6, 6))
    a[0:3, 3:6] = np.eye(3)
    a[3, 0], a[3, 4], a[4, 3], a[5, 2] = 3 * n * n, 2 * n, -2 * n, -n * n
    x0 = np.concatenate(([300.0, -1200.0, 400.0], drift_free_velocity(n, [300.0, -1200.0, 400.0])))
    period = 2 * math.pi / n
    np.testing.assert_allclose(expm(a * period) @ x0, x0, atol=1e-7)
    step = expm(a * period / 64)
    samples = [x0]
    for _ in range(63):
        samples.append(step @ samples[-1])
    samples = np.array(samples)
    assert np.all(np.abs(samples[:, 0:3].mean(axis=0)) < 1e-6)


def test_simulator_rejects_bad_options():
    with pytest.raises(ValueError, match="truth"):
        Simulator("case1_vbar", truth="kepler")
    with pytest.raises(ValueError, match="seed"):
        Simulator("case1_vbar", seed=-3)
    with pytest.raises(ValueError, match="truth='cw' only"):
        Simulator("case1_vbar", truth="nonlinear", cw_mean_motion_rad_s=1e-3)
    with pytest.raises(RuntimeError, match="nonlinear"):
        Simulator("case1_vbar", truth="cw").eci_state()
    sim = Simulator("case1_vbar", truth="cw", cw_mean_motion_rad_s=1.1e-3)
    assert sim.mean_motion_rad_s == 1.1e-3 and sim.options["j2"] is False and sim.options["drag"] is False
