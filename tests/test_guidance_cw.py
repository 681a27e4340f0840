"""The guidance's CW prediction model: the closed-form STM against scipy's matrix exponential of the
CW system matrix (written out here), and the phase QPs' dynamics blocks against the same."""
import math

import numpy as np
import pytest
from scipy.linalg import expm

from rvd_pil import flight_sw as fsw
from support.cw_reference import cw_a

MU, RE = 3.986004415e14, 6378136.3  # EGM96, as rvd_pil/host_sim/constants.py


def test_mean_motion_is_keplerian():
    n = fsw.mean_motion_rad_s(500e3)
    assert n == pytest.approx(math.sqrt(MU / (RE + 500e3) ** 3), rel=1e-15)
    assert fsw.GuidanceParams().mean_motion_rad_s() == n


@pytest.mark.parametrize("t", [0.0, 1.0, 5.0, 20.0, 30.0, 900.0, 5677.0, 20000.0])
@pytest.mark.parametrize("alt", [400e3, 500e3, 800e3])
def test_closed_form_stm_equals_expm(t, alt):
    n = fsw.mean_motion_rad_s(alt)
    np.testing.assert_allclose(fsw.cw_stm(n, t), expm(cw_a(n) * t), rtol=1e-10, atol=1e-12 * max(1.0, t))


def test_system_matrix_is_the_cw_matrix():
    n = fsw.mean_motion_rad_s(500e3)
    np.testing.assert_array_equal(fsw.cw_system_matrix(n), cw_a(n))


@pytest.mark.parametrize("phase,ts", [(fsw.Phase.Rendezvous, 30.0), (fsw.Phase.Approach, 20.0), (fsw.Phase.Docking, 5.0)])
def test_phase_qp_dynamics_are_impulsive_cw(phase, ts):
    p = fsw.GuidanceParams()
    qp = fsw.build_phase_qp(p, phase, [100.0, -300.0, 10.0, 0.1, 0.0, 0.0])
    a_ref = expm(cw_a(p.mean_motion_rad_s()) * ts)
    b_ref = a_ref @ np.vstack([np.zeros((3, 3)), np.eye(3)])  # velocity impulse, then drift
    for a, b, c in zip(qp["A"], qp["B"], qp["b"]):
        np.testing.assert_allclose(a, a_ref, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(b[:, :3], b_ref, rtol=1e-10, atol=1e-12)
        assert not np.any(b[:, 3:])  # slack inputs do not move the chaser
        assert not np.any(c)
