#include "flight_sw/solver/settings.hpp"

namespace rvd::solver {

Settings Settings::converged(int max_iter) {
  Settings s;
  s.mode = Mode::Converged;
  s.max_iter = max_iter;
  return s;
}

Settings Settings::reference() {
  Settings s;
  s.mode = Mode::Converged;
  s.tol = 1e-10;
  s.max_iter = 100;
  s.warm_start = false;
  return s;
}

Settings Settings::fixed_barrier(double kappa, int max_iter) {
  Settings s;
  s.mode = Mode::FixedBarrier;
  s.barrier = kappa;
  s.max_iter = max_iter;
  s.warm_start = true;
  return s;
}

const char* Settings::invalid() const {
  if (max_iter < 0 || active_set_max_iter < 0) return "max_iter and active_set_max_iter must be >= 0";
  static_assert(kMaxActiveSetBulk == 32, "the message below names the limit");
  if (active_set_bulk < 0 || active_set_bulk > kMaxActiveSetBulk) return "active_set_bulk must be in 0..32";
  if (!(tol > 0.0)) return "tol must be > 0";
  if (mode == Mode::FixedBarrier && !(barrier > 0.0)) return "barrier (kappa) must be > 0";
  if (!(time_limit_us >= 0.0)) return "time_limit_us must be >= 0";
  if (!(reg_min > 0.0 && reg_max >= reg_min)) return "need 0 < reg_min <= reg_max";
  if (!(step_to_boundary > 0.0 && step_to_boundary < 1.0 && step_to_boundary_late > 0.0 && step_to_boundary_late < 1.0 &&
        warm_step_to_boundary > 0.0 && warm_step_to_boundary < 1.0))
    return "step_to_boundary, step_to_boundary_late and warm_step_to_boundary must be in (0, 1)";
  if (!(corrector_band >= 1.0)) return "corrector_band must be >= 1";
  if (!(late_from_gap >= 0.0)) return "late_from_gap must be >= 0";
  if (max_correctors < 0 || max_refinements < 0 || stall_window < 1) return "counts must be >= 0 (stall_window >= 1)";
  if (!(certificate_reach > 0.0)) return "certificate_reach must be > 0";
  if (!(cold_complementarity > 0.0)) return "cold_complementarity must be > 0";
  if (!(cold_slack_floor > 0.0)) return "cold_slack_floor must be > 0";
  if (!(separate_steps_above >= 0.0)) return "separate_steps_above must be >= 0 (inf: never)";
  if (!(ls_beta > 0.0 && ls_beta < 1.0 && ls_alpha > 0.0 && ls_alpha < 0.5)) return "need 0 < ls_alpha < 0.5, 0 < ls_beta < 1";
  if (!(newton_to_boundary > 0.0 && newton_to_boundary < 1.0)) return "newton_to_boundary must be in (0, 1)";
  return nullptr;
}

}  // namespace rvd::solver
