"""The chaser's six on/off thrusters (dissertation sections 2.1.2 and 5.1).

Six thrusters of nominal force F along +x, -x, +y, -y, +z, -z of the chaser body, which is held
aligned with the target's LVLH frame, so each thruster pushes along one LVLH axis. A command is
one pulse width per thruster for the control period; all pulses start together at the burn start.
A pulse shorter than the minimum impulse bit (MIB) is dropped (eq. 2.6: t_pulse < t_MIB gives no
impulse); a zero-width pulse is simply "off", not a drop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

THRUSTER_NAMES = ("+x", "-x", "+y", "-y", "+z", "-z")
# Unit thrust directions in LVLH, in command order.
THRUSTER_AXES_LVLH = np.array([
    [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0], [0.0, -1.0, 0.0],
    [0.0, 0.0, 1.0], [0.0, 0.0, -1.0],
])


@dataclass(frozen=True)
class ThrusterParams:
    """Nominal force per thruster [N] and minimum impulse bit as a pulse width [s]."""

    force_n: float = 0.5
    minimum_impulse_bit_s: float = 0.010


def validate_pulses(pulse_widths_s) -> np.ndarray:
    """Pulse widths as a float array of 6, or ValueError saying what is wrong."""
    try:
        pulses = np.array(pulse_widths_s, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"pulse widths must be 6 numbers in seconds, got {pulse_widths_s!r}") from exc
    if pulses.shape != (6,):
        raise ValueError(f"pulse widths must be 6 numbers (+x, -x, +y, -y, +z, -z) in seconds, "
                         f"got shape {pulses.shape}")
    if not np.all(np.isfinite(pulses)):
        raise ValueError(f"pulse widths must be finite, got {pulses.tolist()}")
    if np.any(pulses < 0.0):
        raise ValueError(f"pulse widths must be >= 0 s, got {pulses.tolist()}")
    return pulses


def drop_below_mib(pulses_s: np.ndarray, mib_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(pulses that fire, mask of pulses dropped by the MIB rule)."""
    dropped = (pulses_s > 0.0) & (pulses_s < mib_s)
    return np.where(dropped, 0.0, pulses_s), dropped


def lvlh_delta_v(dv_thruster_mps: np.ndarray) -> np.ndarray:
    """Net LVLH delta-v [m/s] of per-thruster delta-v magnitudes: sum_i dv_i * axis_i."""
    d = dv_thruster_mps
    return np.array([d[0] - d[1], d[2] - d[3], d[4] - d[5]])

