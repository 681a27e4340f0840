"""Target attitude relative to LVLH: fixed, or a constant spin about the body z axis (which stays
aligned with LVLH z, the orbit normal), as in the dissertation's Case 3.

The body frame starts rotated by `initial_angle` about LVLH z and turns at `spin_rate`:
angle(t) = initial_angle + spin_rate * t. Body x is the docking axis; the docking port sits at
`port_body_m` in the body frame (Table 3.2: (0.5, 0, 0) m). An initial angle of -90 deg points the
port at -y (a V-bar approach from behind), 0 deg at +x (R-bar approach from above).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .frames import quaternion_about_z, rotation_z


@dataclass(frozen=True)
class TargetState:
    """Target attitude and docking port at one time (LVLH frame, SI units)."""

    t_s: float
    q_lvlh_body: np.ndarray           # unit quaternion (w, x, y, z), LVLH <- body
    omega_body_rad_s: np.ndarray      # body rate relative to LVLH, in body axes
    port_position_lvlh_m: np.ndarray  # docking port relative to the target CoM
    port_velocity_lvlh_mps: np.ndarray
    docking_axis_lvlh: np.ndarray     # body x in LVLH (outward through the port)


class TargetAttitude:
    """Constant-rate rotation about the body z axis, measured relative to LVLH."""

    def __init__(self, initial_angle_rad: float, spin_rate_rad_s: float, port_body_m):
        self.initial_angle_rad = float(initial_angle_rad)
        self.spin_rate_rad_s = float(spin_rate_rad_s)
        self.port_body_m = np.asarray(port_body_m, dtype=float).copy()

    def angle_rad(self, t_s: float) -> float:
        """Rotation angle of the body about LVLH z at time t_s [s]."""
        return self.initial_angle_rad + self.spin_rate_rad_s * float(t_s)

    def state(self, t_s: float) -> TargetState:
        theta = self.angle_rad(t_s)
        rot = rotation_z(theta)
        port = rot @ self.port_body_m
        w = self.spin_rate_rad_s
        return TargetState(
            t_s=float(t_s),
            q_lvlh_body=quaternion_about_z(theta),
            omega_body_rad_s=np.array([0.0, 0.0, w]),
            port_position_lvlh_m=port,
            # d/dt (R(theta) p) = omega_z x (R p); body z = LVLH z, so the rate vector is the same.
            port_velocity_lvlh_mps=np.array([-w * port[1], w * port[0], 0.0]),
            docking_axis_lvlh=np.array([math.cos(theta), math.sin(theta), 0.0]),
        )
