#include "flight_sw/guidance/attitude.hpp"

#include <cmath>

#include "flight_sw/guidance/params.hpp"

namespace rvd::guidance {

namespace {
constexpr double kPi = 3.14159265358979323846;
double wrap(double a) { return a - 2.0 * kPi * std::floor((a + kPi) / (2.0 * kPi)); }
}  // namespace

double yaw_rad(const Eigen::Quaterniond& q) { return wrap(2.0 * std::atan2(q.z(), q.w())); }

AttitudeMpc::AttitudeMpc(const GuidanceParams& params) : p_(params.attitude), x0_(solver::Vector::Zero(2)) {
  const PhaseParams* phases[3] = {&params.rendezvous, &params.approach, &params.docking};
  for (int k = 0; k < 3; ++k) {
    const int N = phases[k]->N;
    const double T = phases[k]->Ts_s;
    solver::OcpQp& qp = qp_[k];
    qp = solver::OcpQp(solver::OcpQpDims::uniform(N, 2, 1, 2, 0, 0));
    for (int i = 0; i <= N; ++i) {
      // e_{i+1} = e_i + T e_dot_i + T^2 / (2 I) tau_i, e_dot_{i+1} = e_dot_i + T / I tau_i (zero-order hold).
      if (i < N) {
        qp.A[i] << 1.0, T, 0.0, 1.0;
        qp.B[i] << 0.5 * T * T / p_.inertia_kgm2, T / p_.inertia_kgm2;
        qp.R[i](0, 0) = 2.0 * p_.R_torque;
        qp.D[i] << 1.0, -1.0;
        qp.d[i].setConstant(p_.torque_max_nm);
      }
      qp.Q[i].diagonal() << 2.0 * p_.Q_angle, 2.0 * p_.Q_rate;  // the cost's e'Qe is the OCP's 1/2 e'(2Q)e
    }
    solver_[k] = std::make_unique<solver::FastMpcSolver>(qp.dims, phases[k]->solver);
  }
}

AttitudeMpc::~AttitudeMpc() = default;

AttitudeMpc::Result AttitudeMpc::step(int k, double angle, double rate, double target_angle, double target_rate) {
  Result r;
  // The docking attitude faces the target's port: the target's angle plus pi, turning at its rate.
  r.error_rad = wrap(angle - (target_angle + kPi));
  x0_ << r.error_rad, rate - target_rate;
  solver_[k]->solve(qp_[k], x0_);
  r.info = solver_[k]->info();
  const bool ok = (r.info.status == solver::Status::Solved || r.info.status == solver::Status::MaxIter) &&
                  std::isfinite(solver_[k]->u()[0](0));
  r.torque_nm = ok ? std::fmax(-p_.torque_max_nm, std::fmin(p_.torque_max_nm, solver_[k]->u()[0](0))) : 0.0;
  if (ok) solver_[k]->shift_warm_start();
  return r;
}

}  // namespace rvd::guidance
