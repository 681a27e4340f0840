// Closed loop against the CW plant: the dissertation's three cases dock, and the summary figures are
// those of the trajectory, checked through a CW integrator written here (RK4 on the equations of
// motion, not the closed-form STM the loop uses). (tests/test_guidance_closed_loop.py re-checks the
// geometry from the log independently.)
#include <doctest/doctest.h>

#include <cmath>

#include "flight_sw/guidance/closed_loop.hpp"

using namespace rvd::guidance;

namespace {
// xdd = 3n^2 x + 2n yd, ydd = -2n xd, zdd = -n^2 z (LVLH: x radial, y along-track), by RK4 at 0.1 s.
Vector6d cw_rk4(double n, Vector6d x, double t_s) {
  auto f = [n](const Vector6d& s) {
    Vector6d d;
    d << s(3), s(4), s(5), 3 * n * n * s(0) + 2 * n * s(4), -2 * n * s(3), -n * n * s(2);
    return d;
  };
  const int steps = static_cast<int>(std::ceil(t_s / 0.1));
  const double h = t_s / steps;
  for (int i = 0; i < steps; ++i) {
    const Vector6d k1 = f(x), k2 = f(x + 0.5 * h * k1), k3 = f(x + 0.5 * h * k2), k4 = f(x + h * k3);
    x += h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4);
  }
  return x;
}
}  // namespace

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
    // The trajectory is the CW flow of the logged impulses (1 mm, 1e-6 m/s: RK4's error over 30 s),
    // so the impulses are those the plant received; the totals are their sums and the sampled times.
    const double n = p.mean_motion_rad_s();
    double dv[3] = {0, 0, 0}, t[3] = {0, 0, 0};
    for (size_t i = 0; i + 1 < r.log.size(); ++i) {
      const ClosedLoopStep& s = r.log[i];
      if (s.phase == Phase::Docked) break;
      Vector6d kicked = s.x;
      kicked.tail<3>() += s.dv_alloc_mps;
      const Vector6d next = cw_rk4(n, kicked, r.log[i + 1].t_s - s.t_s);
      CHECK((next.head<3>() - r.log[i + 1].x.head<3>()).cwiseAbs().maxCoeff() < 1e-3);
      CHECK((next.tail<3>() - r.log[i + 1].x.tail<3>()).cwiseAbs().maxCoeff() < 1e-6);
      const int ph = static_cast<int>(s.phase) - 1;
      dv[ph] += s.dv_alloc_mps.norm();
      t[ph] += r.log[i + 1].t_s - s.t_s;
    }
    for (int ph = 0; ph < 3; ++ph) {
      CHECK(r.phases[ph].dv_mps == doctest::Approx(dv[ph]).epsilon(1e-12));
      CHECK(r.phases[ph].time_s == doctest::Approx(t[ph]).epsilon(1e-12));
    }
    CHECK(r.total.dv_mps == doctest::Approx(dv[0] + dv[1] + dv[2]).epsilon(1e-12));
    CHECK(r.t_final_s == doctest::Approx(t[0] + t[1] + t[2]).epsilon(1e-12));
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
