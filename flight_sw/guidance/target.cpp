#include "flight_sw/guidance/target.hpp"

#include <cmath>

namespace rvd::guidance {

Eigen::Quaterniond attitude_after(const TargetState& target, double dt_s) {
  const double rate = target.omega_body_rad_s.norm();
  if (rate * std::abs(dt_s) < 1e-15) return target.q_lvlh_body;
  const Eigen::Quaterniond dq(Eigen::AngleAxisd(rate * dt_s, target.omega_body_rad_s / rate));
  return (target.q_lvlh_body * dq).normalized();
}

Eigen::Vector3d omega_lvlh(const TargetState& target) { return target.q_lvlh_body * target.omega_body_rad_s; }

Matrix43d pyramid_rows_lvlh(const Eigen::Quaterniond& q_lvlh_body, double half_angle_rad) {
  const double c = std::cos(half_angle_rad), s = std::sin(half_angle_rad);
  Matrix43d H_body;
  H_body << -s, c, 0.0,   //
      -s, -c, 0.0,        //
      -s, 0.0, c,         //
      -s, 0.0, -c;
  // h_lvlh = R h_body, i.e. H_lvlh = H_body R^T (eq 3.15 with a general rotation).
  return H_body * q_lvlh_body.toRotationMatrix().transpose();
}

TargetGeometry target_geometry(const TargetState& target, double dt_s, const Eigen::Vector3d& port_body_m) {
  TargetGeometry g;
  g.q_lvlh_body = attitude_after(target, dt_s);
  g.axis = g.q_lvlh_body * Eigen::Vector3d::UnitX();
  g.port_m = g.q_lvlh_body * port_body_m;
  g.omega_rad_s = omega_lvlh(target);
  g.port_velocity_mps = g.omega_rad_s.cross(g.port_m);
  return g;
}

}  // namespace rvd::guidance
