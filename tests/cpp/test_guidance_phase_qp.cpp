// Phase QP builders: shapes, dynamics, and constraint rows against geometry computed here.
#include <doctest/doctest.h>

#include <cmath>

#include "flight_sw/guidance/phase_qp.hpp"

using namespace rvd::guidance;

namespace {
const double kDeg = M_PI / 180.0;
TargetState vbar_target(double spin_deg_s = 0.0) {
  TargetState t;
  t.q_lvlh_body = Eigen::AngleAxisd(-90.0 * kDeg, Eigen::Vector3d::UnitZ());
  t.omega_body_rad_s = Eigen::Vector3d(0, 0, spin_deg_s * kDeg);
  return t;
}
Vector6d state(double x, double y, double z, double vx, double vy, double vz) {
  Vector6d s;
  s << x, y, z, vx, vy, vz;
  return s;
}
// The linear penalty of row `row` on stage i when it is a soft row, -1 when it is hard.
double soft_penalty(const rvd::solver::OcpQp& qp, int i, int row) {
  if (qp.dims.ns.empty()) return -1.0;
  for (int k = 0; k < qp.dims.ns[i]; ++k)
    if (qp.idxs[i][k] == row) return qp.zs[i](k);
  return -1.0;
}
}  // namespace

TEST_CASE("every phase QP is consistent, with the CW dynamics and the Table 3.1 horizons") {
  GuidanceParams p;
  const double n = p.mean_motion_rad_s();
  for (Phase ph : {Phase::Rendezvous, Phase::Approach, Phase::Docking}) {
    for (bool recovery : {false, true}) {
      PhaseQp b(ph, p, recovery);
      b.build(state(140, -1580, 60, -0.9, -0.32, 0), vbar_target());
      CHECK(b.qp().validate().empty());
      CHECK(b.N() == p.phase(ph).N);
      Matrix6d A;
      Matrix63d B;
      cw_impulsive_model(n, p.phase(ph).Ts_s, A, B);
      for (int i = 0; i < b.N(); ++i) {
        CHECK((b.qp().A[i] - A).cwiseAbs().maxCoeff() == 0.0);
        CHECK((b.qp().B[i].leftCols<3>() - B).cwiseAbs().maxCoeff() == 0.0);
        CHECK(b.qp().B[i].rightCols(b.dims().nu[i] - 3).isZero(0.0));  // slacks do not move the chaser
        // |u|_inf <= u_max as +-I rows on the delta-v.
        CHECK(b.qp().d[i].head<6>().isConstant(p.phase(ph).u_max_mps));
      }
    }
  }
}

TEST_CASE("rendezvous: keep-out rows are -n_i' rho <= -r1 with unit normals turning at most n Ts per step") {
  GuidanceParams p;
  PhaseQp b(Phase::Rendezvous, p);
  const Vector6d x = state(-300, 250, 40, 0.1, 0.2, 0);
  b.build(x, vbar_target());
  const double cap = p.mean_motion_rad_s() * p.rendezvous.Ts_s;
  for (int i = 1; i <= b.N(); ++i) {
    const int row = b.keepout_row(i);
    REQUIRE(row >= 0);
    const Eigen::Vector3d n_i = -b.qp().C[i].block<1, 3>(row, 0).transpose();
    CHECK(n_i.norm() == doctest::Approx(1.0));
    CHECK(b.qp().d[i](row) == doctest::Approx(-p.keepout_radius_m));
    const Eigen::Vector3d n_prev = i == 1 ? Eigen::Vector3d(x.head<3>().normalized()) : Eigen::Vector3d(-b.qp().C[i - 1].block<1, 3>(b.keepout_row(i - 1), 0).transpose());
    CHECK(std::acos(std::min(1.0, n_i.dot(n_prev))) <= cap + 1e-12);
  }
  CHECK(b.keepout_row(0) == -1);  // x_0 is measured, never constrained
  CHECK(soft_penalty(b.qp(), 1, b.keepout_row(1)) < 0.0);  // the keep-out plane is hard
  // Terminal cone penalty: H rho_N <= 0 as soft rows, lambda per metre outside a face.
  const int c = b.cone_row(b.N());
  REQUIRE(c >= 0);
  for (int k = 0; k < 4; ++k) CHECK(soft_penalty(b.qp(), b.N(), c + k) == p.rendezvous.lambda);
  for (int i = 0; i < b.N(); ++i) CHECK(b.dims().nu[i] == 3);
  CHECK(b.dims().nu[b.N()] == 0);
}

TEST_CASE("rendezvous set point sits on the docking axis at r1 and rotates with the target") {
  GuidanceParams p;
  PhaseQp b(Phase::Rendezvous, p);
  b.build(state(140, -1580, 60, 0, 0, 0), vbar_target(0.25));
  const double w = 0.25 * kDeg;
  for (int i : {0, 7, 30}) {
    const double ang = -90.0 * kDeg + w * i * p.rendezvous.Ts_s;
    const Eigen::Vector3d expect = p.keepout_radius_m * Eigen::Vector3d(std::cos(ang), std::sin(ang), 0);
    CHECK((b.reference()[i].head<3>() - expect).norm() < 1e-9);
    CHECK((b.reference()[i].tail<3>() - Eigen::Vector3d(0, 0, w).cross(expect)).norm() < 1e-12);
    // q_i = -Q_i xs_i (the OCP's 1/2 x'Qx + q'x is the dissertation's (x - xs)'Q(x - xs) up to a constant).
    CHECK((b.qp().q[i] + b.qp().Q[i] * b.reference()[i]).norm() < 1e-9);
  }
}

TEST_CASE("approach: overshoot plane along the axis at r2 and a pyramid penalty on every stage") {
  GuidanceParams p;
  PhaseQp b(Phase::Approach, p);
  b.build(state(10, -150, 0, 0, 0.5, 0), vbar_target());
  const Eigen::Vector3d axis(0, -1, 0);
  for (int i = 1; i <= b.N(); ++i) {
    const int row = b.keepout_row(i);
    CHECK((-b.qp().C[i].block<1, 3>(row, 0).transpose() - axis).norm() < 1e-12);
    CHECK(b.qp().d[i](row) == doctest::Approx(-p.approach_stop_m));
    const Eigen::Matrix<double, 4, 3> H = b.qp().C[i].block<4, 3>(b.cone_row(i), 0);
    CHECK((H * axis).maxCoeff() < 0.0);  // the axis is inside
    for (int k = 0; k < 4; ++k) CHECK(soft_penalty(b.qp(), i, b.cone_row(i) + k) == p.approach.lambda);
    CHECK(soft_penalty(b.qp(), i, row) < 0.0);  // the overshoot plane is hard
  }
}

TEST_CASE("docking: hard pyramid with its apex at the port, and |v|_inf rows") {
  GuidanceParams p;
  PhaseQp b(Phase::Docking, p);
  const TargetState t = vbar_target(0.25);
  b.build(state(1, -25, 0, 0, 0.05, 0), t);
  for (int i = 1; i <= b.N(); ++i) {
    const Eigen::Quaterniond q_i = attitude_after(t, i * p.docking.Ts_s);
    const Eigen::Vector3d port = q_i * p.port_body_m, axis = q_i * Eigen::Vector3d::UnitX();
    const Eigen::Matrix<double, 4, 3> H = b.qp().C[i].block<4, 3>(b.cone_row(i), 0);
    const Eigen::Vector4d d = b.qp().d[i].segment<4>(b.cone_row(i));
    // Points on the axis beyond the port satisfy H rho <= d; the port itself is the apex (equality).
    CHECK((H * (port + 10.0 * axis) - d).maxCoeff() < 0.0);
    CHECK((H * port - d).cwiseAbs().maxCoeff() < 1e-12);
    // A point 9 deg off the axis (outside the 8 deg pyramid) is cut off.
    const Eigen::Vector3d off = port + 10.0 * (std::cos(9 * kDeg) * axis + std::sin(9 * kDeg) * Eigen::Vector3d::UnitZ());
    CHECK((H * off - d).maxCoeff() > 0.0);
    const int v = b.velocity_row(i);
    CHECK(b.qp().C[i].block<3, 3>(v, 3).isIdentity());
    CHECK(b.qp().d[i].segment<6>(v).isConstant(p.v_max_mps));
    // The set point: on the axis, docking_setpoint_offset_m beyond the apex (no margins: the port).
    CHECK((b.reference()[i].head<3>() - (port + p.docking_setpoint_offset_m * axis)).norm() < 1e-12);
    // The stop plane: normal to the axis through the set point, no nearer the port than it; soft, linear.
    const int s = b.stop_row(i);
    REQUIRE(s == v + 6);
    CHECK((b.qp().C[i].block<1, 3>(s, 0).transpose() + axis).norm() < 1e-12);
    CHECK(b.qp().C[i].block<1, 3>(s, 3).isZero(0.0));
    CHECK(std::abs(b.qp().C[i].block<1, 3>(s, 0).dot(b.reference()[i].head<3>()) - b.qp().d[i](s)) < 1e-12);
    CHECK((b.qp().C[i].block<1, 3>(s, 0).dot(port + 0.9 * p.docking_setpoint_offset_m * axis) - b.qp().d[i](s)) > 0.0);
    CHECK(soft_penalty(b.qp(), i, s) == p.docking_stop_penalty);
  }
  CHECK(b.stop_row(0) == -1);
}

TEST_CASE("docking: docking_stop_penalty = 0 leaves the dissertation's QP, with no stop plane") {
  GuidanceParams p;
  p.docking_stop_penalty = 0.0;
  PhaseQp b(Phase::Docking, p);
  for (int i = 0; i <= b.N(); ++i) {
    CHECK(b.stop_row(i) == -1);
    CHECK(b.dims().nc[i] == (i == 0 ? 6 : i < b.N() ? 16 : 10));
    CHECK(b.qp().dims.soft_rows(i) == 0);
  }
  p.docking_stop_penalty = -1.0;
  CHECK(!p.validate().empty());
}

TEST_CASE("recovery QP: exactly the hard state rows become soft, the inputs stay the 3 delta-v") {
  GuidanceParams p;
  PhaseQp b(Phase::Docking, p, true);
  b.build(state(1, -25, 0, 0, 0.05, 0), vbar_target());
  PhaseQp nominal(Phase::Docking, p);
  CHECK(b.dims().nu == nominal.dims().nu);
  CHECK(b.dims().nc == nominal.dims().nc);
  for (int i = 1; i <= b.N(); ++i) {
    for (int k = 0; k < 4; ++k) CHECK(soft_penalty(b.qp(), i, b.cone_row(i) + k) == p.recovery_weight);
    // |v|_inf weighs recovery_speed_factor times the cone (falling behind a spinning target's cone far
    // from the port is the lesser harm than chasing it faster than v_max).
    for (int k = 0; k < 6; ++k)
      CHECK(soft_penalty(b.qp(), i, b.velocity_row(i) + k) == p.recovery_speed_factor * p.recovery_weight);
    for (int k = 0; k < b.dims().ns[i]; ++k) {
      if (b.qp().idxs[i][k] == b.stop_row(i)) {  // soft already, at its own penalty
        CHECK(b.qp().zs[i](k) == p.docking_stop_penalty);
        CHECK(b.qp().Zs[i](k) == 0.0);
        continue;
      }
      const bool speed = b.qp().idxs[i][k] >= b.velocity_row(i) && b.qp().idxs[i][k] < b.velocity_row(i) + 6;
      CHECK(b.qp().Zs[i](k) == (speed ? p.recovery_speed_factor : 1.0) * 2.0 * p.recovery_quadratic);
    }
    if (i < b.N())
      for (int k = 0; k < 6; ++k) CHECK(soft_penalty(b.qp(), i, k) < 0.0);  // the thrust box stays hard
  }
  CHECK(b.dims().ns[0] == 0);
}

TEST_CASE("1-norm rendezvous: an LP (no quadratic terms) with |Q e| and |R u| as soft rows") {
  GuidanceParams p;
  p.rendezvous_objective = RendezvousObjective::OneNorm;
  PhaseQp b(Phase::Rendezvous, p);
  b.build(state(140, -1580, 60, -0.9, -0.32, 0), vbar_target());
  CHECK(b.qp().validate().empty());
  for (int i = 0; i <= b.N(); ++i) {
    CHECK(b.qp().Q[i].isZero(0.0));
    CHECK(b.qp().R[i].isZero(0.0));
  }
  CHECK(b.dims().nu[0] == 3);  // |Q e| and |R u| are soft rows at penalty 1, not epigraph inputs
  CHECK(b.dims().ns[0] == 12 + 6);
  CHECK(b.dims().ns[b.N()] == 12 + 4);
}

TEST_CASE("terminal weight: the DARE solution satisfies the Riccati equation") {
  GuidanceParams p;
  p.docking.terminal_weight = TerminalWeight::Dare;
  PhaseQp b(Phase::Docking, p);
  const Matrix6d P = b.terminal_weight();
  const Matrix6d Q = p.docking.Q_diag.asDiagonal();
  const Eigen::Matrix3d R = p.docking.R_diag.asDiagonal();
  const Matrix6d& A = b.A();
  const Matrix63d& B = b.B();
  const Matrix6d rhs = Q + A.transpose() * P * A -
                       A.transpose() * P * B * (R + B.transpose() * P * B).inverse() * B.transpose() * P * A;
  CHECK((rhs - P).cwiseAbs().maxCoeff() < 1e-6 * P.cwiseAbs().maxCoeff());
  CHECK((b.qp().Q[b.N()] - 2.0 * P).cwiseAbs().maxCoeff() < 1e-9 * P.cwiseAbs().maxCoeff());
}
