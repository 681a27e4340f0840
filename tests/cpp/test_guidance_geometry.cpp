// Target geometry: the line-of-sight pyramid, the rotating target, and the rotating keep-out planes.
#include <doctest/doctest.h>

#include <cmath>

#include "flight_sw/guidance/phase_qp.hpp"
#include "flight_sw/guidance/target.hpp"

using namespace rvd::guidance;

namespace {
const double kDeg = M_PI / 180.0;
// Unit vector at angle `a` from `axis` towards `side` (side perpendicular to axis).
Eigen::Vector3d tilted(const Eigen::Vector3d& axis, const Eigen::Vector3d& side, double a) {
  return std::cos(a) * axis + std::sin(a) * side;
}
}  // namespace

TEST_CASE("pyramid rows: unit, the axis is strictly inside, face centres at the half-angle are on the faces") {
  const Eigen::Quaterniond q(Eigen::AngleAxisd(-90.0 * kDeg, Eigen::Vector3d::UnitZ()));  // V-bar: axis -y
  const Eigen::Vector3d axis = q * Eigen::Vector3d::UnitX();
  CHECK((axis - Eigen::Vector3d(0, -1, 0)).norm() < 1e-15);
  const double a = 15.0 * kDeg;
  const Matrix43d H = pyramid_rows_lvlh(q, a);
  for (int k = 0; k < 4; ++k) CHECK(H.row(k).norm() == doctest::Approx(1.0));
  CHECK((H * axis).maxCoeff() == doctest::Approx(-std::sin(a)));
  // Tilting towards each face normal direction (LVLH x and z here) crosses that face at exactly a.
  for (const Eigen::Vector3d& side : {Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(-1, 0, 0), Eigen::Vector3d(0, 0, 1),
                                      Eigen::Vector3d(0, 0, -1)}) {
    CHECK((H * tilted(axis, side, a)).maxCoeff() == doctest::Approx(0.0).epsilon(1e-12));
    CHECK((H * tilted(axis, side, a - 0.01)).maxCoeff() < 0.0);
    CHECK((H * tilted(axis, side, a + 0.01)).maxCoeff() > 0.0);
  }
  // The opposite direction is outside.
  CHECK((H * (-axis)).maxCoeff() > 0.0);
}

TEST_CASE("a spinning target: attitude, port and its velocity follow the constant body rate") {
  TargetState t;
  t.q_lvlh_body = Eigen::AngleAxisd(-90.0 * kDeg, Eigen::Vector3d::UnitZ());
  t.omega_body_rad_s = Eigen::Vector3d(0, 0, 0.25 * kDeg);
  const Eigen::Vector3d port_body(0.5, 0, 0);
  const TargetGeometry g0 = target_geometry(t, 0.0, port_body);
  CHECK((g0.port_m - Eigen::Vector3d(0, -0.5, 0)).norm() < 1e-15);
  // After 360 s the body has turned 90 deg about z: body x now along LVLH +x.
  const TargetGeometry g = target_geometry(t, 360.0, port_body);
  CHECK((g.axis - Eigen::Vector3d(1, 0, 0)).norm() < 1e-12);
  CHECK((g.port_m - Eigen::Vector3d(0.5, 0, 0)).norm() < 1e-12);
  // Port velocity = omega x r, by finite difference of the port position.
  const double h = 1e-3;
  const Eigen::Vector3d fd = (target_geometry(t, 360.0 + h, port_body).port_m - target_geometry(t, 360.0 - h, port_body).port_m) / (2 * h);
  CHECK((fd - g.port_velocity_mps).norm() < 1e-9);
}

TEST_CASE("keep-out planes: reach the axis in N equal steps when within the cap") {
  const Eigen::Vector3d axis(0, -1, 0);
  const Eigen::Vector3d rho = 1000.0 * tilted(axis, Eigen::Vector3d(1, 0, 0), 20.0 * kDeg);
  const int N = 30;
  const double cap = 1.1e-3 * 30.0;  // n Ts
  const KeepoutPlanes p = plan_keepout_rotation(rho, axis, N, cap, KeepoutDirection::NaturalMotion);
  CHECK(p.total_rad == doctest::Approx(20.0 * kDeg));
  CHECK(p.step_rad == doctest::Approx(20.0 * kDeg / N));
  CHECK(!p.natural_way);
  const Eigen::Vector3d nN = Eigen::AngleAxisd(N * p.step_rad, p.rotation_axis) * rho.normalized();
  CHECK((nN - axis).norm() < 1e-12);
}

TEST_CASE("keep-out planes: capped rate, and the natural-motion way when the axis is out of reach") {
  const int N = 30;
  const double cap = 1.1e-3 * 30.0;  // 57 deg over the horizon
  // R-bar axis (+x), chaser on -y: the short way turns about +z (against the natural -z circulation).
  const Eigen::Vector3d axis(1, 0, 0), rho(0, -1000, 0);
  const KeepoutPlanes nat = plan_keepout_rotation(rho, axis, N, cap, KeepoutDirection::NaturalMotion);
  CHECK(nat.natural_way);
  CHECK(nat.rotation_axis.z() == doctest::Approx(-1.0));
  CHECK(nat.total_rad == doctest::Approx(270.0 * kDeg));
  CHECK(nat.step_rad == doctest::Approx(cap));
  const KeepoutPlanes shortest = plan_keepout_rotation(rho, axis, N, cap, KeepoutDirection::Shortest);
  CHECK(!shortest.natural_way);
  CHECK(shortest.rotation_axis.z() == doctest::Approx(1.0));
  CHECK(shortest.total_rad == doctest::Approx(90.0 * kDeg));
  // Within reach, both rules take the short way even against the natural direction.
  const Eigen::Vector3d near = 1000.0 * tilted(axis, Eigen::Vector3d(0, -1, 0), 40.0 * kDeg);
  const KeepoutPlanes n2 = plan_keepout_rotation(near, axis, N, cap, KeepoutDirection::NaturalMotion);
  CHECK(!n2.natural_way);
  CHECK(n2.total_rad == doctest::Approx(40.0 * kDeg));
  // Exactly opposite the axis: the natural way, half a turn.
  const KeepoutPlanes opp = plan_keepout_rotation(Eigen::Vector3d(-500, 0, 0), axis, N, cap, KeepoutDirection::NaturalMotion);
  CHECK(opp.total_rad == doctest::Approx(M_PI));
  CHECK(opp.rotation_axis.z() == doctest::Approx(-1.0));
}

TEST_CASE("keep-out planes: near the antipode of the axis the turn does not swing with small offsets") {
  // A V-bar start opposite its port (the dissertation's Case 1): chaser on -y, axis +y. Offsets of a
  // few metres at 1.5 km, as noise leaves between two periods, turn the short way's axis u0 x axis
  // by more than 90 degrees; the planned turn may move by a few degrees only, and keeps the natural
  // circulation's sense (about -z).
  const int N = 30;
  const double cap = 1.1e-3 * 30.0;
  const Eigen::Vector3d axis(0, 1, 0);
  const Eigen::Vector3d a(8.0, -1500.0, 6.0), b(-8.0, -1500.0, 2.0), c(-2.0, -1500.0, -5.0);
  auto short_turn = [&](const Eigen::Vector3d& rho) { return Eigen::Vector3d(rho.normalized().cross(axis).normalized()); };
  CHECK(std::acos(short_turn(a).dot(short_turn(b))) > 90.0 * kDeg);  // the ill-conditioned geometry
  CHECK(std::acos(short_turn(a).dot(short_turn(c))) > 90.0 * kDeg);
  const KeepoutPlanes pa = plan_keepout_rotation(a, axis, N, cap, KeepoutDirection::NaturalMotion);
  for (const Eigen::Vector3d& rho : {b, c}) {
    const KeepoutPlanes p = plan_keepout_rotation(rho, axis, N, cap, KeepoutDirection::NaturalMotion);
    CHECK(std::acos(std::min(1.0, pa.rotation_axis.dot(p.rotation_axis))) < 3.0 * kDeg);
    CHECK(p.rotation_axis.z() < -0.99);
    CHECK(p.rotation_axis.norm() == doctest::Approx(1.0));
    CHECK(std::abs(p.rotation_axis.dot(rho.normalized())) < 1e-12);  // a great circle through u0
    CHECK(p.step_rad == doctest::Approx(cap));
  }
  // 30 degrees from the antipode the turn is the great circle to the axis within 5 degrees.
  const Eigen::Vector3d d = 1500.0 * tilted(-axis, Eigen::Vector3d(1, 0, 0), 30.0 * kDeg);
  const KeepoutPlanes pd = plan_keepout_rotation(d, axis, N, cap, KeepoutDirection::NaturalMotion);
  const Eigen::Vector3d way = pd.natural_way ? Eigen::Vector3d(-short_turn(d)) : short_turn(d);
  CHECK(std::acos(std::min(1.0, pd.rotation_axis.dot(way))) < 5.0 * kDeg);
}
