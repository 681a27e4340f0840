"""Physical constants used by the truth simulator (SI units).

One consistent set: the EGM96 gravity model (the model the dissertation's 42 simulator uses), so mu,
the reference radius and the zonal coefficients belong together. The flight software must use the
same mean motion as the CW truth for exact comparisons; `Simulator.mean_motion_rad_s` gives it.
"""

# EGM96: gravitational parameter [m^3/s^2] and reference (equatorial) radius [m].
MU_EARTH_M3_S2 = 3.986004415e14
R_EARTH_M = 6378136.3

# EGM96 unnormalised zonal coefficients J_n = -C_n0 (C_n0 de-normalised by sqrt(2n+1)).
J2 = 1.0826266835531513e-3
J3 = -2.5326564853322355e-6
J4 = -1.6196215913670001e-6

# Earth rotation rate [rad/s] (IERS nominal), used for the co-rotating atmosphere.
OMEGA_EARTH_RAD_S = 7.292115e-5

# Standard gravity [m/s^2] (only for Isp-style conversions by users; not used by the dynamics).
G0_M_S2 = 9.80665
