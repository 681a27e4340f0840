// CW model: the closed-form STM against physical facts that do not depend on how it was derived.
#include <doctest/doctest.h>

#include <cmath>

#include "flight_sw/guidance/cw.hpp"

using namespace rvd::guidance;

TEST_CASE("mean motion of a 500 km circular orbit") {
  const double n = mean_motion_rad_s(500e3);
  // Kepler: T = 2 pi sqrt(a^3 / mu) = 5677 s for a = 6878.137 km.
  CHECK(2.0 * M_PI / n == doctest::Approx(5676.98).epsilon(1e-4));
}

TEST_CASE("STM is the identity at t = 0 and composes over time") {
  const double n = mean_motion_rad_s(500e3);
  CHECK((cw_stm(n, 0.0) - Matrix6d::Identity()).cwiseAbs().maxCoeff() < 1e-15);
  const Matrix6d ab = cw_stm(n, 30.0) * cw_stm(n, 20.0);
  CHECK((ab - cw_stm(n, 50.0)).cwiseAbs().maxCoeff() < 1e-9);
}

TEST_CASE("STM derivative at 0 is the CW system matrix and it solves dPhi/dt = Ac Phi") {
  const double n = mean_motion_rad_s(500e3), h = 1e-3, t = 400.0;
  const Matrix6d dPhi = (cw_stm(n, t + h) - cw_stm(n, t - h)) / (2.0 * h);
  CHECK((dPhi - cw_system_matrix(n) * cw_stm(n, t)).cwiseAbs().maxCoeff() < 1e-8);
}

TEST_CASE("a natural motion circumnavigation closes after one orbit; V-bar points are equilibria") {
  const double n = mean_motion_rad_s(500e3), T = 2.0 * M_PI / n;
  Vector6d x;
  x << 100.0, 0.0, 20.0, 0.0, -2.0 * n * 100.0, 0.0;  // ydot = -2 n x: no along-track drift
  const Vector6d xT = cw_stm(n, T) * x;
  CHECK((xT - x).cwiseAbs().maxCoeff() < 1e-9);
  Vector6d vbar;
  vbar << 0.0, -300.0, 0.0, 0.0, 0.0, 0.0;
  CHECK((cw_stm(n, 1234.5) * vbar - vbar).cwiseAbs().maxCoeff() < 1e-12);
  // A radial offset without the matching velocity drifts along-track by -12 pi x per orbit (CW secular term).
  Vector6d radial;
  radial << 10.0, 0.0, 0.0, 0.0, 0.0, 0.0;
  CHECK((cw_stm(n, T) * radial)(1) == doctest::Approx(-12.0 * M_PI * 10.0).epsilon(1e-9));
}

TEST_CASE("impulsive discretisation: B = A [0; I]") {
  const double n = mean_motion_rad_s(500e3);
  Matrix6d A;
  Matrix63d B;
  cw_impulsive_model(n, 30.0, A, B);
  CHECK((A - cw_stm(n, 30.0)).cwiseAbs().maxCoeff() == 0.0);
  Vector6d x = Vector6d::Zero();
  Eigen::Vector3d dv(0.1, -0.05, 0.02);
  Vector6d with_impulse = x;
  with_impulse.tail<3>() += dv;
  CHECK((A * with_impulse - (A * x + B * dv)).cwiseAbs().maxCoeff() < 1e-14);
}
