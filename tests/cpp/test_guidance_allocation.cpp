// Thruster allocation (eqs 2.4-2.6): pulse widths t = m |dv| / F, minimum impulse bit, pulse cap.
#include <doctest/doctest.h>

#include <cmath>
#include <limits>

#include "flight_sw/guidance/allocation.hpp"

using namespace rvd::guidance;

TEST_CASE("pulse widths realise dv = F t / m on the right thrusters") {
  ThrusterParams thr;  // 14 kg, 0.5 N, 10 ms
  const double cap = max_pulse_s(0.1786, thr);
  CHECK(cap == doctest::Approx(0.1786 * 14.0 / 0.5));
  const Eigen::Vector3d dv(0.05, -0.1, 0.0);
  const Allocation a = allocate_thrusters(dv, cap, thr);
  CHECK(a.pulse_s[PlusX] == doctest::Approx(14.0 * 0.05 / 0.5));
  CHECK(a.pulse_s[MinusX] == 0.0);
  CHECK(a.pulse_s[MinusY] == doctest::Approx(14.0 * 0.1 / 0.5));
  CHECK(a.pulse_s[PlusY] == 0.0);
  CHECK(a.pulse_s[PlusZ] == 0.0);
  CHECK(a.pulse_s[MinusZ] == 0.0);
  // The realised delta-v from the pulses, computed independently: F t / m with the thruster's sign.
  const double F = 0.5, m = 14.0;
  CHECK(a.dv_alloc_mps.x() == doctest::Approx(F * a.pulse_s[PlusX] / m));
  CHECK(a.dv_alloc_mps.y() == doctest::Approx(-F * a.pulse_s[MinusY] / m));
  CHECK((a.dv_alloc_mps - dv).norm() < 1e-15);
}

TEST_CASE("pulses below the minimum impulse bit are dropped, at or above are fired") {
  ThrusterParams thr;
  thr.min_impulse_bit_s = 0.010;
  const double dv_mib = thr.thrust_N * thr.min_impulse_bit_s / thr.mass_kg;  // 0.357 mm/s
  const Allocation below = allocate_thrusters(Eigen::Vector3d(0.0, 0.0, -0.99 * dv_mib), 5.0, thr);
  CHECK(below.pulse_s[MinusZ] == 0.0);
  CHECK(below.dv_alloc_mps.isZero(0.0));
  const Allocation at = allocate_thrusters(Eigen::Vector3d(0.0, 0.0, -1.01 * dv_mib), 5.0, thr);
  CHECK(at.pulse_s[MinusZ] == doctest::Approx(0.0101));
  CHECK(at.dv_alloc_mps.z() == doctest::Approx(-1.01 * dv_mib));
}

TEST_CASE("pulses are cut at the cap and the realised dv follows the cut pulse") {
  ThrusterParams thr;
  const double cap = max_pulse_s(0.0357, thr);  // docking: 1.0 s
  const Allocation a = allocate_thrusters(Eigen::Vector3d(0.2, 0.0, 0.0), cap, thr);
  CHECK(a.pulse_s[PlusX] == doctest::Approx(cap));
  CHECK(a.dv_alloc_mps.x() == doctest::Approx(0.0357));
}

TEST_CASE("a non-finite command fires nothing") {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const Allocation a = allocate_thrusters(Eigen::Vector3d(nan, std::numeric_limits<double>::infinity(), 0.01), 5.0, ThrusterParams{});
  CHECK(a.pulse_s[PlusX] == 0.0);
  CHECK(a.pulse_s[MinusX] == 0.0);
  CHECK(a.pulse_s[PlusY] == 0.0);
  CHECK(a.pulse_s[MinusY] == 0.0);
  CHECK(a.pulse_s[PlusZ] > 0.0);
  CHECK(a.dv_alloc_mps.allFinite());
}
