"""Nonlinear truth dynamics in ECI: two-body + zonal harmonics (J2, optionally J3 and J4) +
atmospheric drag, and the numerical propagation of the target/chaser pair.

The pair is integrated as [r_t, v_t, dr, dv] with dr = r_c - r_t (an Encke-like split): the
relative motion is then integrated with its own, metre-level tolerances instead of being the
difference of two 7000 km positions, so the LVLH state keeps sub-micrometre integration error.

Integrator: scipy's DOP853 (explicit Runge-Kutta 8(5,3), adaptive step) with rtol 1e-12 and
absolute tolerances 1e-6 m / 1e-9 m/s on the target and 1e-9 m / 1e-12 m/s on the relative state
(defaults of `Tolerances`). Finite burns are integrated segment by segment so the thrust is smooth
inside each call.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from . import constants as k
from .atmosphere import density_kg_m3
from .frames import lvlh_basis


@dataclass(frozen=True)
class ForceModel:
    """What the truth includes. Drag uses a co-rotating atmosphere unless `atmosphere_rotation`
    is False; altitude is above the sphere of radius `r_earth_m`."""

    j2: bool = True
    j3_j4: bool = False
    drag: bool = True
    atmosphere_rotation: bool = True
    mu_m3_s2: float = k.MU_EARTH_M3_S2
    r_earth_m: float = k.R_EARTH_M

    def zonal_accel(self, r: np.ndarray) -> np.ndarray:
        """Acceleration [m/s^2] from J2 (and J3, J4 if enabled) at ECI position r [m]
        (z is Earth's rotation axis; the ECI frame is taken aligned with Earth's equator)."""
        acc = np.zeros(3)
        if not (self.j2 or self.j3_j4):
            return acc
        x, y, z = r
        r2 = x * x + y * y + z * z
        rn = np.sqrt(r2)
        mu = self.mu_m3_s2
        re = self.r_earth_m
        zr2 = z * z / r2
        if self.j2:
            f = -1.5 * k.J2 * mu * re**2 / rn**5
            acc += f * np.array([x * (1.0 - 5.0 * zr2), y * (1.0 - 5.0 * zr2), z * (3.0 - 5.0 * zr2)])
        if self.j3_j4:
            f3 = -2.5 * k.J3 * mu * re**3 / rn**7
            common3 = 3.0 * z - 7.0 * z * zr2
            acc += f3 * np.array([x * common3, y * common3, 6.0 * z * z - 7.0 * z * z * zr2 - 0.6 * r2])
            f4 = 1.875 * k.J4 * mu * re**4 / rn**7
            common4 = 1.0 - 14.0 * zr2 + 21.0 * zr2 * zr2
            acc += f4 * np.array([x * common4, y * common4, z * (5.0 - 70.0 / 3.0 * zr2 + 21.0 * zr2 * zr2)])
        return acc

    def drag_accel(self, r: np.ndarray, v: np.ndarray, ballistic_m2_kg: float) -> np.ndarray:
        """Drag acceleration [m/s^2]: -1/2 rho (Cd A / m) |v_rel| v_rel, v_rel relative to the
        atmosphere. `ballistic_m2_kg` is Cd*A/m."""
        if not self.drag or ballistic_m2_kg == 0.0:
            return np.zeros(3)
        altitude = np.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2]) - self.r_earth_m
        rho = density_kg_m3(altitude)
        if self.atmosphere_rotation:
            w = k.OMEGA_EARTH_RAD_S
            v_rel = np.array([v[0] + w * r[1], v[1] - w * r[0], v[2]])
        else:
            v_rel = v
        speed = np.sqrt(v_rel[0] ** 2 + v_rel[1] ** 2 + v_rel[2] ** 2)
        return (-0.5 * rho * ballistic_m2_kg * speed) * v_rel

    def perturbation_accel(self, r, v, ballistic_m2_kg: float) -> np.ndarray:
        """Everything except the central term: zonal harmonics + drag [m/s^2]."""
        return self.zonal_accel(r) + self.drag_accel(r, v, ballistic_m2_kg)

    def accel(self, r, v, ballistic_m2_kg: float) -> np.ndarray:
        """Total acceleration [m/s^2] of a spacecraft at ECI r [m], v [m/s]."""
        r = np.asarray(r, dtype=float)
        rn = np.sqrt(r @ r)
        return -self.mu_m3_s2 / rn**3 * r + self.perturbation_accel(r, np.asarray(v, dtype=float), ballistic_m2_kg)


@dataclass(frozen=True)
class Tolerances:
    """DOP853 tolerances (see module docstring)."""

    rtol: float = 1e-12
    atol_position_m: float = 1e-6
    atol_velocity_mps: float = 1e-9
    atol_relative_position_m: float = 1e-9
    atol_relative_velocity_mps: float = 1e-12


def propagate_orbit(r0_m, v0_mps, t_eval_s, model: ForceModel, ballistic_m2_kg: float = 0.0,
                    tol: Tolerances = Tolerances()) -> np.ndarray:
    """Propagate one spacecraft in ECI from t = 0 and return its states (len(t_eval_s) x 6)
    [m, m/s] at the increasing times `t_eval_s` [s]."""
    t_eval = np.asarray(t_eval_s, dtype=float)
    y0 = np.concatenate((np.asarray(r0_m, float), np.asarray(v0_mps, float)))

    def rhs(_t, y):
        return np.concatenate((y[3:6], model.accel(y[0:3], y[3:6], ballistic_m2_kg)))

    atol = np.array([tol.atol_position_m] * 3 + [tol.atol_velocity_mps] * 3)
    sol = solve_ivp(rhs, (0.0, float(t_eval[-1])), y0, method="DOP853", t_eval=t_eval,
                    rtol=tol.rtol, atol=atol)
    if not sol.success:
        raise RuntimeError(f"orbit propagation failed: {sol.message}")
    return sol.y.T


class PairPropagator:
    """Propagates the pair state y = [r_t, v_t, dr, dv] (ECI; dr = r_c - r_t) under `model`,
    with an optional constant thrust acceleration on the chaser given in the target's LVLH frame
    (it turns with the frame, as a thruster on an LVLH-held chaser does)."""

    def __init__(self, model: ForceModel, ballistic_target_m2_kg: float, ballistic_chaser_m2_kg: float,
                 tol: Tolerances = Tolerances()):
        self.model = model
        self.b_t = float(ballistic_target_m2_kg)
        self.b_c = float(ballistic_chaser_m2_kg)
        self.tol = tol
        self._atol = np.array([tol.atol_position_m] * 3 + [tol.atol_velocity_mps] * 3
                              + [tol.atol_relative_position_m] * 3 + [tol.atol_relative_velocity_mps] * 3)

    def derivative(self, y: np.ndarray, thrust_lvlh_mps2=None) -> np.ndarray:
        """dy/dt for the pair state y."""
        if not self.model.j3_j4:
            return self._derivative_scalar(y, thrust_lvlh_mps2)
        return self._derivative_vector(y, thrust_lvlh_mps2)

    def _perturbation_scalar(self, x, y, z, vx, vy, vz, ballistic_m2_kg):
        """perturbation_accel() without J3/J4, on floats: the integrator calls it twice per evaluation,
        and numpy's per-call overhead on 3-vectors is most of a run's CPU time. Same formulas."""
        m = self.model
        ax = ay = az = 0.0
        r2 = x * x + y * y + z * z
        rn = math.sqrt(r2)
        if m.j2:
            re = m.r_earth_m
            zr2 = z * z / r2
            f = -1.5 * k.J2 * m.mu_m3_s2 * re**2 / rn**5
            ax = f * (x * (1.0 - 5.0 * zr2))
            ay = f * (y * (1.0 - 5.0 * zr2))
            az = f * (z * (3.0 - 5.0 * zr2))
        if m.drag and ballistic_m2_kg != 0.0:
            rho = density_kg_m3(rn - m.r_earth_m)
            if m.atmosphere_rotation:
                w = k.OMEGA_EARTH_RAD_S
                ux, uy, uz = vx + w * y, vy - w * x, vz
            else:
                ux, uy, uz = vx, vy, vz
            g = -0.5 * rho * ballistic_m2_kg * math.sqrt(ux * ux + uy * uy + uz * uz)
            ax += g * ux
            ay += g * uy
            az += g * uz
        return ax, ay, az

    def _derivative_scalar(self, y: np.ndarray, thrust_lvlh_mps2=None) -> np.ndarray:
        mu = self.model.mu_m3_s2
        xt, yt, zt, vxt, vyt, vzt, dx, dy, dz, dvx, dvy, dvz = y.tolist()
        xc, yc, zc = xt + dx, yt + dy, zt + dz
        vxc, vyc, vzc = vxt + dvx, vyt + dvy, vzt + dvz
        rt = math.sqrt(xt * xt + yt * yt + zt * zt)
        rc = math.sqrt(xc * xc + yc * yc + zc * zc)
        ptx, pty, ptz = self._perturbation_scalar(xt, yt, zt, vxt, vyt, vzt, self.b_t)
        pcx, pcy, pcz = self._perturbation_scalar(xc, yc, zc, vxc, vyc, vzc, self.b_c)
        kt = -mu / rt**3
        kc = -mu / rc**3
        # Central-term difference written directly (see _derivative_vector); -kt is mu / rt^3 exactly.
        dax = kc * xc + (-kt) * xt + (pcx - ptx)
        day = kc * yc + (-kt) * yt + (pcy - pty)
        daz = kc * zc + (-kt) * zt + (pcz - ptz)
        if thrust_lvlh_mps2 is not None:
            t = lvlh_basis(y[0:3], y[3:6]).T @ thrust_lvlh_mps2
            dax += t[0]
            day += t[1]
            daz += t[2]
        return np.array((vxt, vyt, vzt, kt * xt + ptx, kt * yt + pty, kt * zt + ptz, dvx, dvy, dvz, dax, day, daz))

    def _derivative_vector(self, y: np.ndarray, thrust_lvlh_mps2=None) -> np.ndarray:
        mu = self.model.mu_m3_s2
        r_t, v_t, dr, dv = y[0:3], y[3:6], y[6:9], y[9:12]
        r_c = r_t + dr
        v_c = v_t + dv
        rt = np.sqrt(r_t @ r_t)
        rc = np.sqrt(r_c @ r_c)
        p_t = self.model.perturbation_accel(r_t, v_t, self.b_t)
        a_t = -mu / rt**3 * r_t + p_t
        # Central-term difference written directly; each term is ~8 m/s^2, so the rounding error
        # of the difference is ~1e-15 m/s^2, far below the differential perturbations.
        da = (-mu / rc**3) * r_c + (mu / rt**3) * r_t
        da += self.model.perturbation_accel(r_c, v_c, self.b_c) - p_t
        if thrust_lvlh_mps2 is not None:
            da += lvlh_basis(r_t, v_t).T @ thrust_lvlh_mps2
        return np.concatenate((v_t, a_t, dv, da))

    def propagate(self, y0: np.ndarray, duration_s: float, thrust_lvlh_mps2=None,
                  t_eval_s=None) -> np.ndarray:
        """State after `duration_s` [s] (or the states at `t_eval_s`, relative to the start, as an
        array len x 12). A zero duration returns y0 unchanged."""
        duration = float(duration_s)
        y0 = np.asarray(y0, dtype=float)
        if duration == 0.0 and t_eval_s is None:
            return y0.copy()
        thrust = None if thrust_lvlh_mps2 is None else np.asarray(thrust_lvlh_mps2, dtype=float)
        if thrust is not None and not thrust.any():
            thrust = None
        sol = solve_ivp(lambda _t, y: self.derivative(y, thrust), (0.0, duration), y0, method="DOP853",
                        t_eval=t_eval_s, rtol=self.tol.rtol, atol=self._atol)
        if not sol.success:
            raise RuntimeError(f"pair propagation failed: {sol.message}")
        return sol.y.T if t_eval_s is not None else sol.y[:, -1]

    def propagate_sampled(self, y0: np.ndarray, duration_s: float, sample_s, thrust_lvlh_mps2=None):
        """(state after `duration_s`, states at the times `sample_s` relative to the start, len x 12).
        The samples come from the integrator's dense output, so the end state is exactly what
        propagate() gives: sampling does not change the trajectory."""
        duration = float(duration_s)
        y0 = np.asarray(y0, dtype=float)
        thrust = None if thrust_lvlh_mps2 is None else np.asarray(thrust_lvlh_mps2, dtype=float)
        if thrust is not None and not thrust.any():
            thrust = None
        sol = solve_ivp(lambda _t, y: self.derivative(y, thrust), (0.0, duration), y0, method="DOP853",
                        dense_output=True, rtol=self.tol.rtol, atol=self._atol)
        if not sol.success:
            raise RuntimeError(f"pair propagation failed: {sol.message}")
        end = sol.y[:, -1]
        samples = sol.sol(np.asarray(sample_s, dtype=float)).T
        samples[-1] = end if np.asarray(sample_s)[-1] == duration else samples[-1]
        return end, samples
