// Obstacle rows of the phase QPs (flight_sw/guidance/obstacles.hpp): the linearized row is the zone's
// tangent plane at the boundary point towards the predicted position (support function of the
// ellipsoid), selection keeps the nearest, the rows sit on every stage of every phase.
#include <doctest/doctest.h>

#include <array>
#include <cmath>

#include "flight_sw/guidance/guidance.hpp"
#include "flight_sw/guidance/obstacles.hpp"
#include "flight_sw/guidance/phase_qp.hpp"

using namespace rvd::guidance;

namespace {
Obstacle ellipsoid(uint32_t id, const Eigen::Vector3d& c, const Eigen::Vector3d& axes,
                   const Eigen::Quaterniond& q = Eigen::Quaterniond::Identity()) {
  Obstacle o;
  o.id = id;
  o.position_lvlh_m = c;
  o.semi_axes_m = axes;
  o.q_lvlh_body = q;
  return o;
}
}  // namespace

TEST_CASE("the linearized row is the tangent plane at the boundary point: the whole zone lies behind it") {
  const Eigen::Quaterniond q(Eigen::AngleAxisd(0.6, Eigen::Vector3d(1.0, 2.0, -1.0).normalized()));
  const Obstacle o = ellipsoid(1, Eigen::Vector3d(10.0, -20.0, 5.0), Eigen::Vector3d(30.0, 12.0, 6.0), q);
  const Eigen::Matrix3d S = obstacle_shape(o, 0.0);
  for (const Eigen::Vector3d p : {Eigen::Vector3d(80.0, 0.0, 0.0), Eigen::Vector3d(10.0, -20.0, 9.0),
                                  Eigen::Vector3d(-5.0, 40.0, -30.0), Eigen::Vector3d(12.0, -19.0, 5.5)}) {
    const ObstacleRow row = linearize_obstacle(o.position_lvlh_m, S, p, Eigen::Vector3d::UnitX());
    CHECK(row.normal.norm() == doctest::Approx(1.0).epsilon(1e-14));
    // Support function of the ellipsoid {c + S^-1/2 u, |u| <= 1} along n: n'c + sqrt(n' S^-1 n).
    const double support = row.normal.dot(o.position_lvlh_m) + std::sqrt(row.normal.dot(S.inverse() * row.normal));
    CHECK(row.bound_m == doctest::Approx(support).epsilon(1e-12));
    // It touches the zone at r0 on the segment centre -> p (the paper's expansion point).
    const Eigen::Vector3d d = p - o.position_lvlh_m;
    const Eigen::Vector3d r0 = o.position_lvlh_m + d / std::sqrt(d.dot(S * d));
    CHECK(row.normal.dot(r0) == doctest::Approx(row.bound_m).epsilon(1e-12));
  }
  // A sphere: the plane normal to the centre line at the radius.
  const Obstacle s = ellipsoid(2, Eigen::Vector3d::Zero(), Eigen::Vector3d::Constant(20.0));
  const ObstacleRow r = linearize_obstacle(s.position_lvlh_m, obstacle_shape(s, 5.0), Eigen::Vector3d(0.0, 100.0, 0.0),
                                           Eigen::Vector3d::UnitX());
  CHECK(r.normal.y() == doctest::Approx(1.0));
  CHECK(r.bound_m == doctest::Approx(25.0));
}

TEST_CASE("a longer list keeps the nearest the guidance can hold; bad entries are refused") {
  std::array<Obstacle, 7> list{};
  for (int k = 0; k < 6; ++k)  // surface distances 90, 190, ..., 590 m from the origin, given far first
    list[k] = ellipsoid(static_cast<uint32_t>(10 + k), Eigen::Vector3d(0.0, 600.0 - 100.0 * k, 0.0),
                        Eigen::Vector3d::Constant(10.0));
  list[6] = ellipsoid(99, Eigen::Vector3d(0.0, 20.0, 0.0), Eigen::Vector3d(5.0, -1.0, 5.0));  // negative axis
  ObstacleSet set;
  select_obstacles(list.data(), 7, Eigen::Vector3d::Zero(), 0.0, 0.0011, ObstaclePrediction::ConstantVelocity, set);
  REQUIRE(set.count == kMaxObstacles);
  for (int k = 0; k < kMaxObstacles; ++k) CHECK(set.items[k].id == static_cast<uint32_t>(15 - k));
  CHECK(set.dropped_total == 6u - kMaxObstacles);
  CHECK(set.rejected_total == 1u);
  CHECK(set.received == 7u);
  list[0].position_lvlh_m.x() = std::nan("");
  select_obstacles(list.data(), 1, Eigen::Vector3d::Zero(), 0.0, 0.0011, ObstaclePrediction::ConstantVelocity, set);
  CHECK(set.count == 0);
  CHECK(set.rejected_total == 2u);
}

TEST_CASE("obstacle centres move by constant velocity or by natural CW motion") {
  Obstacle o = ellipsoid(1, Eigen::Vector3d(-30.0, -800.0, 10.0), Eigen::Vector3d::Constant(20.0));
  o.velocity_lvlh_mps = Eigen::Vector3d(-0.075, -0.005, 0.015);
  o.t_state_s = 100.0;
  const double n = 0.00106;
  const Eigen::Vector3d cv = obstacle_position(o, 400.0, n, ObstaclePrediction::ConstantVelocity);
  CHECK((cv - (o.position_lvlh_m + 300.0 * o.velocity_lvlh_mps)).norm() < 1e-12);
  Vector6d x0;
  x0 << o.position_lvlh_m, o.velocity_lvlh_mps;
  const Eigen::Vector3d cw = obstacle_position(o, 400.0, n, ObstaclePrediction::NaturalMotion);
  CHECK((cw - (cw_stm(n, 300.0) * x0).head<3>()).norm() < 1e-9);
}

TEST_CASE("every phase QP has two soft rows per obstacle slot on stages 1..N, and none without obstacles") {
  GuidanceParams off;
  GuidanceParams on;
  on.obstacle_capacity = kMaxObstacles;
  for (Phase ph : {Phase::Rendezvous, Phase::Approach, Phase::Docking}) {
    for (bool recovery : {false, true}) {
      PhaseQp a(ph, off, recovery), b(ph, on, recovery);
      CHECK(a.obstacle_row(1) == -1);
      CHECK(b.obstacle_row(0) == -1);
      for (int i = 1; i <= b.N(); ++i) {
        CHECK(b.dims().nc[i] == a.dims().nc[i] + 2 * kMaxObstacles);
        CHECK(b.dims().ns[i] == a.dims().ns[i] + 2 * kMaxObstacles);
        CHECK(b.obstacle_row(i) == a.dims().nc[i]);  // appended: every other block keeps its rows
      }
    }
  }
}

TEST_CASE("the rotating hyperplane starts facing the chaser, turns at its rate and stops facing the goal") {
  std::array<Obstacle, 1> list{ellipsoid(7, Eigen::Vector3d(0.0, -500.0, 0.0), Eigen::Vector3d::Constant(40.0))};
  ObstacleSet set;
  const Eigen::Vector3d chaser(-300.0, -500.0, 0.0);  // from the centre: -x; the goal (origin): +y
  select_obstacles(list.data(), 1, chaser, 100.0, 0.0011, ObstaclePrediction::ConstantVelocity, set);
  REQUIRE(set.count == 1);
  const Obstacle& o = set.items[0];
  CHECK((o.first_normal - Eigen::Vector3d(-1.0, 0.0, 0.0)).norm() < 1e-12);
  CHECK(o.t_first_held_s == 100.0);
  const Eigen::Matrix3d Sinv = obstacle_shape(o, 0.0).inverse();
  const double rate = 0.01;
  for (double dt : {0.0, 50.0, 100.0, 1000.0}) {
    const ObstacleRow r = rotating_hyperplane(o, o.position_lvlh_m, Sinv, Eigen::Vector3d::Zero(), 100.0 + dt, rate);
    const double angle = std::min(rate * dt, 3.14159265358979 / 2);  // a quarter turn from -x to +y
    CHECK(r.normal.x() == doctest::Approx(-std::cos(angle)).epsilon(1e-12));
    CHECK(r.normal.y() == doctest::Approx(std::sin(angle)).epsilon(1e-12));
    CHECK(r.bound_m == doctest::Approx(r.normal.dot(o.position_lvlh_m) + 40.0).epsilon(1e-12));  // tangent
  }
  // Held again a step later: its start is kept, not re-taken from the chaser's new position.
  select_obstacles(list.data(), 1, Eigen::Vector3d(-250.0, -400.0, 0.0), 130.0, 0.0011,
                   ObstaclePrediction::ConstantVelocity, set);
  CHECK(set.items[0].t_first_held_s == 100.0);
  CHECK((set.items[0].first_normal - Eigen::Vector3d(-1.0, 0.0, 0.0)).norm() < 1e-12);
}
