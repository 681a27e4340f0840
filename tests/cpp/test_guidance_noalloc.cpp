// Guidance::step allocates nothing on the heap: every buffer is sized in the constructor (OSQP-like data
// flow). Checked over the rotating-target case (every phase, recovery solves) with injected faults:
//  - every allocation path is counted (alloc_counter.hpp: operator new and the C allocator, which
//    is Eigen's, in Release, static and sanitizer builds alike);
//  - in builds with assertions Eigen's heap allocations also abort under EIGEN_RUNTIME_NO_MALLOC
//    (flight_sw/CMakeLists.txt defines it for every flight_sw library).
#include <doctest/doctest.h>

#include <array>
#include <cmath>
#include <cstdlib>
#include <string>

#include "alloc_counter.hpp"
#include "flight_sw/guidance/guidance.hpp"

using namespace rvd::guidance;

namespace {
void forbid_heap(bool forbid) {
#ifdef EIGEN_RUNTIME_NO_MALLOC
  Eigen::internal::set_is_malloc_allowed(!forbid);
#endif
}
}  // namespace

TEST_CASE("the counter sees every allocation path this build has") {
  MESSAGE("allocations counted by " << std::string(rvd::testing::kAllocationCounting));
  using rvd::testing::allocations_during;
  CHECK(allocations_during([] {
          Eigen::VectorXd v = Eigen::VectorXd::Ones(64);  // Eigen's aligned malloc
          CHECK(v.sum() == 64.0);
        }) >= 1);
  CHECK(allocations_during([] {
          void* volatile p = std::malloc(24);
          std::free(p);
        }) >= 1);
  CHECK(allocations_during([] {
          void* volatile p = std::calloc(3, 8);
          p = std::realloc(p, 4096);
          std::free(p);
        }) >= 2);
  CHECK(allocations_during([] {
          void* p = nullptr;
          REQUIRE(posix_memalign(&p, 64, 128) == 0);
          std::free(p);
          void* volatile q = std::aligned_alloc(64, 128);
          std::free(q);
        }) >= 2);
  CHECK(allocations_during([] {
          int* volatile p = new int(3);
          delete p;
        }) >= 1);
}

TEST_CASE("no heap allocation inside Guidance::step, whatever the step does") {
  GuidanceParams p;
  const double n = p.mean_motion_rad_s();
  {
    const ScenarioCase c = dissertation_case(3);
    Guidance g(p);  // allocates here
    TargetState target0;
    target0.q_lvlh_body = c.q_lvlh_body;
    target0.omega_body_rad_s = c.omega_body_rad_s;
    Vector6d x = c.x0;
    double t = 0.0;
    long news = 0;
    int fallbacks = 0, steps = 0, recovered = 0;
    for (; steps < 400; ++steps) {
      NavInput nav;
      nav.step = static_cast<uint32_t>(steps);
      nav.t_s = t;
      nav.x_lvlh = x;
      nav.q_lvlh_body = attitude_after(target0, t);
      nav.omega_body_rad_s = c.omega_body_rad_s;
      if (steps % 11 == 5) nav.x_lvlh(2) = std::nan("");  // rejected input: fallback path
      forbid_heap(true);
      const long before = rvd::testing::allocations();
      const Command cmd = g.step(nav, steps % 7 == 3 ? 1.0 : 0.0);  // a 1 us budget now and then
      news += rvd::testing::allocations() - before;
      forbid_heap(false);
      if (cmd.status == StepStatus::Recovered) ++recovered;
      if (cmd.status != StepStatus::Ok && cmd.status != StepStatus::Recovered) ++fallbacks;
      if (cmd.phase == Phase::Docked) break;
      Vector6d xp = x;
      xp.tail<3>() += cmd.dv_alloc_mps;
      x = cw_stm(n, cmd.period_s) * xp;
      t += cmd.period_s;
    }
    MESSAGE("allocations counted by " << std::string(rvd::testing::kAllocationCounting));
    CHECK(news == 0);
    CHECK(recovered > 0);  // the recovery QPs (soft rows) ran
    CHECK(g.phase() == Phase::Docked);  // it still docks through the injected faults
    CHECK(fallbacks > 10);             // and the fallback paths were exercised
  }
}

TEST_CASE("no heap allocation inside Guidance::step and set_obstacles with obstacle rows on") {
  GuidanceParams p;
  p.obstacle_capacity = kMaxObstacles;
  const double n = p.mean_motion_rad_s();
  const ScenarioCase c = dissertation_case(1);
  Guidance g(p);
  TargetState target0;
  target0.q_lvlh_body = c.q_lvlh_body;
  // Six spheres near the path (more than the guidance holds), one drifting across it.
  std::array<Obstacle, 6> list{};
  for (int k = 0; k < 6; ++k) {
    list[k].id = static_cast<uint32_t>(k + 1);
    list[k].position_lvlh_m = Eigen::Vector3d(60.0 - 40.0 * k, -1200.0 + 180.0 * k, 30.0);
    list[k].velocity_lvlh_mps = Eigen::Vector3d(0.02 * (k % 2 ? 1 : -1), 0.0, 0.0);
    list[k].semi_axes_m = Eigen::Vector3d(25.0, 15.0, 10.0);
  }
  Vector6d x = c.x0;
  double t = 0.0;
  long news = 0;
  int steps = 0;
  for (; steps < 150; ++steps) {
    NavInput nav;
    nav.step = static_cast<uint32_t>(steps);
    nav.t_s = t;
    nav.x_lvlh = x;
    nav.q_lvlh_body = c.q_lvlh_body;
    forbid_heap(true);
    const long before = rvd::testing::allocations();
    g.set_obstacles(list.data(), static_cast<int>(list.size()), t, x.head<3>());
    const Command cmd = g.step(nav);
    news += rvd::testing::allocations() - before;
    forbid_heap(false);
    if (cmd.phase == Phase::Docked) break;
    Vector6d xp = x;
    xp.tail<3>() += cmd.dv_alloc_mps;
    x = cw_stm(n, cmd.period_s) * xp;
    t += cmd.period_s;
  }
  CHECK(news == 0);
  CHECK(g.obstacles().count == kMaxObstacles);
  CHECK(g.obstacles().dropped_total == 2u * static_cast<uint32_t>(steps + (steps < 150 ? 1 : 0)));
}
