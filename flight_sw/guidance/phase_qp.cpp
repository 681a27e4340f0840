#include "flight_sw/guidance/phase_qp.hpp"

#include <algorithm>
#include <cmath>

namespace rvd::guidance {

namespace {
constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;
// The docking set point at most this fraction of r3 out from the port: a set point on r3 itself is
// reached only asymptotically (as r1 and r2 are, "Phase switching"), and the run would not dock.
constexpr double kDockingAimOfR3 = 0.9;
}  // namespace

PhaseQp::StageLayout PhaseQp::stage(int i) const {
  StageLayout L;
  const bool terminal = (i == N_);
  auto row = [&L](int height) { int r = L.nc; L.nc += height; return r; };
  auto soft = [&L](int height) { L.ns += height; };
  if (!terminal) L.nu = 3;  // delta-v
  if (!terminal) L.box_row = row(6);
  switch (phase_) {
    case Phase::Rendezvous:
      if (i >= 1) L.keepout_row = row(1);
      // The closing-speed row towards the stage's keep-out plane carries the rendezvous' braking curve
      // (none with a holding radius: no keep-out planes).
      if (i >= 1 && params_.margins.rendezvous_brake_fraction > 0.0 && !params_.holding_in(Phase::Rendezvous))
        L.speed_row = row(1);
      if (one_norm_) {
        L.t_row = row(12);
        soft(12);
        if (!terminal) {
          L.w_row = row(6);
          soft(6);
        }
      }
      if (terminal && cone_slacks_) {
        L.cone_row = row(4);
        soft(4);
      }
      break;
    case Phase::Approach:
      if (i >= 1) L.keepout_row = row(1);  // the overshoot plane
      // The closing-speed row carries the cap and the braking curve (none with a holding radius: no plane).
      if (i >= 1 && (params_.margins.approach_speed_cap_mps > 0.0 ||
                     (params_.margins.approach_brake_fraction > 0.0 && !params_.holding_in(Phase::Approach))))
        L.speed_row = row(1);
      if (i >= 1 && cone_slacks_) {
        L.cone_row = row(4);
        soft(4);
      }
      break;
    case Phase::Docking:
    case Phase::Docked:
      if (i >= 1) {
        L.cone_row = row(4);
        L.vel_row = row(6);
        if (params_.docking_stop_penalty > 0.0) {
          L.stop_row = row(1);
          soft(1);
        }
      }
      break;
  }
  // The entry cone and the obstacle rows last, so that every other block keeps its place; always soft.
  if (i >= 1 && params_.entry_cone_in(phase_)) {
    L.entry_row = row(2);
    soft(2);
  }
  if (i >= 1 && params_.obstacle_capacity > 0) {
    L.obstacle_row = row(2 * params_.obstacle_capacity);
    soft(2 * params_.obstacle_capacity);
  }
  // Recovery variant: every hard state row of the stage is soft, at recovery_weight per unit of
  // violation (an exact penalty), so the QP is always feasible.
  if (recovery_ && i >= 1) {
    if (L.keepout_row >= 0) soft(1);
    if (L.speed_row >= 0) soft(1);
    if (phase_ == Phase::Docking) soft(10);  // the docking cone and |v|_inf; the approach cone is soft already
  }
  return L;
}

KeepoutPlanes plan_keepout_rotation(const Eigen::Vector3d& rho, const Eigen::Vector3d& axis, int N,
                                    double max_step_rad, KeepoutDirection direction) {
  // Towards the antipode of the axis every great circle is about as short, and u0 x axis, the short
  // way's turn, swings with noise-level components of rho: on a V-bar start opposite its port it
  // turned by 35-80 degrees from one period to the next, and each swing moved every keep-out plane of
  // the plan (a warm start the interior point then needs twice its usual iterations from). Out of
  // reach, the turn leans towards the natural circulation's by this share of -cos(theta): continuous
  // through the antipode, nothing where the axis is within reach or less than 90 degrees away.
  constexpr double kAntipodeLean = 0.25;
  KeepoutPlanes plan;
  const double r = rho.norm();
  if (!(r > 1e-9) || N < 1) return plan;  // at the CoM there is no direction to turn from
  const Eigen::Vector3d u0 = rho / r;
  const double theta = std::acos(std::clamp(u0.dot(axis), -1.0, 1.0));
  if (theta < 1e-9) return plan;  // already on the axis
  const Eigen::Vector3d natural(0.0, 0.0, -1.0);  // CW relative orbits circulate about -z of LVLH
  Eigen::Vector3d lean = natural - natural.dot(u0) * u0;  // the natural circulation's turn of u0
  if (lean.norm() < 1e-9) lean = u0.unitOrthogonal();
  lean.normalize();
  const Eigen::Vector3d k = u0.cross(axis);  // the short way's turn, |k| = sin(theta)
  const bool reachable = theta <= N * max_step_rad;
  // Out of reach, with the short way against the natural circulation: go round the way the relative orbit drifts.
  plan.natural_way = direction == KeepoutDirection::NaturalMotion && !reachable && k.dot(natural) < 0.0;
  Eigen::Vector3d turn = plan.natural_way ? Eigen::Vector3d(-k) : k;
  if (!reachable) turn += kAntipodeLean * std::max(0.0, -std::cos(theta)) * lean;
  if (turn.norm() < 1e-12) turn = lean;  // exactly opposite the axis
  plan.rotation_axis = turn.normalized();
  plan.total_rad = plan.natural_way ? 2.0 * kPi - theta : theta;
  plan.step_rad = std::min(plan.total_rad / N, max_step_rad);
  return plan;
}

Matrix6d solve_dare(const Matrix6d& A, const Matrix63d& B, const Matrix6d& Q, const Eigen::Matrix3d& R) {
  Matrix6d P = Q;
  for (int it = 0; it < 100000; ++it) {
    const Eigen::Matrix3d S = R + B.transpose() * P * B;
    const Eigen::Matrix<double, 3, 6> K = S.ldlt().solve(B.transpose() * P * A);
    Matrix6d Pn = Q + A.transpose() * P * A - A.transpose() * P * B * K;
    Pn = 0.5 * (Pn + Pn.transpose());
    const double change = (Pn - P).cwiseAbs().maxCoeff();
    P = Pn;
    if (change <= 1e-12 * std::max(1.0, P.cwiseAbs().maxCoeff())) break;
  }
  return P;
}

PhaseQp::PhaseQp(Phase phase, const GuidanceParams& params, bool recovery)
    : phase_(phase), params_(params), recovery_(recovery) {
  if (phase_ == Phase::Docked) phase_ = Phase::Docking;
  const PhaseParams& pp = params_.phase(phase_);
  N_ = pp.N;
  Ts_ = pp.Ts_s;
  u_max_ = pp.u_max_mps;
  n_ = params_.mean_motion_rad_s();
  one_norm_ = (phase_ == Phase::Rendezvous && params_.rendezvous_objective == RendezvousObjective::OneNorm);
  cone_slacks_ = (phase_ != Phase::Docking) && pp.lambda > 0.0;
  centroid_s_ = params_.finite_burns ? std::min(0.5 * max_pulse_s(u_max_, params_.thrusters), 0.5 * Ts_) : 0.0;
  cw_burn_model(n_, Ts_, centroid_s_, A_, B_);
  Qw_ = pp.Q_diag.asDiagonal();
  Rw_ = pp.R_diag;
  if (pp.terminal_weight == TerminalWeight::Dare && !one_norm_)
    Qf_ = solve_dare(A_, B_, Qw_, Eigen::Matrix3d(Rw_.asDiagonal()));
  else
    Qf_ = Qw_;

  solver::OcpQpDims dims;
  dims.N = N_;
  dims.nx = 6;
  for (int i = 0; i <= N_; ++i) {
    const StageLayout L = stage(i);
    dims.nu.push_back(L.nu);
    dims.nc.push_back(L.nc);
    dims.ns.push_back(L.ns);
  }
  qp_ = solver::OcpQp(dims);
  keepout_normals_.assign(N_ + 1, Eigen::Vector3d::Zero());
  reference_.assign(N_ + 1, Vector6d::Zero());

  // Everything that does not change between periods is filled once here.
  for (int i = 0; i <= N_; ++i) {
    const StageLayout L = stage(i);
    if (i < N_) {
      qp_.A[i] = A_;
      qp_.B[i].leftCols<3>() = B_;
    }
    if (!one_norm_) {
      qp_.Q[i] = 2.0 * (i < N_ ? Qw_ : Qf_);
      if (i < N_) qp_.R[i].topLeftCorner<3, 3>() = 2.0 * Eigen::Matrix3d(Rw_.asDiagonal());
    }
    if (L.box_row >= 0) {
      qp_.D[i].block<3, 3>(L.box_row, 0).setIdentity();
      qp_.D[i].block<3, 3>(L.box_row + 3, 0) = -Eigen::Matrix3d::Identity();
      // Bounds are set per build (fill_input_box): they follow what the thrusters are known to deliver.
    }
    int ns = 0;  // soft rows: row index, linear and quadratic penalty
    auto soft = [&](int row, int height, double linear, double quadratic) {
      for (int k = 0; k < height; ++k, ++ns) {
        qp_.idxs[i][ns] = row + k;
        qp_.zs[i](ns) = linear;
        qp_.Zs[i](ns) = quadratic;
      }
    };
    if (L.cone_row >= 0 && phase_ != Phase::Docking) soft(L.cone_row, 4, pp.lambda, 0.0);  // H rho <= 0, soft
    if (L.t_row >= 0) {  // 1-norm state term: +-Q (x - xs) <= 0, soft at 1: |Q (x - xs)|_1
      const Vector6d w = (i < N_ ? Qw_ : Qf_).diagonal();
      qp_.C[i].block<6, 6>(L.t_row, 0) = w.asDiagonal();
      qp_.C[i].block<6, 6>(L.t_row + 6, 0) = -Matrix6d(w.asDiagonal());
      soft(L.t_row, 12, 1.0, 0.0);
    }
    if (L.w_row >= 0) {  // 1-norm input term: +-R u <= 0, soft at 1: |R u|_1
      qp_.D[i].block<3, 3>(L.w_row, 0) = Rw_.asDiagonal();
      qp_.D[i].block<3, 3>(L.w_row + 3, 0) = -Eigen::Matrix3d(Rw_.asDiagonal());
      soft(L.w_row, 6, 1.0, 0.0);
    }
    if (L.vel_row >= 0) {
      qp_.C[i].block<3, 3>(L.vel_row, 3).setIdentity();
      qp_.C[i].block<3, 3>(L.vel_row + 3, 3) = -Eigen::Matrix3d::Identity();
    }
    if (L.stop_row >= 0) soft(L.stop_row, 1, params_.docking_stop_penalty, 0.0);
    if (recovery_ && i >= 1) {
      const double lin = params_.recovery_weight, quad = 2.0 * params_.recovery_quadratic;
      if (L.keepout_row >= 0) soft(L.keepout_row, 1, lin, quad);
      if (L.speed_row >= 0) soft(L.speed_row, 1, lin, quad);
      if (phase_ == Phase::Docking) {  // the docking cone is hard; the approach cone is already soft
        soft(L.cone_row, 4, lin, quad);
        // |v|_inf outweighs the cone: when a spinning target's cone cannot be held at v_max (r omega >
        // v_max), falling behind the cone far from the port is the lesser harm than chasing it faster.
        soft(L.vel_row, 6, params_.recovery_speed_factor * lin, params_.recovery_speed_factor * quad);
      }
    }
    if (L.entry_row >= 0) {  // inactive until fill_entry_cone: 0 <= 1
      soft(L.entry_row, 2, params_.entry_cone_penalty, 2.0 * params_.obstacle_penalty_quadratic);
      qp_.d[i].segment<2>(L.entry_row).setOnes();
    }
    if (L.obstacle_row >= 0) {  // inactive until fill_obstacles: 0 <= 1
      soft(L.obstacle_row, 2 * params_.obstacle_capacity, params_.obstacle_penalty,
           2.0 * params_.obstacle_penalty_quadratic);
      qp_.d[i].segment(L.obstacle_row, 2 * params_.obstacle_capacity).setOnes();
    }
  }
}

int PhaseQp::keepout_row(int i) const { return stage(i).keepout_row; }
int PhaseQp::cone_row(int i) const { return stage(i).cone_row; }
int PhaseQp::velocity_row(int i) const { return stage(i).vel_row; }
int PhaseQp::stop_row(int i) const { return stage(i).stop_row; }
int PhaseQp::obstacle_row(int i) const { return stage(i).obstacle_row; }
int PhaseQp::entry_row(int i) const { return stage(i).entry_row; }

void PhaseQp::build(const Vector6d& x0, const TargetState& target, const EstimateQuality& quality) {
  x0_ = x0;
  quality_ = quality;
  for (int i = 0; i < N_; ++i) fill_input_box(i);
  switch (phase_) {
    case Phase::Rendezvous:
      if (one_norm_)
        build_rendezvous_one_norm(x0, target);
      else
        build_rendezvous(x0, target);
      break;
    case Phase::Approach: build_approach(x0, target); break;
    case Phase::Docking:
    case Phase::Docked: build_docking(x0, target); break;
  }
  if (params_.entry_cone_in(phase_)) fill_entry_cone(x0, target);
  if (params_.obstacle_capacity > 0) fill_obstacles(x0);
}

// The holding circle (eq. 9) linearized about the previous plan's positions, in the stage rows of the
// stand-off constraint: p_hat_i' rho_i >= r, with r no more than the current range (a chaser that is
// inside is asked to get no closer, not to jump out) and grown by the estimate margin and the chord
// margin, as the keep-out plane.
void PhaseQp::fill_holding_rows(const Vector6d& x0, double radius_m) {
  const double r = std::min(radius_m + params_.margins.keepout_m + estimate_margin_m(), x0.head<3>().norm());
  keepout_radius_used_ = r;
  keepout_normals_[0] = x0.head<3>().norm() > 1e-12 ? Eigen::Vector3d(x0.head<3>().normalized()) : Eigen::Vector3d::UnitX();
  for (int i = 1; i <= N_; ++i) {
    const Eigen::Vector3d about = predicted_ != nullptr ? predicted_[i] : x0.head<3>();
    const HalfSpace h = holding_row(r, about, x0.head<3>());
    keepout_normals_[i] = h.normal;
    const int row = stage(i).keepout_row;
    qp_.C[i].block<1, 3>(row, 0) = -h.normal.transpose();
    qp_.d[i](row) = -h.bound_m;
  }
}

// Set point: the holding position of the current radius, turning with the target over the horizon.
void PhaseQp::fill_holding_setpoints(const TargetState& target) {
  const Eigen::Vector3d w = omega_lvlh(target);
  for (int i = 0; i <= N_; ++i) {
    const Eigen::Vector3d p = holding_position(attitude_after(target, i * Ts_), params_.port_body_m, holding_radius_m_);
    reference_[i].head<3>() = p;
    reference_[i].tail<3>() = w.cross(p);
  }
}

// Eq. 10 on stages 1..N with the target's predicted attitude, while the chaser is within the cone's
// range of the port; inactive rows (0 <= 1) otherwise.
void PhaseQp::fill_entry_cone(const Vector6d& x0, const TargetState& target) {
  const Eigen::Vector3d port0 = target.q_lvlh_body * params_.port_body_m;
  entry_active_ = (x0.head<3>() - port0).norm() <= params_.entry_cone_range_m;
  const double half_angle = params_.entry_cone_half_angle_deg * kDeg;
  for (int i = 1; i <= N_; ++i) {
    const int row = stage(i).entry_row;
    if (!entry_active_) {
      qp_.C[i].block<2, 3>(row, 0).setZero();
      qp_.d[i].segment<2>(row).setOnes();
      continue;
    }
    const EntryCone c = entry_cone(attitude_after(target, i * Ts_), params_.port_body_m, half_angle);
    qp_.C[i].block<2, 3>(row, 0) = c.rows;
    qp_.d[i].segment<2>(row) = c.bounds.array() - estimate_margin_m();
  }
}

// Each held obstacle, linearized on stage i about the chaser position the previous plan predicts for
// t + i Ts (obstacles.hpp). Two rows per obstacle and stage: the stage's own tangent plane, and the next
// stage's plane moved with the obstacle to this stage's time. So both ends of every period's path lie
// outside one plane (relative to the obstacle), and with them the whole, nearly straight, relative
// path of the period: a plane per sample alone lets the path between samples cut through the zone
// when it moves further in a period than the zone is wide. The rows of empty slots stay 0 <= 1.
void PhaseQp::fill_obstacles(const Vector6d& x0) {
  const int K = params_.obstacle_capacity;
  const int held = obstacles_ != nullptr && predicted_ != nullptr ? std::min(obstacles_->count, K) : 0;
  const double margin = params_.obstacle_margin_m + estimate_margin_m();
  for (int k = 0; k < K; ++k) {
    if (k >= held) {
      for (int i = 1; i <= N_; ++i) {
        const int row = stage(i).obstacle_row + 2 * k;
        qp_.C[i].block<2, 3>(row, 0).setZero();
        qp_.d[i].segment<2>(row).setOnes();
      }
      continue;
    }
    const Obstacle& o = obstacles_->items[k];
    const Eigen::Matrix3d S = obstacle_shape(o, margin);
    auto centre_at = [&](int i) { return obstacle_position(o, obstacle_t_s_ + i * Ts_, n_, params_.obstacle_prediction); };
    const bool hyperplane = params_.obstacle_method == ObstacleMethod::RotatingHyperplane;
    if (hyperplane && obstacle_surface_distance_m(o, x0.head<3>(), obstacle_t_s_, n_, params_.obstacle_prediction) >
                          params_.hyperplane_active_range_m + margin) {
      for (int i = 1; i <= N_; ++i) {  // out of range: inactive
        const int row = stage(i).obstacle_row + 2 * k;
        qp_.C[i].block<2, 3>(row, 0).setZero();
        qp_.d[i].segment<2>(row).setOnes();
      }
      continue;
    }
    const Eigen::Matrix3d S_inverse = S.inverse();
    auto plane = [&](int i, const Eigen::Vector3d& c) {
      return hyperplane ? rotating_hyperplane(o, c, S_inverse, Eigen::Vector3d::Zero(), obstacle_t_s_ + i * Ts_,
                                              params_.hyperplane_rate_rad_s)
                        : linearize_obstacle(c, S, predicted_[i], x0.head<3>() - c);
    };
    Eigen::Vector3d centre = centre_at(1);
    ObstacleRow own = plane(1, centre);
    for (int i = 1; i <= N_; ++i) {
      const int row = stage(i).obstacle_row + 2 * k;
      ObstacleRow next = own;
      Eigen::Vector3d centre_next = centre;
      if (i < N_) {
        centre_next = centre_at(i + 1);
        next = plane(i + 1, centre_next);
      }
      qp_.C[i].block<1, 3>(row, 0) = -own.normal.transpose();  // n' rho_i >= b
      qp_.d[i](row) = -own.bound_m;
      // The next plane, at this stage's obstacle position: n' (rho_i - c_i) >= n' (c_next' - c_next).
      qp_.C[i].block<1, 3>(row + 1, 0) = -next.normal.transpose();
      qp_.d[i](row + 1) = -(next.bound_m - next.normal.dot(centre_next - centre));
      own = next;
      centre = centre_next;
    }
  }
}

// |dv| bounds of stage i per thruster direction: what thruster j is known to deliver at its longest pulse,
// s_j - k sigma_s of nominal (never more than u_max, the guidance's own limit), less the static margin;
// later stages keep a reserve on top, so that the next plan can absorb what this period's disturbances
// did to the state (a plan that rides the limit of its authority jumps, or fails, when a few centimetres
// are off). The allocation lengthens the pulses of a weak thruster, so a plan within these bounds is flown.
void PhaseQp::fill_input_box(int i) {
  const int row = stage(i).box_row;
  if (row < 0) return;
  const Margins& m = params_.margins;
  const double common = u_max_ * (1.0 - m.input_fraction) * (i == 0 ? 1.0 : 1.0 - m.plan_reserve_fraction);
  const double k_sigma = m.estimate_sigmas * quality_.thrust_scale_sigma;
  for (int axis = 0; axis < 3; ++axis) {
    for (int sign = 0; sign < 2; ++sign) {  // rows +axis, then -axis; thrusters +axis = 2 axis, -axis = 2 axis + 1
      const double s = quality_.thrust_scale[2 * axis + sign];
      const double deliverable = std::isfinite(s) ? std::clamp(s - k_sigma, 0.5, 1.0) : 0.5;
      qp_.d[i](row + 3 * sign + axis) = common * deliverable;
    }
  }
}

// Set point on the docking axis at `range_m` from the CoM, rotating with the target over the horizon.
void PhaseQp::fill_setpoints(const TargetState& target, double range_m) {
  const Eigen::Vector3d w = omega_lvlh(target);
  for (int i = 0; i <= N_; ++i) {
    const Eigen::Vector3d p = range_m * (attitude_after(target, i * Ts_) * Eigen::Vector3d::UnitX());
    reference_[i].head<3>() = p;
    reference_[i].tail<3>() = w.cross(p);
  }
}

void PhaseQp::fill_keepout(const Vector6d& x0, const TargetState& target) {
  const Eigen::Vector3d rho = x0.head<3>();
  const Eigen::Vector3d axis_N = attitude_after(target, N_ * Ts_) * Eigen::Vector3d::UnitX();
  keepout_plan_ = plan_keepout_rotation(rho, axis_N, N_, params_.keepout_rate_cap_factor * n_ * Ts_,
                                        params_.keepout_direction);
  // Started inside the sphere (possible for random starts): keep at least the current range rather
  // than demand an impossible jump back out; the set point then pulls the chaser outwards.
  const double r = rho.norm();
  keepout_radius_used_ = std::min(params_.keepout_radius_m + params_.margins.keepout_m + estimate_margin_m(), r);
  const Eigen::Vector3d u0 = r > 1e-9 ? Eigen::Vector3d(rho / r) : axis_N;
  keepout_normals_[0] = u0;
  for (int i = 1; i <= N_; ++i) {
    const Eigen::Vector3d n_i = Eigen::AngleAxisd(i * keepout_plan_.step_rad, keepout_plan_.rotation_axis) * u0;
    keepout_normals_[i] = n_i;
    const int row = stage(i).keepout_row;
    qp_.C[i].block<1, 3>(row, 0) = -n_i.transpose();  // n_i' rho_i >= r1
    qp_.d[i](row) = -keepout_radius_used_;
  }
  fill_keepout_braking(x0);
}

// Braking curve of the rendezvous, as the approach's towards its overshoot plane: on stages 1..N the
// closing speed towards the stage's keep-out plane, -n_i' v_i, no faster than stops the chaser before the
// sphere with rendezvous_brake_fraction of the braking authority (per-period decrements dv: Ts (c^2 / 2 dv
// + c / 2) = d), from a lower bound of its distance (the range now less r and what closing at the earlier
// stages' bounds covers), and never below what braking at 90 % of the planned authority reaches from the
// closing speed now (so the row can always be met). Without it a 15-stage rendezvous (450 s) round a
// turning target planned at full thrust towards the sphere while the planes still turned ahead of the
// chaser; once its direction met the docking axis they stopped turning, the braking no longer fitted and
// the chaser ended 20-25 m inside the sphere (3 of 400 disturbed random starts). The range, not the
// plane's distance from the chaser now: a plane turned far ahead is near the chaser now but not where the
// plan slides round to, and bounding by it made one plan push away from the target for good.
void PhaseQp::fill_keepout_braking(const Vector6d& x0) {
  if (stage(1).speed_row < 0) return;
  const Margins& m = params_.margins;
  const double slowdown = slowdown_mps();
  const double range = x0.head<3>().norm();
  double travelled = 0.0, closing = std::max(-keepout_normals_[1].dot(x0.tail<3>()), 0.0);
  for (int i = 1; i <= N_; ++i) {
    const Eigen::Vector3d& n_i = keepout_normals_[i];
    const double dv = m.rendezvous_brake_fraction * braking_authority_mps(n_i);
    travelled += Ts_ * closing;
    const double d = std::max(range - keepout_radius_used_ - travelled, 0.0);
    // Never below the speed this braking stops within half the horizon: a plan sees such a braking
    // whole, and its keep-out rows hold it. Lower bounds only fought the set point near the sphere: rows
    // tight on every stage with multipliers of 1e5, and the interior point's numerical_error in 15-25 of
    // 14000 in-process steps (the active-set method solved the same QPs).
    const double limit = std::max(braking_curve_mps(dv, d), 0.5 * N_ * dv);
    const double bound = std::max(limit, -n_i.dot(x0.tail<3>()) - i * slowdown);
    const int row = stage(i).speed_row;
    qp_.C[i].block<1, 3>(row, 3) = -n_i.transpose();  // -n_i' v_i <= bound
    qp_.d[i](row) = bound;
    closing = std::max(bound, 0.0);
  }
}

// The rendezvous set point's range from the target: outside the keep-out sphere, or the origin
// when the no-set-point variant (Table 3.6) is chosen.
double PhaseQp::rendezvous_setpoint_range_m() const {
  return params_.rendezvous_use_setpoint ? params_.keepout_radius_m + params_.rendezvous_setpoint_offset_m : 0.0;
}

void PhaseQp::build_rendezvous(const Vector6d& x0, const TargetState& target) {
  const PhaseParams& pp = params_.rendezvous;
  const bool holding = params_.holding_in(Phase::Rendezvous);
  if (holding)
    fill_holding_setpoints(target);
  else
    fill_setpoints(target, rendezvous_setpoint_range_m());
  for (int i = 0; i <= N_; ++i) qp_.q[i].noalias() = -qp_.Q[i] * reference_[i];
  if (holding)
    fill_holding_rows(x0, holding_radius_m_);
  else
    fill_keepout(x0, target);
  if (cone_slacks_) {  // terminal cone penalty with the pyramid predicted at t_N (sec 3.4)
    const Matrix43d H = pyramid_rows_lvlh(attitude_after(target, N_ * Ts_), pp.los_half_angle_deg * kDeg);
    qp_.C[N_].block<4, 3>(stage(N_).cone_row, 0) = H;
  }
}

void PhaseQp::build_rendezvous_one_norm(const Vector6d& x0, const TargetState& target) {
  const PhaseParams& pp = params_.rendezvous;
  const bool holding = params_.holding_in(Phase::Rendezvous);
  if (holding)
    fill_holding_setpoints(target);
  else
    fill_setpoints(target, rendezvous_setpoint_range_m());
  for (int i = 0; i <= N_; ++i) {
    const StageLayout L = stage(i);
    const Vector6d qe = (i < N_ ? Qw_ : Qf_).diagonal().cwiseProduct(reference_[i]);
    qp_.d[i].segment<6>(L.t_row) = qe;        //  Q x - t <=  Q xs
    qp_.d[i].segment<6>(L.t_row + 6) = -qe;   // -Q x - t <= -Q xs
  }
  if (holding)
    fill_holding_rows(x0, holding_radius_m_);
  else
    fill_keepout(x0, target);
  if (cone_slacks_) {
    const Matrix43d H = pyramid_rows_lvlh(attitude_after(target, N_ * Ts_), pp.los_half_angle_deg * kDeg);
    qp_.C[N_].block<4, 3>(stage(N_).cone_row, 0) = H;
  }
}

void PhaseQp::build_approach(const Vector6d& x0, const TargetState& target) {
  const PhaseParams& pp = params_.approach;
  // Between samples a spinning target turns its corridor and its overshoot plane by omega Ts.
  const double turn = omega_lvlh(target).norm() * Ts_;
  const double turning = params_.margins.rotating_cone_factor * turn * turn;
  const double cone_margin = params_.margins.approach_cone_m + estimate_margin_m() + turning * x0.head<3>().norm();
  // The braking burn before a sample may be short by k sigma_s of it: (Ts - t_c) of that velocity.
  const double braking = params_.margins.estimate_sigmas * quality_.thrust_scale_sigma * u_max_ * (Ts_ - centroid_s_);
  const double plane_m = params_.approach_stop_m + params_.margins.overshoot_m + estimate_margin_m() + braking +
                         turning * params_.approach_stop_m;
  // Closing-speed cap, reached from the current closing speed at 90 % of the planned authority per period.
  const double cap = params_.margins.approach_speed_cap_mps;
  const double closing0 = -(target.q_lvlh_body * Eigen::Vector3d::UnitX()).dot(x0.tail<3>());
  const double slowdown = slowdown_mps();
  // Braking curve: the fastest closing speed from which per-period decrements of approach_brake_fraction of
  // the later stages' braking authority stop the chaser at the plane (discrete: Ts (c^2 / 2 dv + c / 2) = d).
  // Without it the cost has the plan brake at the last moment with all of that authority: when the
  // estimate of the braking thruster drops a few per cent during the braking (a thruster unused since the
  // rendezvous), the hard plane can then only be held through the CW coupling, by a lateral swing out of
  // the (soft) corridor. The distance is bounded below by closing at the stages' caps from the plane's
  // distance now.
  // (The holding radius takes the plane's place where it is on: no curve then.)
  const bool holding = params_.holding_in(Phase::Approach);
  const Eigen::Vector3d axis0 = target.q_lvlh_body * Eigen::Vector3d::UnitX();
  const double brake_dv = holding ? 0.0 : params_.margins.approach_brake_fraction * braking_authority_mps(axis0);
  double reach = axis0.dot(x0.head<3>()) - plane_m;
  double closing = std::max(closing0, 0.0);
  if (holding)
    fill_holding_setpoints(target);
  else
    fill_setpoints(target, params_.approach_stop_m + params_.approach_setpoint_offset_m);
  for (int i = 0; i <= N_; ++i) {
    qp_.q[i].noalias() = -qp_.Q[i] * reference_[i];
    const StageLayout L = stage(i);
    const Eigen::Quaterniond q_i = attitude_after(target, i * Ts_);
    if (L.keepout_row >= 0 && !holding) {  // overshoot plane n_cone' rho >= r2 (eq 3.9)
      const Eigen::Vector3d axis = q_i * Eigen::Vector3d::UnitX();
      keepout_normals_[i] = axis;
      qp_.C[i].block<1, 3>(L.keepout_row, 0) = -axis.transpose();
      qp_.d[i](L.keepout_row) = -plane_m;
    }
    if (L.speed_row >= 0) {  // -a' v <= cap_i
      // No cap: faster than the plan can reach with all of its authority, so the row never binds.
      double limit = cap > 0.0 ? cap : std::abs(closing0) + (i + 1) * u_max_;
      if (brake_dv > 0.0) {
        reach -= Ts_ * closing;
        const double d = std::max(reach, 0.0);
        limit = std::min(limit, braking_curve_mps(brake_dv, d));
      }
      const double bound = std::max(limit, closing0 - i * slowdown);
      qp_.C[i].block<1, 3>(L.speed_row, 3) = -(q_i * Eigen::Vector3d::UnitX()).transpose();
      qp_.d[i](L.speed_row) = bound;
      closing = std::max(bound, 0.0);
    }
    if (L.cone_row >= 0) {  // the approach cone has its apex at the CoM; H rho - s <= -margin
      qp_.C[i].block<4, 3>(L.cone_row, 0) = pyramid_rows_lvlh(q_i, pp.los_half_angle_deg * kDeg);
      qp_.d[i].segment<4>(L.cone_row).setConstant(-cone_margin);
    }
  }
  if (holding) fill_holding_rows(x0, holding_radius_m_);  // in place of the overshoot plane
}

// How fast a closing-speed bound may fall from one stage to the next: 90 % of the authority the later
// stages plan with, so the plan can always meet it from the closing speed now.
double PhaseQp::slowdown_mps() const {
  const Margins& m = params_.margins;
  return 0.9 * u_max_ * (1.0 - m.input_fraction) * (1.0 - m.plan_reserve_fraction) *
         std::max(0.5, 1.0 - m.estimate_sigmas * quality_.thrust_scale_sigma);
}

// The fastest closing speed from which per-period decrements dv stop the chaser within d (discrete,
// impulsive: Ts (c^2 / 2 dv + c / 2) = d).
double PhaseQp::braking_curve_mps(double dv, double d) const {
  return 0.5 * (std::sqrt(dv * dv + 8.0 * dv * d / Ts_) - dv);
}

// Delta-v per period along `axis` that the later stages' input bounds (stage 1) allow every thruster
// that brakes motion towards -axis: the smallest bound of the axes the docking axis has a part in.
double PhaseQp::braking_authority_mps(const Eigen::Vector3d& axis) const {
  const int row = stage(1).box_row;
  if (row < 0) return 0.0;
  double authority = u_max_;
  for (int k = 0; k < 3; ++k)
    if (std::abs(axis(k)) >= 0.1) authority = std::min(authority, qp_.d[1](row + (axis(k) > 0.0 ? 0 : 3) + k));
  return authority;
}

void PhaseQp::build_docking(const Vector6d& x0, const TargetState& target) {
  (void)x0;
  const PhaseParams& pp = params_.docking;
  const Margins& m = params_.margins;
  const double cone_margin = m.docking_cone_m + estimate_margin_m();
  const double v_bound = params_.v_max_mps - m.v_max_mps - m.estimate_sigmas * quality_.velocity_mps;
  const Eigen::Vector3d w = omega_lvlh(target);
  // The set point: on the docking axis, inside the cone the margins tighten (its apex lies
  // cone_margin / sin(half-angle) out from the port), and inside r3 so that the docked declaration
  // is met on the way in. Aimed at the port, the plan's tail sat on the apex with all four facets
  // active on every stage (four rows on three coordinates) and the active set churned near the port.
  const double apex_m = cone_margin / std::sin(pp.los_half_angle_deg * kDeg);
  const double aim_m = std::min(apex_m + params_.docking_setpoint_offset_m, kDockingAimOfR3 * params_.dock_tolerance_m);
  const Eigen::Vector3d aim_body = params_.port_body_m + Eigen::Vector3d::UnitX() * aim_m;
  for (int i = 0; i <= N_; ++i) {
    const Eigen::Quaterniond q_i = attitude_after(target, i * Ts_);
    const Eigen::Vector3d port = q_i * params_.port_body_m;
    const Eigen::Vector3d aim = q_i * aim_body;
    reference_[i].head<3>() = aim;
    reference_[i].tail<3>() = w.cross(aim);
    qp_.q[i].noalias() = -qp_.Q[i] * reference_[i];
    const StageLayout L = stage(i);
    if (L.cone_row >= 0) {  // hard cone with its apex at the port: H (rho - port) <= 0 (eq 3.12)
      const Matrix43d H = pyramid_rows_lvlh(q_i, pp.los_half_angle_deg * kDeg);
      qp_.C[i].block<4, 3>(L.cone_row, 0) = H;
      qp_.d[i].segment<4>(L.cone_row).noalias() = H * port;
      qp_.d[i].segment<4>(L.cone_row).array() -= cone_margin;
    }
    if (L.vel_row >= 0) qp_.d[i].segment<6>(L.vel_row).setConstant(v_bound);
    if (L.stop_row >= 0) {  // -axis' rho <= -axis' aim: no nearer the port than the set point
      const Eigen::Vector3d axis = q_i * Eigen::Vector3d::UnitX();
      qp_.C[i].block<1, 3>(L.stop_row, 0) = -axis.transpose();
      qp_.d[i](L.stop_row) = -axis.dot(aim);
    }
  }
}


}  // namespace rvd::guidance
