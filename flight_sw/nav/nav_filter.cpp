#include "flight_sw/nav/nav_filter.hpp"

#include <algorithm>
#include <cmath>

namespace rvd::nav {

namespace {
bool finite_nonnegative(double v) { return std::isfinite(v) && v >= 0.0; }
}  // namespace

const char* NavFilterParams::validate() const {
  if (!finite_nonnegative(sigma_position_m) || !finite_nonnegative(sigma_velocity_mps))
    return "nav filter sigmas must be finite and >= 0";
  if (!finite_nonnegative(thrust_error_sigma) || thrust_error_sigma >= 1.0)
    return "nav filter thrust_error_sigma must be in [0, 1)";
  if (!(std::isfinite(thrust_error_tau_s) && thrust_error_tau_s > 0.0)) return "nav filter thrust_error_tau_s must be > 0";
  if (!finite_nonnegative(accel_noise_mps2_rthz)) return "nav filter accel_noise_mps2_rthz must be >= 0";
  if (!(gate_chi2 > 0.0)) return "nav filter gate_chi2 must be > 0";
  if (max_rejections < 1) return "nav filter max_rejections must be >= 1";
  return "";
}

const char* to_string(NavUpdate u) {
  switch (u) {
    case NavUpdate::Initialised: return "initialised";
    case NavUpdate::Fused: return "fused";
    case NavUpdate::Gated: return "gated";
    case NavUpdate::Reinitialised: return "reinitialised";
    case NavUpdate::Passthrough: return "passthrough";
    case NavUpdate::Invalid: return "invalid";
  }
  return "unknown";
}

NavFilter::NavFilter(const NavFilterParams& params, double mean_motion_rad_s) : p_(params), n_(mean_motion_rad_s) {
  R_.diagonal() << Eigen::Vector3d::Constant(p_.sigma_position_m * p_.sigma_position_m),
      Eigen::Vector3d::Constant(p_.sigma_velocity_mps * p_.sigma_velocity_mps);
  thruster_.fill(-1);
}

void NavFilter::command(double t_s, const Eigen::Vector3d& dv_lvlh_mps, const std::array<double, 6>& pulse_s) {
  if (!std::isfinite(t_s) || !dv_lvlh_mps.allFinite()) return;
  command_pending_ = true;
  t_cmd_ = t_s;
  dv_cmd_ = dv_lvlh_mps;
  for (int i = 0; i < 3; ++i) {
    const double plus = pulse_s[2 * i], minus = pulse_s[2 * i + 1];
    const double width = std::max(plus, minus);
    const bool fired = std::isfinite(width) && width > 0.0 && dv_lvlh_mps(i) != 0.0;
    thruster_[i] = fired ? (plus >= minus ? 2 * i : 2 * i + 1) : -1;
    centroid_s_(i) = fired && p_.finite_burns ? 0.5 * width : 0.0;
    if (!fired) dv_cmd_(i) = 0.0;
  }
}

void NavFilter::publish(NavUpdate why) {
  est_.x = s_.head<6>();
  est_.P = Ps_.topLeftCorner<6, 6>();
  est_.thrust_error = s_.tail<6>().cwiseMax(-0.3).cwiseMin(0.3);  // what the allocation may rely on
  est_.thrust_error_sigma = std::sqrt(Ps_.bottomRightCorner<6, 6>().diagonal().maxCoeff());
  est_.update = why;
}

void NavFilter::initialise(double t_s, const Vector6d& z, NavUpdate why) {
  s_.head<6>() = z;
  s_.tail<6>().setZero();
  Ps_.setZero();
  Ps_.topLeftCorner<6, 6>() = R_;
  Ps_.bottomRightCorner<6, 6>().diagonal().setConstant(p_.thrust_error_sigma * p_.thrust_error_sigma);
  est_.innovation_chi2 = 0.0;
  t_ = t_s;
  initialised_ = true;
  rejections_ = 0;
  command_pending_ = false;
  publish(why);
}

void NavFilter::predict(double t_s) {
  const double T = t_s - t_;
  // Transition F of [x; b]: x' = Phi x + sum_i g_i dv_i (1 + b_j(i)), b' = a b.
  Matrix12d F = Matrix12d::Zero();
  F.topLeftCorner<6, 6>() = guidance::cw_stm(n_, T);
  const double a = std::exp(-T / p_.thrust_error_tau_s);
  F.bottomRightCorner<6, 6>().diagonal().setConstant(a);
  Vector12d s = F * s_;
  if (command_pending_) {
    for (int i = 0; i < 3; ++i) {
      const int j = thruster_[i];
      if (j < 0) continue;
      // The burn on this axis acts like an impulse at its centroid (clamped to the interval).
      const double tau = std::clamp(t_cmd_ + centroid_s_(i) - t_, 0.0, T);
      const Vector6d g = guidance::cw_stm(n_, T - tau).col(3 + i) * dv_cmd_(i);
      s.head<6>() += g * (1.0 + s_(6 + j));  // the realised delta-v, with this thruster's error
      F.block<6, 1>(0, 6 + j) += g;           // and its sensitivity to that error
    }
    command_pending_ = false;
  }
  Matrix12d P = F * Ps_ * F.transpose();
  const double qa = p_.accel_noise_mps2_rthz * p_.accel_noise_mps2_rthz;
  const double T2 = T * T;
  for (int i = 0; i < 3; ++i) {
    P(i, i) += qa * T2 * T / 3.0;
    P(i, 3 + i) += qa * T2 / 2.0;
    P(3 + i, i) += qa * T2 / 2.0;
    P(3 + i, 3 + i) += qa * T;
  }
  const double sb2 = p_.thrust_error_sigma * p_.thrust_error_sigma;
  P.bottomRightCorner<6, 6>().diagonal().array() += sb2 * (1.0 - a * a);
  s_ = s;
  Ps_ = 0.5 * (P + P.transpose());
  t_ = t_s;
}

const NavEstimate& NavFilter::update(double t_s, const Vector6d& z) {
  if (!std::isfinite(t_s) || !z.allFinite()) {
    // Nothing trustworthy to fuse: keep the prediction (the guidance rejects the input anyway).
    if (initialised_ && std::isfinite(t_s) && t_s >= t_) predict(t_s);
    publish(NavUpdate::Invalid);
    return est_;
  }
  if (p_.passthrough()) {  // nothing is estimated: the thrusters are known only to their prior
    s_.head<6>() = z;
    s_.tail<6>().setZero();
    Ps_.setZero();
    Ps_.topLeftCorner<6, 6>() = R_;
    Ps_.bottomRightCorner<6, 6>().diagonal().setConstant(p_.thrust_error_sigma * p_.thrust_error_sigma);
    t_ = t_s;
    initialised_ = true;
    command_pending_ = false;
    publish(NavUpdate::Passthrough);
    return est_;
  }
  if (!initialised_ || !(t_s >= t_)) {  // first input, or time ran backwards: start afresh
    initialise(t_s, z, NavUpdate::Initialised);
    return est_;
  }
  predict(t_s);
  const Matrix6d S = Ps_.topLeftCorner<6, 6>() + R_;
  const Eigen::LLT<Matrix6d> llt(S);
  if (llt.info() != Eigen::Success) {
    initialise(t_s, z, NavUpdate::Reinitialised);
    ++reinit_;
    return est_;
  }
  const Vector6d nu = z - s_.head<6>();
  const double chi2 = nu.dot(llt.solve(nu));
  est_.innovation_chi2 = chi2;
  if (!(chi2 <= p_.gate_chi2)) {
    ++gated_;
    if (++rejections_ >= p_.max_rejections) {
      initialise(t_s, z, NavUpdate::Reinitialised);
      est_.innovation_chi2 = chi2;
      ++reinit_;
    } else {
      publish(NavUpdate::Gated);
    }
    return est_;
  }
  rejections_ = 0;
  // H = [I 0]: K = P H' S^-1 = P.leftCols(6) S^-1, computed as (S^-1 P.topRows(6))'.
  const Eigen::Matrix<double, 12, 6> K = llt.solve(Ps_.topRows<6>()).transpose();
  s_ += K * nu;
  Matrix12d IKH = Matrix12d::Identity();
  IKH.leftCols<6>() -= K;
  const Matrix12d P = IKH * Ps_ * IKH.transpose() + K * R_ * K.transpose();  // Joseph form
  Ps_ = 0.5 * (P + P.transpose());
  publish(NavUpdate::Fused);
  return est_;
}

}  // namespace rvd::nav
