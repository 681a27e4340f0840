// Guidance::step allocates nothing on the heap: every buffer is sized in the constructor (OSQP-like data
// flow). Checked over the rotating-target case (every phase, recovery solves) with injected faults:
//  - operator new is counted here (std::vector, std::string, ... anywhere in the step);
//  - Eigen's heap allocations abort under EIGEN_RUNTIME_NO_MALLOC in builds with assertions (Debug/asan;
//    flight_sw/CMakeLists.txt defines it for every flight_sw library).
#include <doctest/doctest.h>

#include <atomic>
#include <cstdlib>
#include <new>

#include "flight_sw/guidance/guidance.hpp"

namespace {
std::atomic<long> g_news{0};
std::atomic<bool> g_counting{false};
}  // namespace

void* operator new(std::size_t n) {
  if (g_counting) ++g_news;
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }

using namespace rvd::guidance;

namespace {
void forbid_heap(bool forbid) {
  g_counting = forbid;
#ifdef EIGEN_RUNTIME_NO_MALLOC
  Eigen::internal::set_is_malloc_allowed(!forbid);
#endif
}
}  // namespace

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
    g_news = 0;
    int fallbacks = 0, steps = 0;
    for (; steps < 400; ++steps) {
      NavInput nav;
      nav.step = static_cast<uint32_t>(steps);
      nav.t_s = t;
      nav.x_lvlh = x;
      nav.q_lvlh_body = attitude_after(target0, t);
      nav.omega_body_rad_s = c.omega_body_rad_s;
      if (steps % 11 == 5) nav.x_lvlh(2) = std::nan("");  // rejected input: fallback path
      forbid_heap(true);
      const Command cmd = g.step(nav, steps % 7 == 3 ? 1.0 : 0.0);  // a 1 us budget now and then
      forbid_heap(false);
      if (cmd.status != StepStatus::Ok && cmd.status != StepStatus::Recovered) ++fallbacks;
      if (cmd.phase == Phase::Docked) break;
      Vector6d xp = x;
      xp.tail<3>() += cmd.dv_alloc_mps;
      x = cw_stm(n, cmd.period_s) * xp;
      t += cmd.period_s;
    }
    CHECK(g_news == 0);
    CHECK(g.phase() == Phase::Docked);  // it still docks through the injected faults
    CHECK(fallbacks > 10);             // and the fallback paths were exercised
  }
}
