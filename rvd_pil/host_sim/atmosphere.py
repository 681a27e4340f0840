"""Atmospheric density: the piecewise-exponential model of Vallado, *Fundamentals of Astrodynamics
and Applications* (4th ed., 2013), Table 8-4 (CIRA-72 above 25 km, U.S. Standard Atmosphere 1976
below). rho(h) = rho0_i * exp(-(h - h0_i) / H_i) for h0_i <= h < h0_{i+1}.

A static, mean-solar-activity model: at 500 km it gives 6.967e-13 kg/m^3 (real values swing about
one order of magnitude over the solar cycle). Altitude is taken above a sphere of radius
constants.R_EARTH_M (no ellipsoid), so a circular orbit sees a constant density.
"""

from __future__ import annotations

import bisect
import math

# (base altitude [km], nominal density [kg/m^3], scale height [km])
_TABLE = (
    (0.0, 1.225, 7.249),
    (25.0, 3.899e-2, 6.349),
    (30.0, 1.774e-2, 6.682),
    (40.0, 3.972e-3, 7.554),
    (50.0, 1.057e-3, 8.382),
    (60.0, 3.206e-4, 7.714),
    (70.0, 8.770e-5, 6.549),
    (80.0, 1.905e-5, 5.799),
    (90.0, 3.396e-6, 5.382),
    (100.0, 5.297e-7, 5.877),
    (110.0, 9.661e-8, 7.263),
    (120.0, 2.438e-8, 9.473),
    (130.0, 8.484e-9, 12.636),
    (140.0, 3.845e-9, 16.149),
    (150.0, 2.070e-9, 22.523),
    (180.0, 5.464e-10, 29.740),
    (200.0, 2.789e-10, 37.105),
    (250.0, 7.248e-11, 45.546),
    (300.0, 2.418e-11, 53.628),
    (350.0, 9.518e-12, 53.298),
    (400.0, 3.725e-12, 58.515),
    (450.0, 1.585e-12, 60.828),
    (500.0, 6.967e-13, 63.822),
    (600.0, 1.454e-13, 71.835),
    (700.0, 3.614e-14, 88.667),
    (800.0, 1.170e-14, 124.64),
    (900.0, 5.245e-15, 181.05),
    (1000.0, 3.019e-15, 268.00),
)
_BASE_M = [row[0] * 1e3 for row in _TABLE]


def density_kg_m3(altitude_m: float) -> float:
    """Atmospheric density [kg/m^3] at geometric altitude `altitude_m` [m] (0 m to beyond 1000 km;
    the last layer is extrapolated upward). Raises ValueError below 0 m (the vehicle has crashed)."""
    h = float(altitude_m)
    if not h >= 0.0:  # also catches NaN
        raise ValueError(f"altitude {h!r} m is below the surface or not a number")
    i = bisect.bisect_right(_BASE_M, h) - 1
    base_km, rho0, scale_km = _TABLE[i]
    return rho0 * math.exp(-(h - base_km * 1e3) / (scale_km * 1e3))
