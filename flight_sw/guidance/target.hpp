// The target as the guidance sees it: attitude (LVLH <- body) and a constant body rate relative to LVLH,
// the docking port, the docking axis (body +x) and the line-of-sight pyramids around it (eq 3.3, 3.15).
#pragma once

#include <Eigen/Dense>
#include <Eigen/Geometry>

namespace rvd::guidance {

using Matrix43d = Eigen::Matrix<double, 4, 3>;

struct TargetState {
  Eigen::Quaterniond q_lvlh_body = Eigen::Quaterniond::Identity();  // rotates body vectors into LVLH
  Eigen::Vector3d omega_body_rad_s = Eigen::Vector3d::Zero();       // body rate relative to LVLH, body axes
};

// Attitude dt seconds later under the constant body rate: q(t + dt) = q(t) (x) exp(omega dt / 2).
Eigen::Quaterniond attitude_after(const TargetState& target, double dt_s);

// The body rate expressed in LVLH (constant: the rotation is about the rate vector itself).
Eigen::Vector3d omega_lvlh(const TargetState& target);

// Four-sided line-of-sight pyramid of half-angle `half_angle_rad` around the docking axis (body +x),
// apex at the origin of the row space: rows h_j = e_j cos(a) - x_body sin(a), e_j in {+y, -y, +z, -z},
// rotated into LVLH. A point p (relative to the apex) is inside when H p <= 0. Rows are unit vectors.
Matrix43d pyramid_rows_lvlh(const Eigen::Quaterniond& q_lvlh_body, double half_angle_rad);

// Everything the phase QPs need from the target at one instant, in LVLH.
struct TargetGeometry {
  Eigen::Vector3d axis;           // docking axis (unit): the cones open along it
  Eigen::Vector3d port_m;         // docking port position
  Eigen::Vector3d port_velocity_mps;  // omega x port (the port moves when the target spins)
  Eigen::Vector3d omega_rad_s;    // body rate in LVLH
  Eigen::Quaterniond q_lvlh_body;
};
TargetGeometry target_geometry(const TargetState& target, double dt_s, const Eigen::Vector3d& port_body_m);

}  // namespace rvd::guidance
