// The docking corridor of Dong, Ghiglino et al. ("Fast model predictive control with moving obstacle
// avoidance"): a dynamic holding radius around the target (their eq. 9, after Park et al.'s nonlinear
// MPC for docking with a rotating target) and a two-plane entry cone at the docking port (eq. 10).
//
// Holding radius: the chaser is kept outside the circle (sphere) of radius r_hold about the target's
// centre of mass, r_hold^2 <= |rho|^2, linearized about the previous plan's position p like their
// eq. 8: the tangent plane p_hat' rho >= r_hold. Its set point is the holding position, on that
// circle directly in front of the port. r_hold starts at r_hold,0 and shrinks to gamma r_hold at the
// next sample whenever the chaser is within eta of the holding position and within epsilon of the
// docking attitude, down to r_hold,min (the centre-of-mass distance when docked).
//
// Entry cone: two planes through the port with half-angle theta_e about the docking axis, in the
// plane of the target's body x and y axes (their 2-D scenario's plane): h_pm = +-y_b cos(theta_e) -
// x_b sin(theta_e), h_pm' (rho - port) <= 0, i.e. their eq. 10 with n_1 = -h_+, n_2 = h_- (unit rows,
// so a row's excess is the distance outside in metres). Active while the chaser is within r_cone
// of the port.
//
// The same functions are available to plug-in laws through the C interface flight_sw/include/rvd_corridor.h.
#pragma once

#include <Eigen/Dense>
#include <Eigen/Geometry>

namespace rvd::guidance {

struct HoldingParams {
  double radius_m = 0.0;             // r_hold,0; 0: no holding radius
  double radius_min_m = 0.0;         // r_hold,min
  double shrink = 0.95;              // gamma in (0, 1)
  double tolerance_m = 0.0;          // eta: distance to the holding position that lets it shrink
  double attitude_tolerance_rad = 0.0;  // epsilon: chaser attitude error that lets it shrink
};

// Point on the sphere |p| = radius_m about the target's centre of mass, directly in front of the port:
// port + s a with a = q x_body (the docking axis), s >= 0; the port itself when the sphere is inside it.
Eigen::Vector3d holding_position(const Eigen::Quaterniond& q_lvlh_body, const Eigen::Vector3d& port_body_m,
                                 double radius_m);

// Eq. 9's two conditions: the chaser is within eta of the holding position of `radius_m` and within
// epsilon of its docking attitude (attitude_error_rad NaN: unknown, the position alone decides).
bool holding_may_shrink(const HoldingParams& p, double radius_m, const Eigen::Vector3d& chaser_lvlh_m,
                        const Eigen::Quaterniond& q_lvlh_body, const Eigen::Vector3d& port_body_m,
                        double attitude_error_rad);

// The dynamic holding radius over a run (eq. 9). observe() once per control step with the state the step
// plans from: radius() is then the radius this step plans with, and a step that met both conditions
// leaves gamma times it (not below the minimum) for the next one.
class HoldingRadius {
 public:
  HoldingRadius() = default;
  explicit HoldingRadius(const HoldingParams& p) : p_(p), radius_(p.radius_m), next_(p.radius_m) {}
  void reset() { radius_ = next_ = p_.radius_m; shrinks_ = 0; }
  bool active() const { return p_.radius_m > 0.0; }
  void observe(const Eigen::Vector3d& chaser_lvlh_m, const Eigen::Quaterniond& q_lvlh_body,
               const Eigen::Vector3d& port_body_m, double attitude_error_rad);
  double radius() const { return radius_; }
  bool at_minimum() const { return radius_ <= p_.radius_min_m; }
  int shrinks() const { return shrinks_; }
  const HoldingParams& params() const { return p_; }

 private:
  HoldingParams p_;
  double radius_ = 0.0;  // planned with now
  double next_ = 0.0;    // for the next step
  int shrinks_ = 0;
};

// Eq. 9 linearized about p (the previous plan's position for this stage): n' rho >= bound_m, n = p / |p|
// (fallback_direction when p is at the centre), bound_m = radius_m.
struct HalfSpace {
  Eigen::Vector3d normal = Eigen::Vector3d::UnitX();  // unit
  double bound_m = 0.0;
};
HalfSpace holding_row(double radius_m, const Eigen::Vector3d& p, const Eigen::Vector3d& fallback_direction);

// Eq. 10: rows h (unit) and bounds b of h' rho <= b for the cone at the port of a target with attitude q.
struct EntryCone {
  Eigen::Matrix<double, 2, 3> rows = Eigen::Matrix<double, 2, 3>::Zero();
  Eigen::Vector2d bounds = Eigen::Vector2d::Zero();
};
EntryCone entry_cone(const Eigen::Quaterniond& q_lvlh_body, const Eigen::Vector3d& port_body_m, double half_angle_rad);

// Angle [rad] between the chaser's docking axis (its body +x) and the direction it must face to dock
// (minus the target's docking axis): the attitude error of the holding radius' second condition.
double docking_attitude_error_rad(const Eigen::Quaterniond& q_lvlh_chaser, const Eigen::Quaterniond& q_lvlh_target);

}  // namespace rvd::guidance
