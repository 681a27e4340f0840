#include "flight_sw/guidance/cw.hpp"

#include <cmath>

namespace rvd::guidance {

double mean_motion_rad_s(double altitude_m, double mu_m3_s2, double earth_radius_m) {
  const double a = earth_radius_m + altitude_m;
  return std::sqrt(mu_m3_s2 / (a * a * a));
}

Matrix6d cw_system_matrix(double n) {
  Matrix6d Ac = Matrix6d::Zero();
  Ac.topRightCorner<3, 3>().setIdentity();
  Ac(3, 0) = 3.0 * n * n;
  Ac(3, 4) = 2.0 * n;
  Ac(4, 3) = -2.0 * n;
  Ac(5, 2) = -n * n;
  return Ac;
}

Matrix6d cw_stm(double n, double t) {
  Matrix6d P = Matrix6d::Zero();
  if (n == 0.0) {  // no orbit: the limit n -> 0, a double integrator
    P.setIdentity();
    P.topRightCorner<3, 3>() = t * Eigen::Matrix3d::Identity();
    return P;
  }
  const double nt = n * t, s = std::sin(nt), c = std::cos(nt);
  // position <- position
  P(0, 0) = 4.0 - 3.0 * c;
  P(1, 0) = 6.0 * (s - nt);
  P(1, 1) = 1.0;
  P(2, 2) = c;
  // position <- velocity
  P(0, 3) = s / n;
  P(0, 4) = 2.0 * (1.0 - c) / n;
  P(1, 3) = 2.0 * (c - 1.0) / n;
  P(1, 4) = (4.0 * s - 3.0 * nt) / n;
  P(2, 5) = s / n;
  // velocity <- position
  P(3, 0) = 3.0 * n * s;
  P(4, 0) = 6.0 * n * (c - 1.0);
  P(5, 2) = -n * s;
  // velocity <- velocity
  P(3, 3) = c;
  P(3, 4) = 2.0 * s;
  P(4, 3) = -2.0 * s;
  P(4, 4) = 4.0 * c - 3.0;
  P(5, 5) = c;
  return P;
}

void cw_impulsive_model(double n, double Ts, Matrix6d& A, Matrix63d& B) {
  A = cw_stm(n, Ts);
  B = A.rightCols<3>();  // A [0; I]
}

void cw_burn_model(double n, double Ts, double centroid_s, Matrix6d& A, Matrix63d& B) {
  A = cw_stm(n, Ts);
  B = centroid_s == 0.0 ? Matrix63d(A.rightCols<3>()) : Matrix63d(cw_stm(n, Ts - centroid_s).rightCols<3>());
}

}  // namespace rvd::guidance
