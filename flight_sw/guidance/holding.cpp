#include "flight_sw/guidance/holding.hpp"

#include <algorithm>
#include <cmath>

#include "flight_sw/include/rvd_corridor.h"

namespace rvd::guidance {

Eigen::Vector3d holding_position(const Eigen::Quaterniond& q_lvlh_body, const Eigen::Vector3d& port_body_m,
                                 double radius_m) {
  const Eigen::Vector3d axis = q_lvlh_body * Eigen::Vector3d::UnitX();
  const Eigen::Vector3d port = q_lvlh_body * port_body_m;
  // |port + s a|^2 = r^2:  s^2 + 2 (port.a) s + |port|^2 - r^2 = 0, the root in front of the port.
  const double pa = port.dot(axis);
  const double disc = pa * pa - port.squaredNorm() + radius_m * radius_m;
  const double s = disc > 0.0 ? std::max(-pa + std::sqrt(disc), 0.0) : 0.0;
  return port + s * axis;
}

bool holding_may_shrink(const HoldingParams& p, double radius_m, const Eigen::Vector3d& chaser_lvlh_m,
                        const Eigen::Quaterniond& q_lvlh_body, const Eigen::Vector3d& port_body_m,
                        double attitude_error_rad) {
  const double off = (chaser_lvlh_m - holding_position(q_lvlh_body, port_body_m, radius_m)).norm();
  const bool aligned = !std::isfinite(attitude_error_rad) || std::abs(attitude_error_rad) <= p.attitude_tolerance_rad;
  return off <= p.tolerance_m && aligned && radius_m > p.radius_min_m;
}

void HoldingRadius::observe(const Eigen::Vector3d& chaser_lvlh_m, const Eigen::Quaterniond& q_lvlh_body,
                            const Eigen::Vector3d& port_body_m, double attitude_error_rad) {
  radius_ = next_;
  if (active() && holding_may_shrink(p_, radius_, chaser_lvlh_m, q_lvlh_body, port_body_m, attitude_error_rad)) {
    next_ = std::max(p_.shrink * radius_, p_.radius_min_m);
    ++shrinks_;
  }
}

HalfSpace holding_row(double radius_m, const Eigen::Vector3d& p, const Eigen::Vector3d& fallback_direction) {
  HalfSpace h;
  Eigen::Vector3d d = p;
  if (!(d.norm() > 1e-12)) d = fallback_direction;
  if (!(d.norm() > 1e-12)) d = Eigen::Vector3d::UnitX();
  h.normal = d.normalized();
  h.bound_m = radius_m;
  return h;
}

EntryCone entry_cone(const Eigen::Quaterniond& q_lvlh_body, const Eigen::Vector3d& port_body_m, double half_angle_rad) {
  const Eigen::Matrix3d R = q_lvlh_body.toRotationMatrix();
  const Eigen::Vector3d x = R.col(0), y = R.col(1);
  const double c = std::cos(half_angle_rad), s = std::sin(half_angle_rad);
  EntryCone cone;
  cone.rows.row(0) = (y * c - x * s).transpose();
  cone.rows.row(1) = (-y * c - x * s).transpose();
  cone.bounds = cone.rows * (q_lvlh_body * port_body_m);
  return cone;
}

double docking_attitude_error_rad(const Eigen::Quaterniond& q_lvlh_chaser, const Eigen::Quaterniond& q_lvlh_target) {
  const Eigen::Vector3d chaser_axis = q_lvlh_chaser * Eigen::Vector3d::UnitX();
  const Eigen::Vector3d wanted = -(q_lvlh_target * Eigen::Vector3d::UnitX());
  return std::atan2(chaser_axis.cross(wanted).norm(), chaser_axis.dot(wanted));
}

}  // namespace rvd::guidance

// The C interface for plug-in laws (flight_sw/include/rvd_corridor.h): the functions above on plain arrays.
namespace {
Eigen::Quaterniond quaternion(const double q[4]) { return Eigen::Quaterniond(q[0], q[1], q[2], q[3]).normalized(); }
Eigen::Vector3d vec(const double v[3]) { return Eigen::Vector3d(v[0], v[1], v[2]); }
void put(const Eigen::Vector3d& v, double out[3]) {
  for (int i = 0; i < 3; ++i) out[i] = v(i);
}
}  // namespace

extern "C" {

void rvd_holding_position(const double q_lvlh_body[4], const double port_body_m[3], double radius_m,
                          double position_lvlh_m[3]) {
  put(rvd::guidance::holding_position(quaternion(q_lvlh_body), vec(port_body_m), radius_m), position_lvlh_m);
}

void rvd_holding_init(rvd_holding_radius* h, double radius_m, double radius_min_m, double shrink,
                      double tolerance_m, double attitude_tolerance_rad) {
  h->radius_m = h->next_radius_m = radius_m;
  h->radius_min_m = radius_min_m;
  h->shrink = shrink;
  h->tolerance_m = tolerance_m;
  h->attitude_tolerance_rad = attitude_tolerance_rad;
}

double rvd_holding_observe(rvd_holding_radius* h, const double chaser_lvlh_m[3], const double q_lvlh_body[4],
                           const double port_body_m[3], double attitude_error_rad) {
  rvd::guidance::HoldingParams p;
  p.radius_min_m = h->radius_min_m;
  p.shrink = h->shrink;
  p.tolerance_m = h->tolerance_m;
  p.attitude_tolerance_rad = h->attitude_tolerance_rad;
  h->radius_m = h->next_radius_m;
  if (rvd::guidance::holding_may_shrink(p, h->radius_m, vec(chaser_lvlh_m), quaternion(q_lvlh_body), vec(port_body_m),
                                        attitude_error_rad))
    h->next_radius_m = std::max(h->shrink * h->radius_m, h->radius_min_m);
  return h->radius_m;
}

void rvd_holding_row(double radius_m, const double about_lvlh_m[3], double normal[3], double* bound_m) {
  const rvd::guidance::HalfSpace h = rvd::guidance::holding_row(radius_m, vec(about_lvlh_m), Eigen::Vector3d::UnitX());
  put(h.normal, normal);
  *bound_m = h.bound_m;
}

void rvd_entry_cone(const double q_lvlh_body[4], const double port_body_m[3], double half_angle_rad,
                    double rows[2][3], double bounds[2]) {
  const rvd::guidance::EntryCone c = rvd::guidance::entry_cone(quaternion(q_lvlh_body), vec(port_body_m), half_angle_rad);
  for (int j = 0; j < 2; ++j) {
    for (int i = 0; i < 3; ++i) rows[j][i] = c.rows(j, i);
    bounds[j] = c.bounds(j);
  }
}

double rvd_docking_attitude_error(const double q_lvlh_chaser[4], const double q_lvlh_target[4]) {
  return rvd::guidance::docking_attitude_error_rad(quaternion(q_lvlh_chaser), quaternion(q_lvlh_target));
}

}  // extern "C"
