// Closed loop against the CW plant: the dissertation's three cases dock; the summary figures agree
// with the log they were computed from. (tests/test_guidance_closed_loop.py re-checks the physics
// from the log with geometry written independently.)
#include <doctest/doctest.h>

#include <cmath>

#include "flight_sw/guidance/closed_loop.hpp"

using namespace rvd::guidance;

TEST_CASE("cases 1-3 dock without keep-out entry outside the cone and within |u|_inf") {
  GuidanceParams p;
  for (int k = 1; k <= 3; ++k) {
    CAPTURE(k);
    const ScenarioCase c = dissertation_case(k);
    const ClosedLoopResult r = run_closed_loop(p, c.x0, c.q_lvlh_body, c.omega_body_rad_s);
    CHECK(r.docked);
    CHECK(r.keepout_violations == 0);
    CHECK(r.max_u_inf_ratio <= 1.0 + 1e-12);
    CHECK(r.final_port_distance_m <= p.dock_tolerance_m);
    CHECK(r.t_final_s < 200.0 * 60.0);
    // Phase totals add up to the log.
    double dv = 0.0, t = 0.0;
    for (const ClosedLoopStep& s : r.log)
      if (s.phase != Phase::Docked) {
        dv += s.dv_alloc_mps.norm();
        t += s.period_s;
      }
    CHECK(r.total.dv_mps == doctest::Approx(dv));
    CHECK(r.total.time_s == doctest::Approx(t));
    CHECK(r.t_final_s == doctest::Approx(t));
    // Phases only move forward.
    for (size_t i = 1; i < r.log.size(); ++i) CHECK(r.log[i].phase >= r.log[i - 1].phase);
  }
}

TEST_CASE("the loop stops at the timeout and says so") {
  GuidanceParams p;
  const ScenarioCase c = dissertation_case(1);
  const ClosedLoopResult r = run_closed_loop(p, c.x0, c.q_lvlh_body, c.omega_body_rad_s, 300.0);
  CHECK(!r.docked);
  CHECK(r.reason.find("timeout") != std::string::npos);
  CHECK(r.t_final_s == doctest::Approx(300.0));
}
