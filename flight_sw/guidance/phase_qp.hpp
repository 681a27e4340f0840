// The three phase QPs of the dissertation as stage-wise OCP QPs (solver/ocp_qp.hpp):
//   rendezvous (eq 3.7), approach (eq 3.10), docking (eq 3.14), plus the 1-norm rendezvous (eq 2.10).
// Costs use the dissertation's ||e||_Q^2 = e'Qe, so the OCP's 1/2 e'Qe gets 2Q. Soft penalties
// lambda 1'(H rho)_+ are soft rows of the OCP QP (H rho <= 0 with linear penalty lambda), so every
// stage has the 3 physical inputs (delta-v) only, and stage N none.
// State constraints are put on stages 1..N: x_0 is the measurement, a constraint on it could only make
// the QP infeasible. A builder allocates once; build() refills values in place (no heap allocation).
#pragma once

#include <array>
#include <vector>

#include "flight_sw/guidance/params.hpp"
#include "flight_sw/guidance/target.hpp"
#include "flight_sw/solver/ocp_qp.hpp"

namespace rvd::guidance {

// Rotating keep-out hyperplanes (eqs 3.5-3.6): unit normals n_1..n_N that turn from the chaser's
// direction towards `axis` in equal steps, each step capped at `max_step_rad` (out of reach, towards the
// antipode of the axis, the turn leans towards the natural circulation's: guidance README).
struct KeepoutPlanes {
  Eigen::Vector3d rotation_axis = Eigen::Vector3d::UnitZ();  // n_{i+1} = Rot(rotation_axis, step) n_i
  double step_rad = 0.0;
  double total_rad = 0.0;   // angle still to go to reach the axis along the chosen way
  bool natural_way = false;  // true when the longer, natural-motion way was chosen
};
KeepoutPlanes plan_keepout_rotation(const Eigen::Vector3d& rho_m, const Eigen::Vector3d& axis, int N,
                                    double max_step_rad, KeepoutDirection direction);

class PhaseQp {
 public:
  // Inequality rows of one stage; -1 when the block is absent. Soft blocks (the cone penalty, the
  // 1-norm rows, and in the recovery variant every hard state row) are listed in the QP's idxs.
  struct StageLayout {
    int box_row = -1, keepout_row = -1, cone_row = -1, t_row = -1, w_row = -1, vel_row = -1, speed_row = -1;
    int stop_row = -1;      // docking: the soft stop plane through the set point (stages 1..N), -1 if none
    int entry_row = -1;     // first of the entry cone's 2 soft rows (stages 1..N), -1 if none
    int obstacle_row = -1;  // first of 2 x params.obstacle_capacity soft rows (stages 1..N), -1 if none
    int nu = 0, nc = 0, ns = 0;
  };
  StageLayout stage(int i) const;  // blocks follow a fixed order; each present block takes the next columns/rows

  // recovery = true builds the same QP with the hard state constraints (keep-out plane, overshoot plane,
  // docking cone and |v|_inf) made soft rows with penalty recovery_weight * e + recovery_quadratic * e^2
  // per row and metre (or m/s) of violation: the QP the guidance solves when the nominal one is infeasible.
  PhaseQp(Phase phase, const GuidanceParams& params, bool recovery = false);

  // The obstacles the next build() plans around (not owned; nullptr: none), the time t_s of the
  // build's x0 and the chaser positions the previous plan predicts for stages 0..N (N+1 entries; the
  // linearization points). Only used when params.obstacle_capacity > 0.
  void set_obstacles(const ObstacleSet* set, double t_s, const Eigen::Vector3d* predicted) {
    obstacles_ = set;
    obstacle_t_s_ = t_s;
    predicted_ = predicted;
  }

  // The holding radius the next build() plans with (params.holding_in(phase): holding.hpp); its rows are
  // linearized about the predicted positions given to set_obstacles.
  void set_holding_radius(double radius_m) { holding_radius_m_ = radius_m; }

  // Fill the QP for the chaser state x0 (LVLH) with the target as it is at the solve time; `quality`
  // says how well x0 and the thrusters are known (the margins and input bounds follow it).
  void build(const Vector6d& x0, const TargetState& target, const EstimateQuality& quality = {});

  Phase phase() const { return phase_; }
  int N() const { return N_; }
  double Ts_s() const { return Ts_; }
  double u_max_mps() const { return u_max_; }
  const solver::OcpQp& qp() const { return qp_; }
  const Vector6d& x0() const { return x0_; }  // the state of the last build
  const solver::OcpQpDims& dims() const { return qp_.dims; }
  const Matrix6d& A() const { return A_; }
  const Matrix63d& B() const { return B_; }
  const Matrix6d& terminal_weight() const { return Qf_; }  // dissertation units (cost e'Qf e)

  // Geometry of the last build (for tests and telemetry).
  const std::vector<Eigen::Vector3d>& keepout_normals() const { return keepout_normals_; }  // N+1, [0] unused
  double keepout_radius_used_m() const { return keepout_radius_used_; }
  const KeepoutPlanes& keepout_plan() const { return keepout_plan_; }
  const std::vector<Vector6d>& reference() const { return reference_; }  // set point / port track, N+1

  // Column and row layout, so tests can find the blocks they check.
  int keepout_row(int i) const;            // keep-out / overshoot row, -1 if none
  int cone_row(int i) const;               // first of the 4 cone rows (soft or hard), -1 if none
  int velocity_row(int i) const;           // first of the 6 |v|_inf rows (docking), -1 if none
  int stop_row(int i) const;               // the docking stop plane's soft row, -1 if none
  int obstacle_row(int i) const;           // first obstacle row, -1 if none
  int entry_row(int i) const;              // first of the entry cone's 2 rows, -1 if none
  bool entry_cone_active() const { return entry_active_; }  // in the last build
  bool recovery() const { return recovery_; }

 private:
  void build_rendezvous(const Vector6d& x0, const TargetState& target);
  void build_rendezvous_one_norm(const Vector6d& x0, const TargetState& target);
  void build_approach(const Vector6d& x0, const TargetState& target);
  void build_docking(const Vector6d& x0, const TargetState& target);
  double estimate_margin_m() const { return params_.margins.estimate_sigmas * quality_.position_m; }
  void fill_input_box(int stage);
  double braking_authority_mps(const Eigen::Vector3d& axis) const;
  double braking_curve_mps(double dv, double d) const;
  double slowdown_mps() const;
  void fill_keepout_braking(const Vector6d& x0);
  void fill_keepout(const Vector6d& x0, const TargetState& target);
  void fill_setpoints(const TargetState& target, double range_m);
  void fill_obstacles(const Vector6d& x0);
  void fill_holding_rows(const Vector6d& x0, double radius_m);
  void fill_entry_cone(const Vector6d& x0, const TargetState& target);
  void fill_holding_setpoints(const TargetState& target);
  double rendezvous_setpoint_range_m() const;

  Phase phase_;
  GuidanceParams params_;
  bool recovery_ = false;
  bool one_norm_ = false;
  bool cone_slacks_ = false;
  int N_ = 0;
  double Ts_ = 0.0, u_max_ = 0.0, n_ = 0.0;
  Matrix6d A_, Qw_, Qf_;
  Vector6d x0_ = Vector6d::Zero();
  Matrix63d B_;
  Eigen::Vector3d Rw_;
  solver::OcpQp qp_;
  std::vector<Eigen::Vector3d> keepout_normals_;
  std::vector<Vector6d> reference_;
  double keepout_radius_used_ = 0.0;
  KeepoutPlanes keepout_plan_;
  EstimateQuality quality_;  // of the last build's x0
  double centroid_s_ = 0.0;  // where the prediction puts each period's impulse
  const ObstacleSet* obstacles_ = nullptr;
  double obstacle_t_s_ = 0.0;
  const Eigen::Vector3d* predicted_ = nullptr;
  double holding_radius_m_ = 0.0;
  bool entry_active_ = false;
};

// Solution of the discrete algebraic Riccati equation P = Q + A'PA - A'PB (R + B'PB)^-1 B'PA
// (value iteration; used once per phase at construction for TerminalWeight::Dare).
Matrix6d solve_dare(const Matrix6d& A, const Matrix63d& B, const Matrix6d& Q, const Eigen::Matrix3d& R);

}  // namespace rvd::guidance
