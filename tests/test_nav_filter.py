"""The onboard navigation filter (flight_sw/nav) against the host simulator's truth, sensors and
thrusters: statistical consistency, the accuracy it buys, and what it does with hostile input."""
import dataclasses
import math

import numpy as np
import pytest
from scipy.stats import chi2

from rvd_pil import flight_sw
from rvd_pil.host_sim.scenario import load
from rvd_pil.host_sim.simulator import Simulator

SIGMA_P, SIGMA_V = 0.05, 0.001


def filter_params(scen, **kw):
    p = flight_sw.NavFilterParams()
    p.sigma_position_m, p.sigma_velocity_mps = SIGMA_P, SIGMA_V
    p.thrust_error_sigma = math.sqrt(scen.thrust_error.steady_state_covariance()[0, 0]) / 100.0
    for k, v in kw.items():
        setattr(p, k, v)
    return p


def pulses_for(dv, mass=14.0, force=0.5, mib=0.01):
    """Pulse widths for an LVLH delta-v (the flight's allocation, independently: t = m |dv| / F)."""
    pulses = np.zeros(6)
    dv = np.array(dv, float)
    for i in range(3):
        t = abs(dv[i]) * mass / force
        if t < mib:
            dv[i] = 0.0
            continue
        pulses[2 * i + (0 if dv[i] > 0 else 1)] = t
    return dv, pulses


def fly(truth, seed, period_s, u_max, steps=40):
    """A chaser near the target flown with random burns; returns (errors, P, innovations) per step."""
    scen = load("case1_vbar")
    scen = scen.replace(chaser=dataclasses.replace(scen.chaser, position_lvlh_m=(0.1, -100.0, 0.15),
                                                   velocity_lvlh_mps=(0.0, 0.3, 0.0)))
    sim = Simulator(scen, truth=truth, seed=seed, sensor_noise=True, thrust_noise=True)
    kf = flight_sw.NavFilter(filter_params(scen), sim.mean_motion_rad_s)
    rng = np.random.default_rng(1000 + seed)
    out = []
    for k in range(steps):
        m = sim.measure()
        x, P, update, chi, *_ = kf.update(m.t_s, m.state)
        out.append((x - sim.truth_lvlh(), P, m.state - sim.truth_lvlh(), update))
        dv, pulses = pulses_for(rng.uniform(-u_max, u_max, 3) * (rng.random(3) < 0.5))
        kf.command(m.t_s, dv, pulses.tolist())
        sim.apply_command(pulses, period_s, 0.0)
    return out


@pytest.mark.parametrize("truth,period_s,u_max", [("cw", 20.0, 0.1786), ("nonlinear", 5.0, 0.0357)])
def test_the_filter_is_consistent_with_the_truth(truth, period_s, u_max):
    """Normalised estimation error squared e' P^-1 e is chi-square with 6 degrees of freedom for a
    consistent filter. Every 10th step of 20 runs (far enough apart to be nearly independent): the
    mean of 80 such values must lie in the 99.9 % interval of chi2(6 * 80) / 80."""
    nees = []
    for seed in range(20):
        run = fly(truth, seed, period_s, u_max)
        for e, P, _, update in run[10::10]:
            assert update == flight_sw.NavUpdate.fused
            nees.append(float(e @ np.linalg.solve(P, e)))
    lo, hi = chi2.ppf([0.0005, 0.9995], 6 * len(nees)) / len(nees)
    assert lo <= np.mean(nees) <= hi, (np.mean(nees), lo, hi)


def test_the_estimate_is_several_times_better_than_one_measurement():
    errors, raw = [], []
    for seed in range(10):
        for e, _, r, _ in fly("nonlinear", seed, 5.0, 0.0357)[10:]:
            errors.append(e[:3])
            raw.append(r[:3])
    rms = np.sqrt(np.mean(np.square(errors)))
    rms_raw = np.sqrt(np.mean(np.square(raw)))
    assert rms_raw == pytest.approx(SIGMA_P, rel=0.1)
    assert rms < rms_raw / 2.5, (rms, rms_raw)


def test_noise_free_sensors_make_the_filter_the_identity():
    p = flight_sw.NavFilterParams()  # sigmas 0
    kf = flight_sw.NavFilter(p, 1.1e-3)
    for k in range(5):
        z = np.array([1.0 + k, -2.0, 3.0, 0.1, 0.2, -0.3 * k])
        x, P, update, *_ = kf.update(10.0 * k, z)
        assert update == flight_sw.NavUpdate.passthrough
        np.testing.assert_array_equal(x, z)
        kf.command(10.0 * k, [0.1, 0.0, 0.0], [2.8, 0, 0, 0, 0, 0])


def test_hostile_measurements_are_gated_or_refused_never_fused():
    scen = load("case1_vbar")
    kf = flight_sw.NavFilter(filter_params(scen), 1.1e-3)
    z = np.array([10.0, -100.0, 0.0, 0.0, 0.0, 0.0])
    x, *_ = kf.update(0.0, z)
    x, *_ = kf.update(5.0, z + [0.01, 0, 0, 0, 0, 0])
    good = x.copy()
    # NaN: not fused, the prediction stands.
    x, P, update, *_ = kf.update(10.0, np.full(6, np.nan))
    assert update == flight_sw.NavUpdate.invalid and np.all(np.isfinite(x))
    # A 10 m jump is implausible: gated twice, then the filter trusts the new measurements.
    far = z + [10.0, 0, 0, 0, 0, 0]
    updates = [kf.update(15.0 + 5 * i, far)[2] for i in range(3)]
    assert updates == [flight_sw.NavUpdate.gated, flight_sw.NavUpdate.gated, flight_sw.NavUpdate.reinitialised]
    assert kf.gated == 3 and kf.reinitialisations == 1
    x, *_ = kf.update(30.0, far)
    assert abs(x[0] - far[0]) < 0.1 and abs(good[0] - z[0]) < 0.1
    with pytest.raises(ValueError):
        bad = flight_sw.NavFilterParams()
        bad.sigma_position_m = -1.0
        flight_sw.NavFilter(bad, 1.1e-3)
