"""Frames: ECI <-> the target's LVLH frame, and small rotation/quaternion helpers.

LVLH (the dissertation's CW frame): origin at the target's centre of mass, x radial out (R-bar),
z along the orbit angular momentum, y = z x x (along-track, V-bar, the velocity direction on a
circular orbit). Relative velocity is the time derivative of the LVLH components, so it contains
the frame rotation: rho_dot = C (v_c - v_t) - omega x rho.

The frame's angular velocity, in LVLH components, is omega = ((r/h) a_h, 0, h/r^2), where a_h is the
target's acceleration along the orbit normal (zero for two-body motion; J2 makes the orbit plane
precess, which shows up here).
"""

from __future__ import annotations

import math

import numpy as np


def cross3(a, b) -> np.ndarray:
    """Cross product of two 3-vectors (np.cross is slow for single small vectors; this sits in the
    integrator's inner loop)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def lvlh_basis(r_eci_m: np.ndarray, v_eci_mps: np.ndarray) -> np.ndarray:
    """Rotation matrix C (3x3) whose rows are the LVLH axes in ECI: rho_lvlh = C @ rho_eci."""
    r = np.asarray(r_eci_m, dtype=float)
    h = cross3(r, np.asarray(v_eci_mps, dtype=float))
    x_hat = r / math.sqrt(r @ r)
    z_hat = h / math.sqrt(h @ h)
    y_hat = cross3(z_hat, x_hat)
    return np.array((x_hat, y_hat, z_hat))


def lvlh_angular_velocity(r_eci_m, v_eci_mps, normal_accel_mps2: float = 0.0) -> np.ndarray:
    """Angular velocity of the LVLH frame w.r.t. ECI, in LVLH components [rad/s].
    `normal_accel_mps2` is the target's acceleration along the orbit normal (perturbations)."""
    r_vec = np.asarray(r_eci_m, dtype=float)
    r = np.linalg.norm(r_vec)
    h = np.linalg.norm(cross3(r_vec, np.asarray(v_eci_mps, dtype=float)))
    return np.array([r * normal_accel_mps2 / h, 0.0, h / (r * r)])


def eci_to_lvlh(r_t, v_t, r_c, v_c, normal_accel_mps2: float = 0.0) -> np.ndarray:
    """Chaser relative state [rho (m), rho_dot (m/s)] in the target's LVLH frame from ECI states."""
    c = lvlh_basis(r_t, v_t)
    omega = lvlh_angular_velocity(r_t, v_t, normal_accel_mps2)
    rho = c @ (np.asarray(r_c, dtype=float) - np.asarray(r_t, dtype=float))
    rho_dot = c @ (np.asarray(v_c, dtype=float) - np.asarray(v_t, dtype=float)) - cross3(omega, rho)
    return np.concatenate((rho, rho_dot))


def lvlh_to_eci(r_t, v_t, x_lvlh, normal_accel_mps2: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of `eci_to_lvlh`: chaser ECI position [m] and velocity [m/s]."""
    c = lvlh_basis(r_t, v_t)
    omega = lvlh_angular_velocity(r_t, v_t, normal_accel_mps2)
    x = np.asarray(x_lvlh, dtype=float)
    rho, rho_dot = x[0:3], x[3:6]
    r_c = np.asarray(r_t, dtype=float) + c.T @ rho
    v_c = np.asarray(v_t, dtype=float) + c.T @ (rho_dot + cross3(omega, rho))
    return r_c, v_c


def rotation_z(angle_rad: float) -> np.ndarray:
    """Active rotation by `angle_rad` about z (3x3)."""
    c = math.cos(angle_rad)
    s = math.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def quaternion_about_z(angle_rad: float) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation by `angle_rad` about z."""
    return np.array([math.cos(0.5 * angle_rad), 0.0, 0.0, math.sin(0.5 * angle_rad)])


def quaternion_after(q_wxyz, omega_body_rad_s, dt_s: float) -> np.ndarray:
    """The attitude (w, x, y, z; outer <- body) dt_s later under a constant body rate:
    q (x) [cos(|w| dt / 2), sin(|w| dt / 2) w / |w|], as the flight software predicts it."""
    q, w = np.asarray(q_wxyz, dtype=float), np.asarray(omega_body_rad_s, dtype=float)
    rate = float(np.linalg.norm(w))
    if rate * dt_s == 0.0:
        return q
    h = 0.5 * rate * dt_s
    w2, v2 = math.cos(h), math.sin(h) * w / rate
    w1, v1 = q[0], q[1:]
    out = np.r_[w1 * w2 - v1 @ v2, w1 * v2 + w2 * v1 + np.cross(v1, v2)]
    return out / np.linalg.norm(out)


def quaternion_to_matrix(q_wxyz) -> np.ndarray:
    """Rotation matrix of a unit quaternion (w, x, y, z): v_outer = R @ v_inner for q outer<-inner."""
    w, x, y, z = np.asarray(q_wxyz, dtype=float)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])
