// The guidance step never crashes and never commands NaN: bad navigation input, infeasible QPs,
// an exhausted time budget and bad parameters each give a safe action and a status saying why.
#include <doctest/doctest.h>

#include <cmath>
#include <limits>
#include <stdexcept>

#include "flight_sw/guidance/guidance.hpp"

using namespace rvd::guidance;

namespace {
const double kNan = std::numeric_limits<double>::quiet_NaN();
const double kDeg = M_PI / 180.0;

NavInput nav_at(uint32_t k, const Vector6d& x) {
  NavInput n;
  n.step = k;
  n.t_s = 30.0 * k;
  n.x_lvlh = x;
  n.q_lvlh_body = Eigen::AngleAxisd(-90.0 * kDeg, Eigen::Vector3d::UnitZ());
  return n;
}
Vector6d far_state() {
  Vector6d x;
  x << 140, -1580, 60, -0.9, -0.32, 0;
  return x;
}
void check_finite(const Command& c) {
  CHECK(c.dv_cmd_mps.allFinite());
  CHECK(c.dv_alloc_mps.allFinite());
  for (double t : c.pulse_s) CHECK(std::isfinite(t));
}
}  // namespace

TEST_CASE("NaN state before any plan: zero thrust, InvalidState") {
  Guidance g(GuidanceParams{});
  Vector6d x = far_state();
  x(3) = kNan;
  const Command c = g.step(nav_at(0, x));
  CHECK(c.status == StepStatus::InvalidState);
  CHECK(c.fallback == Fallback::ZeroThrust);
  CHECK(c.dv_cmd_mps.isZero(0.0));
  CHECK(!c.solved);
  check_finite(c);
  CHECK(g.phase() == Phase::Rendezvous);
}

TEST_CASE("NaN, Inf and absurd states after a good step: the shifted plan, one input per period") {
  GuidanceParams p;
  Guidance g(p);
  const NavInput first = nav_at(0, far_state());
  const Command ok = g.step(first);
  REQUIRE(ok.status == StepStatus::Ok);
  // The plan, recomputed here: the same QP solved by a fresh solver; stages 1 and 2 as commanded (clipped).
  PhaseQp qp(Phase::Rendezvous, p);
  TargetState t;
  t.q_lvlh_body = first.q_lvlh_body;
  qp.build(first.x_lvlh, t);
  rvd::solver::FastMpcSolver sol(qp.dims(), p.rendezvous.solver);
  REQUIRE(sol.solve(qp.qp(), rvd::solver::Vector(first.x_lvlh)) == rvd::solver::Status::Solved);
  const double um = p.rendezvous.u_max_mps;
  CHECK((ok.dv_cmd_mps - sol.u()[0].head<3>().cwiseMax(-um).cwiseMin(um)).norm() < 1e-6);
  const Eigen::Vector3d u1 = sol.u()[1].head<3>().cwiseMax(-um).cwiseMin(um);
  const Eigen::Vector3d u2 = sol.u()[2].head<3>().cwiseMax(-um).cwiseMin(um);
  Vector6d bad = far_state();
  bad(0) = std::numeric_limits<double>::infinity();
  const Command c1 = g.step(nav_at(1, bad));
  CHECK(c1.status == StepStatus::InvalidState);
  CHECK(c1.fallback == Fallback::ShiftedPlan);
  CHECK(c1.plan_age == 1);
  CHECK((c1.dv_cmd_mps - u1).norm() < 1e-6);
  Vector6d absurd = far_state();
  absurd.head<3>() *= 1e3;  // 1600 km: not a relative state the CW model or this mission can mean
  const Command c2 = g.step(nav_at(2, absurd));
  CHECK(c2.status == StepStatus::InvalidState);
  CHECK((c2.dv_cmd_mps - u2).norm() < 1e-6);
  Vector6d fast = far_state();
  fast(4) = 5e3;
  CHECK(g.step(nav_at(3, fast)).status == StepStatus::InvalidState);
  check_finite(c1);
  check_finite(c2);
}

TEST_CASE("a bad attitude is rejected like a bad state") {
  Guidance g(GuidanceParams{});
  NavInput n = nav_at(0, far_state());
  n.q_lvlh_body = Eigen::Quaterniond(0.5, 0.0, 0.0, 0.0);  // not unit: not an attitude
  CHECK(g.step(n).status == StepStatus::InvalidState);
  n.q_lvlh_body.coeffs()(0) = kNan;
  CHECK(g.step(n).status == StepStatus::InvalidState);
  n = nav_at(0, far_state());
  n.omega_body_rad_s = Eigen::Vector3d(0, 0, 10.0);  // 570 deg/s
  CHECK(g.step(n).status == StepStatus::InvalidState);
}

TEST_CASE("an infeasible approach QP: recovered, or the plan / zero thrust without recovery") {
  // 40 m out on the V-bar axis closing at 2 m/s: the overshoot plane at r2 = 30 m cannot hold next period.
  Vector6d x;
  x << 0, -40, 0, 0, 2.0, 0;
  GuidanceParams p;
  {
    Guidance g(p);
    g.reset(Phase::Approach);
    const Command c = g.step(nav_at(0, x));
    CHECK(c.solver.status == rvd::solver::Status::Infeasible);
    CHECK(c.status == StepStatus::Recovered);
    CHECK(c.dv_cmd_mps.y() == doctest::Approx(-p.approach.u_max_mps));  // brakes as hard as it may
    CHECK(c.dv_cmd_mps.cwiseAbs().maxCoeff() <= p.approach.u_max_mps);
    check_finite(c);
  }
  p.recovery = false;
  Guidance g(p);
  g.reset(Phase::Approach);
  const Command c = g.step(nav_at(0, x));
  CHECK(c.solver.status == rvd::solver::Status::Infeasible);
  CHECK(c.status == StepStatus::ZeroThrust);
  CHECK(c.dv_cmd_mps.isZero(0.0));
  // With a plan from a feasible step first, the failure uses that plan.
  Guidance g2(p);
  g2.reset(Phase::Approach);
  Vector6d calm;
  calm << 0, -150, 0, 0, 0.1, 0;
  REQUIRE(g2.step(nav_at(0, calm)).status == StepStatus::Ok);
  const Command c2 = g2.step(nav_at(1, x));
  CHECK(c2.status == StepStatus::ShiftedPlan);
  CHECK(c2.fallback == Fallback::ShiftedPlan);
  check_finite(c2);
}

TEST_CASE("a spent time budget yields the shifted plan and says time_limit") {
  Guidance g(GuidanceParams{});
  REQUIRE(g.step(nav_at(0, far_state())).status == StepStatus::Ok);
  const Command c = g.step(nav_at(1, far_state()), 1e-3);  // 1 ns: gone before the solver starts
  CHECK(c.solver.status == rvd::solver::Status::TimeLimit);
  CHECK(c.status == StepStatus::ShiftedPlan);
  check_finite(c);
}

TEST_CASE("the plan runs out: zero thrust after N fallbacks") {
  GuidanceParams p;
  p.docking.N = 3;
  Guidance g(p);
  g.reset(Phase::Docking);
  Vector6d x;
  x << 0, -20, 0, 0, 0.05, 0;
  REQUIRE(g.step(nav_at(0, x)).status == StepStatus::Ok);
  Vector6d bad = x;
  bad(1) = kNan;
  CHECK(g.step(nav_at(1, bad)).fallback == Fallback::ShiftedPlan);
  CHECK(g.step(nav_at(2, bad)).fallback == Fallback::ShiftedPlan);
  CHECK(g.step(nav_at(3, bad)).fallback == Fallback::ZeroThrust);
}

TEST_CASE("unusable parameters are refused with the reason") {
  GuidanceParams p;
  p.rendezvous.N = 0;
  p.approach_stop_m = 500.0;  // beyond r1
  try {
    Guidance g(p);
    FAIL("expected std::invalid_argument");
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    CHECK(what.find("rendezvous.N") != std::string::npos);
    CHECK(what.find("approach_stop_m") != std::string::npos);
  }
}
