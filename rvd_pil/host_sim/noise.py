"""Noise models: the Carpenter-Lee thrust amplitude error (dissertation eq. 5.3, Table 5.1) and the
relative-navigation sensor noise (eqs. 5.6-5.7).

Units of the Gauss-Markov model (the dissertation leaves them implicit). State s = [w, v] with

    d/dt [w; v] = [[-1/tau, 1], [-omega_n^2, -2 xi omega_n]] [w; v] + [eta_w; eta_v] (white noise)

We read w in percent of the nominal thrust (eq. 5.2 applies F = (1 + w/100) F_nom) and eta_w, eta_v
as white-noise intensities (square roots of the power spectral densities: %/sqrt(s) and
%/s/sqrt(s)). With Table 5.1 the steady-state (Lyapunov) covariance gives sigma_w = 4.62 %, so
3 sigma = 13.9 % and the text's "stays within about +-7 %" is about 1.5 sigma: the right order, and
the other readings are far off (w as a fraction would give sigma_w = 462 %, impossible for
w in (-1, 1); eta as variance intensities would give sigma_w = 13.2 %). eta_v is so small that the
noise is effectively driven through w alone.

Discretisation is exact for any step (Van Loan): s_{k+1} = Phi s_k + L e_k, e_k ~ N(0, I),
L L^T = Q_d = integral_0^dt e^{F u} Q e^{F^T u} du.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm, solve_continuous_lyapunov


@dataclass(frozen=True)
class GaussMarkovParams:
    """Carpenter-Lee two-state model parameters (defaults: dissertation Table 5.1)."""

    tau_s: float = 3600.0
    omega_n_rad_s: float = 2.6e-4
    xi: float = 1.0
    eta_w: float = 3.0 / math.sqrt(600.0)
    eta_v: float = 1.1267e-8

    def system_matrix(self) -> np.ndarray:
        return np.array([[-1.0 / self.tau_s, 1.0],
                         [-self.omega_n_rad_s**2, -2.0 * self.xi * self.omega_n_rad_s]])

    def noise_intensity(self) -> np.ndarray:
        return np.diag([self.eta_w**2, self.eta_v**2])

    def steady_state_covariance(self) -> np.ndarray:
        """Solution P of F P + P F^T + Q = 0 (units: %^2 for w)."""
        return solve_continuous_lyapunov(self.system_matrix(), -self.noise_intensity())

    def discretize(self, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Exact (Van Loan) transition matrix Phi and process-noise covariance Q_d over dt_s [s]."""
        f = self.system_matrix()
        m = np.zeros((4, 4))
        m[0:2, 0:2] = -f
        m[0:2, 2:4] = self.noise_intensity()
        m[2:4, 2:4] = f.T
        e = expm(m * float(dt_s))
        phi = e[2:4, 2:4].T
        qd = phi @ e[0:2, 2:4]
        return phi, 0.5 * (qd + qd.T)


def _sqrt_psd(q: np.ndarray) -> np.ndarray:
    """A square root L (L L^T = q) of a symmetric positive semi-definite 2x2 matrix, robust when q
    is numerically singular (tiny steps)."""
    vals, vecs = np.linalg.eigh(q)
    return vecs * np.sqrt(np.clip(vals, 0.0, None))


class ThrustAmplitudeError:
    """`count` independent Carpenter-Lee processes (one per thruster: valves, lines and
    catalyst beds age separately; a shared tank pressure would correlate them, which the
    dissertation does not model). Starts from the steady-state distribution."""

    def __init__(self, params: GaussMarkovParams, count: int, rng: np.random.Generator):
        self.params = params
        self.rng = rng
        p_inf = params.steady_state_covariance()
        self.state = (_sqrt_psd(p_inf) @ rng.standard_normal((2, count))).T  # (count, 2): [w %, v]
        self._cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    @property
    def w_percent(self) -> np.ndarray:
        """Current amplitude error of each thruster [%]."""
        return self.state[:, 0].copy()

    def advance(self, dt_s: float) -> None:
        """Move every process forward by dt_s [s] (exact discretisation; dt_s = 0 is a no-op)."""
        dt = float(dt_s)
        if dt < 0.0 or not math.isfinite(dt):
            raise ValueError(f"Gauss-Markov step must be finite and >= 0, got {dt_s!r} s")
        if dt == 0.0:
            return
        if dt not in self._cache:
            if len(self._cache) > 256:  # periods repeat; keep the cache bounded anyway
                self._cache.clear()
            phi, qd = self.params.discretize(dt)
            self._cache[dt] = (phi, _sqrt_psd(qd))
        phi, l = self._cache[dt]
        noise = self.rng.standard_normal((self.state.shape[0], 2))
        self.state = self.state @ phi.T + noise @ l.T


@dataclass(frozen=True)
class SensorParams:
    """Relative navigation noise, 1 sigma per LVLH axis (dissertation eqs. 5.6-5.7, section 5.4)."""

    sigma_position_m: float = 0.05
    sigma_velocity_mps: float = 0.001
