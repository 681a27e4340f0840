/* Compiled as C: the docking-corridor interface (flight_sw/include/rvd_corridor.h) is usable from a C
 * plug-in law. test_guidance_corridor.cpp calls these and checks them against the C++ functions. */
#include "flight_sw/include/rvd_corridor.h"

int corridor_c_shrinks(double r0, double rmin, double gamma, double eta, double eps, const double q[4],
                       const double port[3], int steps, double* final_radius) {
  rvd_holding_radius h;
  double at[3];
  int shrinks = 0;
  rvd_holding_init(&h, r0, rmin, gamma, eta, eps);
  for (int k = 0; k < steps; ++k) {
    rvd_holding_position(q, port, h.next_radius_m, at); /* the chaser sits at the holding position */
    const double before = h.next_radius_m;
    rvd_holding_observe(&h, at, q, port, 0.0);
    shrinks += h.next_radius_m < before;
  }
  *final_radius = h.next_radius_m;
  return shrinks;
}

void corridor_c_cone(const double q[4], const double port[3], double half_angle_rad, double rows[2][3], double bounds[2]) {
  rvd_entry_cone(q, port, half_angle_rad, rows, bounds);
}
