"""Random initial states like the dissertation's Monte Carlo set (range 0.15-2.5 km, velocity perturbed from
a drift-free relative orbit by N(0, 0.5 m/s) per axis), including starts inside the keep-out sphere: the
closed loop never crashes, never commands NaN or more than u_max, and docks."""
import numpy as np
import pytest

from rvd_pil import flight_sw as fsw
from support.guidance_geometry import DEG, VBAR, in_pyramid


def drift_free_velocity(n, rho):
    """A closed CW relative orbit through rho: ydot = -2 n x, xdot = n y / 2 (zdot = 0)."""
    return np.array([n * rho[1] / 2.0, -2.0 * n * rho[0], 0.0])


def starts(seed, count):
    rng = np.random.default_rng(seed)
    n = fsw.mean_motion_rad_s(500e3)
    out = []
    for _ in range(count):
        d = rng.normal(size=3)
        rho = rng.uniform(150.0, 2500.0) * d / np.linalg.norm(d)
        out.append(np.r_[rho, drift_free_velocity(n, rho) + rng.normal(0.0, 0.5, 3)])
    return out


# Inside the keep-out sphere and outside the cone (behind the target, V-bar docking from -y), moving in.
INSIDE = np.array([20.0, 150.0, 0.0, 0.05, -0.2, 0.0])


@pytest.mark.parametrize("x0", [INSIDE] + starts(2024, 5), ids=["inside_keepout"] + [f"rand{i}" for i in range(5)])
def test_random_start_docks_safely(x0):
    p = fsw.GuidanceParams()
    r = fsw.run_closed_loop(p, x0, VBAR)
    assert np.all(np.isfinite(r.x)) and np.all(np.isfinite(r.dv_cmd_mps))
    for i in range(r.steps):
        if r.phase[i] < 4:
            assert np.abs(r.dv_cmd_mps[i]).max() <= p.phase(fsw.Phase(int(r.phase[i]))).u_max_mps + 1e-12
    assert r.docked, r.reason
    # A start inside the sphere must not go deeper while it is outside the cone.
    rng = np.linalg.norm(r.x[:, :3], axis=1)
    outside = np.array([not in_pyramid(q, x[:3], 15 * DEG, 1e-3) for q, x in zip(r.q_lvlh_body, r.x)])
    start = np.linalg.norm(x0[:3])
    assert np.all(rng[outside] >= min(start, p.keepout_radius_m) - 0.05)
