// A small dense QP solver for the command governor: Goldfarb and Idnani's dual active-set method
// ("A numerically stable dual method for solving strictly convex quadratic programs", Mathematical
// Programming 27, 1983), for a diagonal Hessian:
//
//   minimize 1/2 z'diag(H)z + c'z   subject to   G z <= h        (n <= kMaxVars, m <= kMaxRows)
//
// It starts from the unconstrained minimum and adds the most violated row until none is violated,
// dropping rows whose multiplier would turn negative; J = L^-T Q and R (upper triangular) are kept
// up to date with Givens rotations. Fixed-size storage: solve() allocates nothing.
#pragma once

#include <cmath>

namespace ecg {

constexpr int kMaxVars = 24;
constexpr int kMaxRows = 400;

enum class QpStatus { Solved = 0, MaxIter = 1, Infeasible = 2 };

struct DenseQp {
  int n = 0, m = 0;
  double H[kMaxVars] = {}, c[kMaxVars] = {};
  double G[kMaxRows][kMaxVars] = {}, h[kMaxRows] = {};
};

class DualActiveSet {
 public:
  // z: the solution (n entries) on return. iterations: active-set changes (adds and drops).
  QpStatus solve(const DenseQp& qp, double* z, int max_iterations = 200) {
    const int n = qp.n;
    q_ = 0;
    iterations = 0;
    for (int i = 0; i < n; ++i) {
      z[i] = -qp.c[i] / qp.H[i];
      for (int j = 0; j < n; ++j) J_[i][j] = i == j ? 1.0 / std::sqrt(qp.H[i]) : 0.0;
    }
    for (int k = 0; k < qp.m; ++k) {
      active_[k] = false;
      norm_[k] = 0.0;
      for (int i = 0; i < n; ++i) norm_[k] += qp.G[k][i] * qp.G[k][i];
      norm_[k] = std::sqrt(norm_[k]);
    }
    for (;;) {
      // The most violated row, by its distance (rows are scaled by their norms).
      int p = -1;
      double worst = 0.0;
      for (int k = 0; k < qp.m; ++k) {
        if (active_[k] || norm_[k] == 0.0) continue;
        const double s = (slack(qp, k, z)) / norm_[k];
        if (s < -kTol * (1.0 + std::abs(qp.h[k]) / norm_[k]) && s < worst) {
          worst = s;
          p = k;
        }
      }
      if (p < 0) return QpStatus::Solved;
      // n+ = a_p = -G_p (rows are a'z >= b with a = -G, b = -h).
      for (int i = 0; i < n; ++i) np_[i] = -qp.G[p][i];
      u_[q_] = 0.0;
      for (;;) {
        if (++iterations > max_iterations) return QpStatus::MaxIter;
        for (int j = 0; j < n; ++j) {
          d_[j] = 0.0;
          for (int i = 0; i < n; ++i) d_[j] += J_[i][j] * np_[i];
        }
        double dir_dot = 0.0, dir_norm = 0.0;
        for (int i = 0; i < n; ++i) {
          dir_[i] = 0.0;
          for (int j = q_; j < n; ++j) dir_[i] += J_[i][j] * d_[j];
          dir_dot += dir_[i] * np_[i];
          dir_norm += dir_[i] * dir_[i];
        }
        for (int j = q_ - 1; j >= 0; --j) {  // r = R^-1 d_1
          double v = d_[j];
          for (int l = j + 1; l < q_; ++l) v -= R_[j][l] * r_[l];
          r_[j] = v / R_[j][j];
        }
        double t1 = HUGE_VAL, t2 = HUGE_VAL;
        int drop = -1;
        for (int j = 0; j < q_; ++j)
          if (r_[j] > kTiny && u_[j] / r_[j] < t1) {
            t1 = u_[j] / r_[j];
            drop = j;
          }
        if (std::sqrt(dir_norm) > kTiny && dir_dot > kTiny) t2 = -slack(qp, p, z) / dir_dot;
        const double t = std::fmin(t1, t2);
        if (t == HUGE_VAL) return QpStatus::Infeasible;
        for (int j = 0; j < q_; ++j) u_[j] -= t * r_[j];
        u_[q_] += t;
        if (t2 == HUGE_VAL) {  // no primal step: a dual step, then drop
          remove(drop, n);
          continue;
        }
        for (int i = 0; i < n; ++i) z[i] += t * dir_[i];
        if (t == t2) {
          add(p, n);
          break;
        }
        remove(drop, n);
      }
    }
  }

  int iterations = 0;
  int active_rows() const { return q_; }

 private:
  static constexpr double kTol = 1e-9, kTiny = 1e-14;

  static double slack(const DenseQp& qp, int k, const double* z) {  // h - G z (>= 0 feasible)
    double s = qp.h[k];
    for (int i = 0; i < qp.n; ++i) s -= qp.G[k][i] * z[i];
    return s;
  }

  void add(int p, int n) {
    for (int j = n - 1; j > q_; --j) {  // zero d[q+1..n-1] into d[q], rotating J's columns alike
      const double a = d_[j - 1], b = d_[j];
      if (b == 0.0) continue;
      const double hyp = std::hypot(a, b), cs = a / hyp, sn = b / hyp;
      d_[j - 1] = hyp;
      d_[j] = 0.0;
      for (int i = 0; i < n; ++i) {
        const double x = J_[i][j - 1], y = J_[i][j];
        J_[i][j - 1] = cs * x + sn * y;
        J_[i][j] = -sn * x + cs * y;
      }
    }
    for (int i = 0; i <= q_; ++i) R_[i][q_] = d_[i];
    which_[q_] = p;
    active_[p] = true;
    ++q_;
  }

  void remove(int k, int n) {
    active_[which_[k]] = false;
    for (int j = k; j < q_ - 1; ++j) {
      which_[j] = which_[j + 1];
      u_[j] = u_[j + 1];
      for (int i = 0; i <= j + 1; ++i) R_[i][j] = R_[i][j + 1];
    }
    u_[q_ - 1] = u_[q_];  // the pending row's multiplier moves down with the rest
    for (int j = k; j < q_ - 1; ++j) {  // R is Hessenberg from column k: rotate rows j, j+1 back
      const double a = R_[j][j], b = R_[j + 1][j];
      if (b == 0.0) continue;
      const double hyp = std::hypot(a, b), cs = a / hyp, sn = b / hyp;
      for (int l = j; l < q_ - 1; ++l) {
        const double x = R_[j][l], y = R_[j + 1][l];
        R_[j][l] = cs * x + sn * y;
        R_[j + 1][l] = -sn * x + cs * y;
      }
      for (int i = 0; i < n; ++i) {
        const double x = J_[i][j], y = J_[i][j + 1];
        J_[i][j] = cs * x + sn * y;
        J_[i][j + 1] = -sn * x + cs * y;
      }
    }
    --q_;
  }

  int q_ = 0;
  double J_[kMaxVars][kMaxVars] = {}, R_[kMaxVars][kMaxVars] = {};
  double d_[kMaxVars] = {}, r_[kMaxVars] = {}, dir_[kMaxVars] = {}, np_[kMaxVars] = {};
  double u_[kMaxVars + 1] = {}, norm_[kMaxRows] = {};
  int which_[kMaxVars] = {};
  bool active_[kMaxRows] = {};
};

}  // namespace ecg
