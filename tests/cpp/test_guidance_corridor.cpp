// The docking corridor of Dong, Ghiglino et al. (flight_sw/guidance/holding.hpp): the dynamic holding
// radius (eq. 9) and the two-plane entry cone (eq. 10), against geometry worked out by hand, their
// rows in the phase QPs, and the same functions through the C interface (compiled as C).
#include <doctest/doctest.h>

#include <cmath>

#include "flight_sw/guidance/closed_loop.hpp"
#include "flight_sw/guidance/guidance.hpp"
#include "flight_sw/guidance/holding.hpp"
#include "flight_sw/guidance/phase_qp.hpp"

extern "C" {
int corridor_c_shrinks(double r0, double rmin, double gamma, double eta, double eps, const double q[4],
                       const double port[3], int steps, double* final_radius);
void corridor_c_cone(const double q[4], const double port[3], double half_angle_rad, double rows[2][3], double bounds[2]);
}

using namespace rvd::guidance;

namespace {
constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;
Eigen::Quaterniond about_z(double deg) { return Eigen::Quaterniond(Eigen::AngleAxisd(deg * kDeg, Eigen::Vector3d::UnitZ())); }

HoldingParams spot_holding() {  // Dong et al.'s 2-D values: 1.15 m, gamma 0.95, eta sqrt(0.5) m, epsilon 10 deg
  HoldingParams h;
  h.radius_m = 1.15;
  h.radius_min_m = 0.45;
  h.shrink = 0.95;
  h.tolerance_m = std::sqrt(0.5);
  h.attitude_tolerance_rad = 10.0 * kDeg;
  return h;
}
}  // namespace

TEST_CASE("the holding position lies on the holding sphere, directly in front of the port") {
  // Port on the axis, axis along LVLH +y: the point at the radius on +y.
  const Eigen::Vector3d p = holding_position(about_z(90.0), Eigen::Vector3d(0.3, 0.0, 0.0), 1.15);
  CHECK((p - Eigen::Vector3d(0.0, 1.15, 0.0)).norm() < 1e-12);
  // Port 0.1 m off the axis: (0.3 + s)^2 + 0.1^2 = 1, the point (sqrt(0.99), 0.1, 0).
  const Eigen::Vector3d off = holding_position(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0.3, 0.1, 0.0), 1.0);
  CHECK((off - Eigen::Vector3d(std::sqrt(0.99), 0.1, 0.0)).norm() < 1e-12);
  // A sphere inside the port's distance: the port itself.
  CHECK((holding_position(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0.5, 0.0, 0.0), 0.2) -
         Eigen::Vector3d(0.5, 0.0, 0.0)).norm() < 1e-12);
}

TEST_CASE("the holding radius shrinks by gamma per step only within eta and epsilon, down to its minimum") {
  HoldingRadius h(spot_holding());
  const Eigen::Quaterniond q = about_z(250.0);
  const Eigen::Vector3d port(0.45, 0.0, 0.0);
  // At the holding position, aligned: this step plans with 1.15, the next with 0.95 x 1.15.
  h.observe(holding_position(q, port, 1.15), q, port, 0.0);
  CHECK(h.radius() == doctest::Approx(1.15));
  // 20 deg off the docking attitude: the shrink decided before applies, no new one.
  h.observe(holding_position(q, port, 1.0925), q, port, 20.0 * kDeg);
  CHECK(h.radius() == doctest::Approx(1.0925));
  h.observe(holding_position(q, port, 1.0925), q, port, 20.0 * kDeg);
  CHECK(h.radius() == doctest::Approx(1.0925));
  // Attitude unknown (NaN): the position alone decides.
  h.observe(holding_position(q, port, 1.0925), q, port, std::nan(""));
  h.observe(holding_position(q, port, 1.0925), q, port, std::nan(""));
  CHECK(h.radius() == doctest::Approx(0.95 * 1.0925));
  // Farther than eta = 0.7071 m from the holding position: no shrink.
  const double r = h.radius();
  const Eigen::Vector3d far = holding_position(q, port, r) + Eigen::Vector3d(0.0, 0.0, 0.71);
  h.observe(far, q, port, 0.0);
  h.observe(far, q, port, 0.0);
  CHECK(h.radius() == doctest::Approx(0.95 * r));  // the shrink decided at the last aligned step, then none
  h.observe(far, q, port, 0.0);
  CHECK(h.radius() == doctest::Approx(0.95 * r));
  // From 1.15 m to 0.45 m: ln(0.45 / 1.15) / ln(0.95) = 18.3, so 19 shrinks, the last one clamped.
  HoldingRadius g(spot_holding());
  for (int k = 0; k < 40; ++k) g.observe(holding_position(q, port, g.radius()), q, port, std::nan(""));
  CHECK(g.shrinks() == 19);
  CHECK(g.radius() == doctest::Approx(0.45));
  CHECK(g.at_minimum());
  // The C interface: the same sequence.
  double final_radius = 0.0;
  const double qc[4] = {q.w(), q.x(), q.y(), q.z()}, pc[3] = {0.45, 0.0, 0.0};
  CHECK(corridor_c_shrinks(1.15, 0.45, 0.95, std::sqrt(0.5), 10.0 * kDeg, qc, pc, 40, &final_radius) == 19);
  CHECK(final_radius == doctest::Approx(0.45));
}

TEST_CASE("the linearized holding row is the tangent plane of the holding sphere towards the predicted position") {
  const HalfSpace h = holding_row(2.0, Eigen::Vector3d(3.0, 4.0, 0.0), Eigen::Vector3d::UnitX());
  CHECK((h.normal - Eigen::Vector3d(0.6, 0.8, 0.0)).norm() < 1e-15);
  CHECK(h.bound_m == 2.0);
  CHECK(h.normal.dot(Eigen::Vector3d(1.2, 1.6, 0.0)) == doctest::Approx(2.0));  // touches the sphere there
  // Eq. 8 with S = I / r^2 about the centre: the obstacle linearization gives the same plane.
  const ObstacleRow o = linearize_obstacle(Eigen::Vector3d::Zero(), Eigen::Matrix3d::Identity() / 4.0,
                                           Eigen::Vector3d(3.0, 4.0, 0.0), Eigen::Vector3d::UnitX());
  CHECK((o.normal - h.normal).norm() < 1e-14);
  CHECK(o.bound_m == doctest::Approx(h.bound_m));
}

TEST_CASE("the entry cone rows are eq. 10's two planes through the port") {
  const Eigen::Vector3d port(0.45, 0.0, 0.0);
  const double te = 20.0 * kDeg;
  for (double deg : {0.0, 250.0, -37.0}) {
    const double th = deg * kDeg;
    const EntryCone c = entry_cone(about_z(deg), port, te);
    // The paper's normals: n1 = [sin(th + te), -cos(th + te)], n2 = [sin(th - te), -cos(th - te)];
    // -n1' r <= -n1' r_dock and n2' r <= n2' r_dock.
    const Eigen::Vector3d n1(std::sin(th + te), -std::cos(th + te), 0.0), n2(std::sin(th - te), -std::cos(th - te), 0.0);
    const Eigen::Vector3d dock = about_z(deg) * port;
    CHECK((c.rows.row(0).transpose() + n1).norm() < 1e-14);
    CHECK((c.rows.row(1).transpose() - n2).norm() < 1e-14);
    CHECK(c.bounds(0) == doctest::Approx(-n1.dot(dock)));
    CHECK(c.bounds(1) == doctest::Approx(n2.dot(dock)));
    // Inside on the axis, on the boundary at te, outside at te + 5 deg (0.3 m from the port).
    const Eigen::Vector3d axis(std::cos(th), std::sin(th), 0.0);
    CHECK((c.rows * (dock + 0.3 * axis) - c.bounds).maxCoeff() < 0.0);
    const Eigen::Vector3d edge(std::cos(th + te), std::sin(th + te), 0.0), out(std::cos(th + te + 5 * kDeg), std::sin(th + te + 5 * kDeg), 0.0);
    CHECK((c.rows * (dock + 0.3 * edge) - c.bounds).maxCoeff() == doctest::Approx(0.0).epsilon(1e-12));
    CHECK((c.rows * (dock + 0.3 * out) - c.bounds).maxCoeff() == doctest::Approx(0.3 * std::sin(5 * kDeg)).epsilon(1e-12));
    // From C.
    const Eigen::Quaterniond q = about_z(deg);
    const double qc[4] = {q.w(), q.x(), q.y(), q.z()}, pc[3] = {port.x(), port.y(), port.z()};
    double rows[2][3], bounds[2];
    corridor_c_cone(qc, pc, te, rows, bounds);
    for (int j = 0; j < 2; ++j) {
      for (int i = 0; i < 3; ++i) CHECK(rows[j][i] == doctest::Approx(c.rows(j, i)));
      CHECK(bounds[j] == doctest::Approx(c.bounds(j)));
    }
  }
}

TEST_CASE("docking attitude error: the chaser's body x against minus the target's docking axis") {
  CHECK(docking_attitude_error_rad(about_z(180.0), Eigen::Quaterniond::Identity()) == doctest::Approx(0.0).epsilon(1e-12));
  CHECK(docking_attitude_error_rad(about_z(170.0), about_z(0.0)) == doctest::Approx(10.0 * kDeg));
  CHECK(docking_attitude_error_rad(about_z(0.0), about_z(0.0)) == doctest::Approx(kPi));
}

namespace {
GuidanceParams corridor_params() {  // an air-bearing-table scale: no orbit, metres, seconds
  GuidanceParams p;
  p.relative_motion = RelativeMotion::DoubleIntegrator;
  for (PhaseParams* ph : {&p.rendezvous, &p.approach, &p.docking}) {
    ph->N = 15;
    ph->Ts_s = 2.0;
    ph->Q_diag << 10.0, 10.0, 10.0, 300.0, 300.0, 300.0;
    ph->R_diag.setConstant(10.0 * std::pow(16.9 / 2.0, 2));
    ph->u_max_mps = 0.15 * 2.0 / 16.9;
    ph->los_half_angle_deg = 20.0;
  }
  p.thrusters.mass_kg = 16.9;
  p.thrusters.thrust_N = 0.15;
  p.keepout_radius_m = 0.45;
  p.approach_stop_m = 0.44;
  p.port_body_m = Eigen::Vector3d(0.40, 0.0, 0.0);
  p.rendezvous_switch_margin_m = 0.05;
  p.approach_switch_margin_m = 0.06;
  p.dock_tolerance_m = 0.05;
  p.v_max_mps = 0.05;
  p.holding_radius_m = 1.15;
  p.holding_radius_min_m = 0.40;
  p.holding_tolerance_m = std::sqrt(0.5);
  p.holding_phases = 3;
  p.entry_cone_half_angle_deg = 20.0;
  p.entry_cone_range_m = 0.75;
  return p;
}
}  // namespace

TEST_CASE("with the holding radius the rendezvous QP's stand-off rows and set points are the holding sphere's") {
  const GuidanceParams p = corridor_params();
  REQUIRE(p.validate().empty());
  PhaseQp qp(Phase::Rendezvous, p);
  std::vector<Eigen::Vector3d> predicted(p.rendezvous.N + 1);
  for (int i = 0; i <= p.rendezvous.N; ++i) predicted[i] = Eigen::Vector3d(1.9 - 0.05 * i, 0.2 * i, 0.0);
  qp.set_obstacles(nullptr, 0.0, predicted.data());
  qp.set_holding_radius(1.0925);
  TargetState t;
  t.q_lvlh_body = about_z(30.0);
  t.omega_body_rad_s = Eigen::Vector3d(0.0, 0.0, 4.0 * kDeg);
  Vector6d x0;
  x0 << 1.9, 0.0, 0.0, 0.0, 0.0, 0.0;
  qp.build(x0, t);
  for (int i = 1; i <= p.rendezvous.N; ++i) {
    const int row = qp.keepout_row(i);
    CHECK((-qp.qp().C[i].block<1, 3>(row, 0).transpose() - predicted[i].normalized()).norm() < 1e-14);
    CHECK(-qp.qp().d[i](row) == doctest::Approx(1.0925));
    // The set point: the holding position with the target turned by 4 deg/s x i Ts.
    const Eigen::Vector3d hp = holding_position(about_z(30.0 + 4.0 * 2.0 * i), p.port_body_m, 1.0925);
    CHECK((qp.reference()[i].head<3>() - hp).norm() < 1e-12);
  }
  // The chaser is 1.5 m from the port: the entry cone is inactive (0 <= 1) ...
  CHECK_FALSE(qp.entry_cone_active());
  CHECK(qp.qp().C[1].block<2, 3>(qp.entry_row(1), 0).norm() == 0.0);
  // ... and within 0.75 m of it, its rows are eq. 10's with the predicted attitude.
  x0.head<3>() = about_z(30.0) * Eigen::Vector3d(1.0, 0.1, 0.0);
  qp.build(x0, t);
  CHECK(qp.entry_cone_active());
  const EntryCone c = entry_cone(about_z(30.0 + 4.0 * 2.0 * 3), p.port_body_m, 20.0 * kDeg);
  CHECK((qp.qp().C[3].block<2, 3>(qp.entry_row(3), 0) - c.rows).norm() < 1e-12);
  CHECK((qp.qp().d[3].segment<2>(qp.entry_row(3)) - c.bounds).norm() < 1e-12);
}

TEST_CASE("a closed loop without orbit docks through the shrinking holding radius inside the entry cone") {
  GuidanceParams p = corridor_params();
  Vector6d x0;
  x0 << 1.9, 0.3, 0.0, 0.0, 0.0, 0.0;
  // The target turns at 2 deg/s; its port starts facing away from the chaser.
  const ClosedLoopResult r = run_closed_loop(p, x0, about_z(150.0), Eigen::Vector3d(0.0, 0.0, 2.0 * kDeg), 600.0);
  CHECK(r.docked);
  CHECK(r.final_port_distance_m <= p.dock_tolerance_m);
  // Never inside the minimum holding radius less the docking tolerance before docking: no contact with the target.
  double closest = 1e9;
  for (const auto& s : r.log) closest = std::min(closest, s.x.head<3>().norm());
  CHECK(closest >= p.holding_radius_min_m - p.dock_tolerance_m);
}
