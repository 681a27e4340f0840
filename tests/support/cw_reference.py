"""Independent truth shared by the tests: the CW system matrix written out from the equations of
motion, never taken from host_sim or flight_sw."""
import numpy as np


def cw_a(n):
    """CW system matrix from xdd = 3n^2 x + 2n yd, ydd = -2n xd, zdd = -n^2 z (LVLH: x radial, y along-track)."""
    a = np.zeros((6, 6))
    a[0:3, 3:6] = np.eye(3)
    a[3, 0], a[3, 4] = 3 * n * n, 2 * n
    a[4, 3] = -2 * n
    a[5, 2] = -n * n
    return a
