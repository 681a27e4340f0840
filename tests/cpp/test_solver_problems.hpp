// MPC-like test QPs for the solver tests (CW dynamics, the project's phase shapes) and an
// optimality certificate computed from scratch: the KKT conditions of the stage-wise QP.
#pragma once

#include <algorithm>
#include <cmath>
#include <random>

#include "flight_sw/solver/fast_mpc.hpp"

namespace rvd::solver::testing {

// Clohessy-Wiltshire state transition over t seconds at mean motion n (LVLH: x radial, y
// along-track, z normal); impulsive input matrix B = Phi[:, 3:6].
inline Matrix cw_phi(double n, double t) {
  const double s = std::sin(n * t), c = std::cos(n * t), nt = n * t;
  Matrix P(6, 6);
  P << 4 - 3 * c, 0, 0, s / n, 2 * (1 - c) / n, 0,  //
      6 * (s - nt), 1, 0, 2 * (c - 1) / n, (4 * s - 3 * nt) / n, 0,  //
      0, 0, c, 0, 0, s / n,  //
      3 * n * s, 0, 0, c, 2 * s, 0,  //
      6 * n * (c - 1), 0, 0, -2 * s, 4 * c - 3, 0,  //
      0, 0, -n * s, 0, 0, c;
  return P;
}
constexpr double kMeanMotion500km = 0.0011068;  // rad/s

// Docking phase: hard 8 deg pyramid cone about the port (4 rows on x), |v|inf <= 0.1 m/s (6 rows on
// x), |u|inf <= umax (6 rows on u); no input on stage N. Stage 0's cone and velocity rows involve x0
// only: constant rows. `cone_shift` moves the cone apex along -y (metres).
inline OcpQp docking_like(int N, double cone_shift, double umax = 0.0357) {
  OcpQp qp(OcpQpDims{N, 6, [&] {
                       std::vector<int> nu(N + 1, 3);
                       nu[N] = 0;
                       return nu;
                     }(),
                     [&] {
                       std::vector<int> nc(N + 1, 16);
                       nc[N] = 10;
                       return nc;
                     }()});
  const Matrix A = cw_phi(kMeanMotion500km, 5.0);
  const double t = std::tan(8.0 * M_PI / 180.0);
  Eigen::Matrix<double, 4, 3> H;  // axis -y: |x| <= t * (-y), |z| <= t * (-y) about the apex
  H << 1, t, 0, -1, t, 0, 0, t, 1, 0, t, -1;
  Eigen::Vector3d apex(0.0, -0.5 - cone_shift, 0.0);
  Vector xref = Vector::Zero(6);
  xref(1) = -0.5;
  for (int i = 0; i <= N; ++i) {
    if (i < N) {
      qp.A[i] = A;
      qp.B[i] = A.rightCols(3);
    }
    qp.Q[i] = 20.0 * Matrix::Identity(6, 6);
    qp.q[i] = -qp.Q[i] * xref;
    qp.R[i] = 1e6 * Matrix::Identity(qp.dims.nu[i], qp.dims.nu[i]);
    qp.C[i].block(0, 0, 4, 3) = H;
    qp.d[i].head(4) = H * apex;
    qp.C[i].block(4, 3, 3, 3) = Matrix::Identity(3, 3);
    qp.C[i].block(7, 3, 3, 3) = -Matrix::Identity(3, 3);
    qp.d[i].segment(4, 6).setConstant(0.1);
    if (i < N) {
      qp.D[i].block(10, 0, 3, 3) = Matrix::Identity(3, 3);
      qp.D[i].block(13, 0, 3, 3) = -Matrix::Identity(3, 3);
      qp.d[i].segment(10, 6).setConstant(umax);
    }
  }
  return qp;
}

inline Vector docking_x0() {
  Vector x0(6);
  x0 << 0.3, -15.0, -0.2, 0.01, 0.03, -0.005;
  return x0;
}

// Random MPC-like QP, feasible by construction: 3 thrust inputs plus 0-4 slack inputs per stage
// (stage-varying), |u|inf box, hard halfspaces on the state satisfied by a reference rollout (half
// of them exactly, so they bind), soft halfspaces a'p - v <= c with v >= 0 and linear slack cost
// (zero Hessian), PSD state cost with zero weights, a satisfied constant row on stage 0.
inline OcpQp random_like(int N, std::mt19937& rng, Vector& x0) {
  std::normal_distribution<double> nrm(0.0, 1.0);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const double umax = 0.2, ts = 20.0;
  const Matrix A = cw_phi(kMeanMotion500km, ts);
  const Matrix B3 = A.rightCols(3);
  std::vector<int> nsl(N + 1), nu(N + 1), nc(N + 1);
  const int nhard = 2;
  for (int i = 0; i <= N; ++i) {
    nsl[i] = static_cast<int>(uni(rng) * 5.0);
    nu[i] = 3 + nsl[i];
    nc[i] = 6 + (i > 0 ? nhard : 1) + 2 * nsl[i];
  }
  OcpQp qp(OcpQpDims{N, 6, nu, nc});
  x0.resize(6);
  for (int k = 0; k < 3; ++k) x0(k) = 300.0 * nrm(rng), x0(k + 3) = 0.2 * nrm(rng);
  std::vector<Vector> xr(N + 1);
  xr[0] = x0;
  for (int i = 0; i < N; ++i) {
    Vector ur(3);
    for (int k = 0; k < 3; ++k) ur(k) = umax * 0.8 * (2.0 * uni(rng) - 1.0);
    xr[i + 1] = A * xr[i] + B3 * ur;
  }
  Vector target = Vector::Zero(6);
  for (int k = 0; k < 3; ++k) target(k) = 200.0 * nrm(rng);
  for (int i = 0; i <= N; ++i) {
    const int m = nu[i];
    if (i < N) {
      qp.A[i] = A;
      qp.B[i].leftCols(3) = B3;
    }
    Vector qd(6);
    for (int k = 0; k < 6; ++k) qd(k) = uni(rng) < 0.7 ? 1e-3 * uni(rng) : 0.0;
    qp.Q[i] = qd.asDiagonal();
    qp.q[i] = -qp.Q[i] * target;
    Matrix M(3, 3);
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) M(a, b) = nrm(rng);
    qp.R[i].topLeftCorner(3, 3) = (M * M.transpose() + 3.0 * Matrix::Identity(3, 3)) * (1.0 + 99.0 * uni(rng));
    for (int k = 0; k < 3; ++k) qp.r[i](k) = nrm(rng);
    for (int k = 3; k < m; ++k) qp.r[i](k) = 0.1 + 9.9 * uni(rng);
    int row = 0;
    for (int k = 0; k < 3; ++k) {
      qp.D[i](row, k) = 1.0;
      qp.d[i](row++) = umax;
      qp.D[i](row, k) = -1.0;
      qp.d[i](row++) = umax;
    }
    if (i > 0) {
      for (int h = 0; h < nhard; ++h) {
        Vector a(6);
        for (int k = 0; k < 6; ++k) a(k) = (k < 3 ? 1.0 : 0.3) * nrm(rng);
        qp.C[i].row(row) = a.transpose();
        qp.d[i](row++) = a.dot(xr[i]) + (uni(rng) < 0.5 ? 0.0 : 50.0 * uni(rng));
      }
    } else {
      Vector a(6);
      for (int k = 0; k < 6; ++k) a(k) = nrm(rng);
      qp.C[0].row(row) = a.transpose();
      qp.d[0](row++) = a.dot(x0) + 1.0;
    }
    for (int k = 0; k < nsl[i]; ++k) {
      Eigen::Vector3d a(nrm(rng), nrm(rng), nrm(rng));
      a.normalize();
      qp.C[i].block(row, 0, 1, 3) = a.transpose();
      qp.D[i](row, 3 + k) = -1.0;
      qp.d[i](row++) = a.dot(xr[i].head(3)) - 100.0 * uni(rng);
      qp.D[i](row, 3 + k) = -1.0;
      qp.d[i](row++) = 0.0;
    }
  }
  return qp;
}

// A planar double integrator (nx = 4: position, velocity in x and y; 2 inputs, |u| <= 1, |v| <= 2),
// to run the solver's generic-size code path (the project's nx = 6 has its own fixed-size one).
inline OcpQp planar_like(int N, Vector& x0) {
  OcpQpDims dims = OcpQpDims::uniform(N, 4, 2, 8, 0, 4);
  OcpQp qp(dims);
  const double dt = 0.5;
  Matrix A = Matrix::Identity(4, 4);
  A(0, 2) = A(1, 3) = dt;
  Matrix B(4, 2);
  B << 0.5 * dt * dt, 0, 0, 0.5 * dt * dt, dt, 0, 0, dt;
  for (int i = 0; i <= N; ++i) {
    if (i < N) {
      qp.A[i] = A;
      qp.B[i] = B;
      qp.R[i] = 0.1 * Matrix::Identity(2, 2);
    }
    qp.Q[i] = Matrix::Identity(4, 4);
    qp.Q[i](2, 2) = qp.Q[i](3, 3) = 0.1;
    int row = 0;
    for (int k = 0; k < 2; ++k) {  // |v| <= 2
      qp.C[i](row, 2 + k) = 1.0, qp.d[i](row++) = 2.0;
      qp.C[i](row, 2 + k) = -1.0, qp.d[i](row++) = 2.0;
    }
    if (i < N)
      for (int k = 0; k < 2; ++k) {  // |u| <= 1
        qp.D[i](row, k) = 1.0, qp.d[i](row++) = 1.0;
        qp.D[i](row, k) = -1.0, qp.d[i](row++) = 1.0;
      }
  }
  x0.resize(4);
  x0 << 10.0, -5.0, 1.5, 0.0;
  return qp;
}

inline double objective(const OcpQp& qp, const std::vector<Vector>& x, const std::vector<Vector>& u) {
  double f = 0.0;
  for (int i = 0; i <= qp.dims.N; ++i) {
    f += 0.5 * x[i].dot(qp.Q[i] * x[i]) + qp.q[i].dot(x[i]);
    f += 0.5 * u[i].dot(qp.R[i] * u[i]) + qp.r[i].dot(u[i]);
  }
  return f;
}

// KKT conditions at (x, u, lambda, pi), each relative to its own scale: the largest of
// primal infeasibility (dynamics, x0, inequality violation), dual infeasibility (negative lambda),
// stationarity and complementarity |lambda_j (d - Cx - Du)_j|.
struct Kkt {
  double primal = 0, dual_sign = 0, stationarity = 0, complementarity = 0;
  double worst() const { return std::max({primal, dual_sign, stationarity, complementarity}); }
};

inline Kkt kkt(const OcpQp& qp, const Vector& x0, const std::vector<Vector>& x, const std::vector<Vector>& u,
               const std::vector<Vector>& lam, const std::vector<Vector>& pi) {
  Kkt k;
  const int N = qp.dims.N;
  double pscale = 1.0, gscale = 1.0;
  k.primal = (x[0] - x0).lpNorm<Eigen::Infinity>();
  for (int i = 0; i <= N; ++i) {
    if (i < N) k.primal = std::max(k.primal, (qp.A[i] * x[i] + qp.B[i] * u[i] + qp.b[i] - x[i + 1]).lpNorm<Eigen::Infinity>());
    if (qp.dims.nc[i] == 0) continue;
    const Vector slack = qp.d[i] - qp.C[i] * x[i] - qp.D[i] * u[i];
    pscale = std::max(pscale, qp.d[i].lpNorm<Eigen::Infinity>());
    k.primal = std::max(k.primal, -slack.minCoeff());
    k.dual_sign = std::max(k.dual_sign, -lam[i].minCoeff());
    k.complementarity = std::max(k.complementarity, lam[i].cwiseProduct(slack).cwiseAbs().maxCoeff());
  }
  for (int i = 0; i <= N; ++i) {
    Vector gu = qp.R[i] * u[i] + qp.r[i];
    gscale = std::max(gscale, gu.lpNorm<Eigen::Infinity>());
    gu += qp.D[i].transpose() * lam[i];
    if (i < N) gu += qp.B[i].transpose() * pi[i];
    k.stationarity = std::max(k.stationarity, gu.lpNorm<Eigen::Infinity>());
    if (i == 0) continue;
    Vector gx = qp.Q[i] * x[i] + qp.q[i];
    gscale = std::max(gscale, gx.lpNorm<Eigen::Infinity>());
    gx += qp.C[i].transpose() * lam[i] - pi[i - 1];
    if (i < N) gx += qp.A[i].transpose() * pi[i];
    k.stationarity = std::max(k.stationarity, gx.lpNorm<Eigen::Infinity>());
  }
  k.primal /= pscale;
  k.dual_sign /= gscale;
  k.stationarity /= gscale;
  k.complementarity /= std::max(1.0, std::abs(objective(qp, x, u)));
  return k;
}

}  // namespace rvd::solver::testing
