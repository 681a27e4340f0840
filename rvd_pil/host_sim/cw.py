"""Clohessy-Wiltshire relative motion in the target's LVLH frame (x radial out / R-bar,
y along-track / V-bar, z orbit normal). State x = [rho; rho_dot] in m and m/s.

    x_ddot = 3 n^2 x + 2 n y_dot,   y_ddot = -2 n x_dot,   z_ddot = -n^2 z   (+ control acceleration)

Everything here is closed form with scalar math.sin/math.cos: the state transition matrix is the
textbook one, so the host's CW truth and the flight software's prediction model agree to rounding.
"""

from __future__ import annotations

import math

import numpy as np


def cw_matrix(n_rad_s: float) -> np.ndarray:
    """Continuous-time CW system matrix A (6x6) for mean motion n [rad/s]: x_dot = A x + [0; I] a."""
    n = float(n_rad_s)
    a = np.zeros((6, 6))
    a[0:3, 3:6] = np.eye(3)
    a[3, 0] = 3.0 * n * n
    a[3, 4] = 2.0 * n
    a[4, 3] = -2.0 * n
    a[5, 2] = -n * n
    return a


def cw_stm(n_rad_s: float, t_s: float) -> np.ndarray:
    """Closed-form CW state transition matrix Phi(t) (6x6): x(t) = Phi(t) x(0) for free motion.
    n = 0 (no orbit: an air-bearing table) is the limit, a double integrator."""
    n = float(n_rad_s)
    t = float(t_s)
    if n == 0.0:
        phi = np.eye(6)
        phi[0:3, 3:6] = t * np.eye(3)
        return phi
    nt = n * t
    s = math.sin(nt)
    c = math.cos(nt)
    return np.array([
        [4.0 - 3.0 * c, 0.0, 0.0, s / n, 2.0 * (1.0 - c) / n, 0.0],
        [6.0 * (s - nt), 1.0, 0.0, -2.0 * (1.0 - c) / n, (4.0 * s - 3.0 * nt) / n, 0.0],
        [0.0, 0.0, c, 0.0, 0.0, s / n],
        [3.0 * n * s, 0.0, 0.0, c, 2.0 * s, 0.0],
        [-6.0 * n * (1.0 - c), 0.0, 0.0, -2.0 * s, 4.0 * c - 3.0, 0.0],
        [0.0, 0.0, -n * s, 0.0, 0.0, c],
    ])


def cw_forced_response(n_rad_s: float, t_s: float) -> np.ndarray:
    """Gamma(t) (6x3): state change after t seconds of a constant LVLH acceleration a [m/s^2] from
    rest at the origin, so x(t) = Phi(t) x(0) + Gamma(t) a. Gamma(t) = integral_0^t Phi(u) [0; I] du."""
    n = float(n_rad_s)
    t = float(t_s)
    if n == 0.0:  # the double integrator's limit
        return np.vstack((0.5 * t * t * np.eye(3), t * np.eye(3)))
    nt = n * t
    s = math.sin(nt)
    # Cancellation-free forms: pulses last milliseconds, so n*t can be ~1e-5.
    one_minus_c = 2.0 * math.sin(0.5 * nt) ** 2
    nt_minus_s = _nt_minus_sin(nt)
    n2 = n * n
    return np.array([
        [one_minus_c / n2, 2.0 * nt_minus_s / n2, 0.0],
        [-2.0 * nt_minus_s / n2, 4.0 * one_minus_c / n2 - 1.5 * t * t, 0.0],
        [0.0, 0.0, one_minus_c / n2],
        [s / n, 2.0 * one_minus_c / n, 0.0],
        [-2.0 * one_minus_c / n, (4.0 * s - 3.0 * nt) / n, 0.0],
        [0.0, 0.0, s / n],
    ])


def _nt_minus_sin(a: float) -> float:
    """a - sin(a) without cancellation for small |a| (Taylor series, 7 terms, exact to rounding
    for |a| < 0.1)."""
    if abs(a) >= 0.1:
        return a - math.sin(a)
    a2 = a * a
    term = a * a2 / 6.0
    total = 0.0
    for k in range(7):
        total += term
        term *= -a2 / ((2 * k + 4) * (2 * k + 5))
    return total


def drift_free_velocity(n_rad_s: float, position_lvlh_m) -> np.ndarray:
    """LVLH velocity [m/s] that puts a chaser at `position_lvlh_m` on a closed CW relative orbit
    centred on the target: no along-track drift (y_dot = -2 n x) and the 2:1 in-plane ellipse
    centred at the origin (x_dot = n y / 2); out of plane a pure oscillation through z (z_dot = 0)."""
    n = float(n_rad_s)
    x, y, _ = np.asarray(position_lvlh_m, dtype=float)
    return np.array([0.5 * n * y, -2.0 * n * x, 0.0])
