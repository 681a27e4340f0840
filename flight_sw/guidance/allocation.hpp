// Thruster allocation (dissertation eqs 2.4-2.6): a commanded impulsive delta-v in LVLH becomes pulse
// widths of six on/off thrusters on +x, -x, +y, -y, +z, -z (body axes aligned with LVLH, as in the
// dissertation's 42 set-up). Constant mass: t = m |dv_axis| / (s F), s the thruster's estimated relative
// force (1 nominal); pulses shorter than the minimum impulse bit are dropped, pulses longer than the cap
// are cut. The expected realised delta-v is s F t / m per axis.
#pragma once

#include <Eigen/Dense>

#include <array>

namespace rvd::guidance {

// Relative force of each thruster (+x, -x, +y, -y, +z, -z): realised / nominal, 1 when unknown.
using ThrustScale = std::array<double, 6>;
constexpr ThrustScale kNominalThrust{1.0, 1.0, 1.0, 1.0, 1.0, 1.0};

struct ThrusterParams {
  double mass_kg = 14.0;            // chaser mass (6U CubeSat, Table 3.2 scenario)
  double thrust_N = 0.5;            // nominal force of each thruster
  double min_impulse_bit_s = 0.010;  // shortest pulse a valve can make; shorter commands are dropped
};

enum Thruster : int { PlusX = 0, MinusX = 1, PlusY = 2, MinusY = 3, PlusZ = 4, MinusZ = 5 };

struct Allocation {
  std::array<double, 6> pulse_s{};                           // order +x, -x, +y, -y, +z, -z
  Eigen::Vector3d dv_alloc_mps = Eigen::Vector3d::Zero();    // what the pulses are expected to realise
  Eigen::Vector3d dv_nominal_mps = Eigen::Vector3d::Zero();  // F t / m of the pulses at nominal force
};

// max_pulse_s: the longest allowed pulse (u_max m / F of the phase). A NaN/Inf component fires nothing.
// `scale`: the thrusters' estimated relative force; a pulse is lengthened (up to the cap) by 1 / scale so
// that a weak thruster still delivers the commanded delta-v.
Allocation allocate_thrusters(const Eigen::Vector3d& dv_cmd_mps, double max_pulse_s, const ThrusterParams& thr,
                              const ThrustScale& scale = kNominalThrust);

// Longest pulse that realises u_max on one axis.
double max_pulse_s(double u_max_mps, const ThrusterParams& thr);

}  // namespace rvd::guidance
