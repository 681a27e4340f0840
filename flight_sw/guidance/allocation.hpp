// Thruster allocation (dissertation eqs 2.4-2.6): a commanded impulsive delta-v in LVLH becomes pulse
// widths of six on/off thrusters on +x, -x, +y, -y, +z, -z (body axes aligned with LVLH, as in the
// dissertation's 42 set-up). Constant mass: t = m |dv_axis| / F; pulses shorter than the minimum impulse
// bit are dropped, pulses longer than the cap are cut. The realised delta-v is F t / m per axis.
#pragma once

#include <Eigen/Dense>

#include <array>

namespace rvd::guidance {

struct ThrusterParams {
  double mass_kg = 14.0;            // chaser mass (6U CubeSat, Table 3.2 scenario)
  double thrust_N = 0.5;            // nominal force of each thruster
  double min_impulse_bit_s = 0.010;  // shortest pulse a valve can make; shorter commands are dropped
};

enum Thruster : int { PlusX = 0, MinusX = 1, PlusY = 2, MinusY = 3, PlusZ = 4, MinusZ = 5 };

struct Allocation {
  std::array<double, 6> pulse_s{};                      // order +x, -x, +y, -y, +z, -z
  Eigen::Vector3d dv_alloc_mps = Eigen::Vector3d::Zero();  // what the pulses realise nominally
};

// max_pulse_s: the longest allowed pulse (u_max m / F of the phase). A NaN/Inf component fires nothing.
Allocation allocate_thrusters(const Eigen::Vector3d& dv_cmd_mps, double max_pulse_s, const ThrusterParams& thr);

// Longest pulse that realises u_max on one axis.
double max_pulse_s(double u_max_mps, const ThrusterParams& thr);

}  // namespace rvd::guidance
