// Three-phase MPC guidance for rendezvous and docking (dissertation ch. 3, Algorithm 1):
// navigation input -> phase logic -> phase QP build -> Fast MPC solve -> safe action -> thruster pulses.
// One PhaseQp and one FastMpcSolver per phase are allocated in the constructor; step() allocates nothing.
#pragma once

#include <Eigen/Dense>
#include <Eigen/Geometry>

#include <array>
#include <cstdint>
#include <limits>
#include <memory>
#include <vector>

#include "flight_sw/guidance/allocation.hpp"
#include "flight_sw/guidance/params.hpp"
#include "flight_sw/guidance/phase_qp.hpp"
#include "flight_sw/guidance/target.hpp"
#include "flight_sw/solver/fast_mpc.hpp"

namespace rvd::guidance {

enum class StepStatus : uint8_t {
  Ok = 0,            // the phase QP was solved; its first delta-v is commanded
  ShiftedPlan = 1,   // the QP gave no usable solution (solver.status says why): the previous plan's next delta-v
  ZeroThrust = 2,    // the same, and no previous plan is left: zero delta-v
  InvalidState = 3,  // the navigation input was rejected (NaN/Inf or absurd); `fallback` says what was commanded
  Docked = 4,        // the docking end condition holds: zero delta-v from now on
  Recovered = 5,     // the phase QP was infeasible; the recovery QP (hard state constraints made elastic)
                     // was solved and its first delta-v is commanded
};
const char* to_string(StepStatus s);

enum class Fallback : uint8_t { None = 0, ShiftedPlan = 1, ZeroThrust = 2 };

struct NavInput {
  uint32_t step = 0;
  double t_s = 0.0;
  Vector6d x_lvlh = Vector6d::Zero();  // chaser relative position [m] and velocity [m/s] in LVLH
  Eigen::Quaterniond q_lvlh_body = Eigen::Quaterniond::Identity();  // target attitude, LVLH <- body
  Eigen::Vector3d omega_body_rad_s = Eigen::Vector3d::Zero();       // target rate relative to LVLH, body axes
  EstimateQuality quality;  // of x_lvlh and of the thrusters (the navigation filter's): margins, allocation
  // The chaser's angle from its docking attitude (holding.hpp, docking_attitude_error_rad); NaN when its
  // attitude is not sensed: the holding radius then shrinks on the position condition alone.
  double chaser_attitude_error_rad = std::numeric_limits<double>::quiet_NaN();
};

struct Command {
  uint32_t step = 0;
  double t_s = 0.0;
  Phase phase = Phase::Rendezvous;  // the phase this command belongs to (after this step's switching)
  double period_s = 0.0;            // the phase's control period: the next navigation input comes then
  Eigen::Vector3d dv_cmd_mps = Eigen::Vector3d::Zero();    // commanded impulsive delta-v, LVLH
  Eigen::Vector3d dv_alloc_mps = Eigen::Vector3d::Zero();  // what the pulses are expected to realise
  Eigen::Vector3d dv_nominal_mps = Eigen::Vector3d::Zero();  // what they realise at nominal force
  std::array<double, 6> pulse_s{};  // thruster on-times, order +x, -x, +y, -y, +z, -z
  StepStatus status = StepStatus::ZeroThrust;
  Fallback fallback = Fallback::None;
  solver::Info solver;             // of this step's phase-QP solve (status InvalidInput, 0 iterations when none ran)
  solver::Info recovery;           // of the recovery-QP solve, when the phase QP was infeasible
  solver::Info lookahead;          // of the approach QP at the predicted entry (rendezvous steps; 0 iterations when none ran)
  bool solved = false;             // a QP was built and handed to the solver this step
  int plan_age = 0;                // periods since the QP whose input is commanded (0: this step's)
  double step_time_us = 0.0;       // whole step: checks, build, solve, allocation
  double range_m = 0.0;            // |rho|
  double port_distance_m = 0.0;    // distance to the docking port
};

// Whether a step's solver status says something: a QP went to the solver, or the step's time budget was
// spent before it could (TimeLimit). Otherwise no solve ran (the link's "not run", 255).
inline bool solver_status_reported(bool solved, solver::Status status) {
  return solved || status == solver::Status::TimeLimit;
}

// Called around every solver call of a step (the phase QP, and the recovery QP when it runs), for a
// caller that wants the solves alone bracketed (the flight executable brackets the whole law step).
class SolveObserver {
 public:
  virtual ~SolveObserver() = default;
  virtual void before_solve() = 0;
  virtual void after_solve() = 0;
};

class Guidance {
 public:
  explicit Guidance(const GuidanceParams& params);  // throws std::invalid_argument when params are unusable
  ~Guidance();

  // Not owned; nullptr (the default) observes nothing.
  void set_solve_observer(SolveObserver* observer) { observer_ = observer; }

  // One control period. time_limit_us > 0 is the wall-time budget of the whole step; the solve gets what
  // the checks and the QP build left of it, and a solve that runs out yields the shifted previous plan.
  Command step(const NavInput& nav, double time_limit_us = 0.0);

  // The obstacles sensed now (list[0..n), states at their own t_state_s): the nearest
  // params.obstacle_capacity of them are planned around from the next step on (obstacles.hpp), the
  // rest counted as dropped, unusable entries as rejected. Allocates nothing.
  void set_obstacles(const Obstacle* list, int n, double t_s, const Eigen::Vector3d& chaser_lvlh_m);
  const ObstacleSet& obstacles() const { return obstacles_; }
  const HoldingRadius& holding() const { return holding_; }  // the dynamic holding radius (holding.hpp)
  void count_dropped_obstacles(uint32_t n) { obstacles_.dropped_total += n; }  // left out before they got here

  Phase phase() const { return phase_; }
  const GuidanceParams& params() const { return params_; }
  const PhaseQp& phase_qp(Phase p, bool recovery = false) const;             // as last built
  const solver::FastMpcSolver& solver(Phase p, bool recovery = false) const;  // its last solve
  void reset(Phase start = Phase::Rendezvous);  // back to a phase, forgetting plans and warm starts

  // Phase-switching predicates of Algorithm 1 (public so that tests and the closed loop can report them).
  bool ready_for_approach(const Vector6d& x, const TargetState& target, const EstimateQuality& u = {}) const;
  bool ready_for_docking(const Vector6d& x, const TargetState& target, const EstimateQuality& u = {}) const;
  bool docked(const Vector6d& x, const TargetState& target) const;

 private:
  static int index(Phase p) { return p == Phase::Rendezvous ? 0 : p == Phase::Approach ? 1 : 2; }
  bool nav_plausible(const NavInput& nav) const;
  void fall_back(Command& cmd);
  // Build and solve one QP within what is left of the budget; on success keep its plan.
  bool solve_into_plan(PhaseQp& qp, solver::FastMpcSolver& sol, const Vector6d& x, const TargetState& target,
                       const EstimateQuality& u, double t_s, double budget_left_us, solver::Info& info);

  GuidanceParams params_;
  Phase phase_ = Phase::Rendezvous;
  std::array<std::unique_ptr<PhaseQp>, 3> qps_, recovery_qps_;
  std::array<std::unique_ptr<solver::FastMpcSolver>, 3> solvers_, recovery_solvers_;
  solver::Vector x0_;                  // the solver's x0 argument, sized once
  std::vector<Eigen::Vector3d> plan_;  // delta-v plan of the last accepted solve (capacity: longest N)
  int plan_len_ = 0, plan_next_ = 0;
  Phase plan_phase_ = Phase::Rendezvous;
  SolveObserver* observer_ = nullptr;
  ObstacleSet obstacles_;
  HoldingRadius holding_;
  std::vector<Eigen::Vector3d> predicted_;  // linearization points, stages 0..N (capacity: longest N + 1)
  void predict_positions(const PhaseQp& qp, const Vector6d& x);
  // After a rendezvous solve: iterations of the approach QP at the entry state its plan predicts.
  void look_ahead(const solver::FastMpcSolver& rendezvous, const TargetState& target, const EstimateQuality& quality,
                  double budget_left_us, bool carried, solver::Info& info);
  bool lookahead_warm_ = false;  // the approach solver holds this step's look-ahead iterate
  // The docking solver's rows were compressed in an earlier step (the docking QP built for the
  // target then, guidance.cpp): the first docking solve keeps them instead of compressing them itself.
  bool docking_rows_ready_ = false;
};

// The dissertation's scenarios (Table 3.2; sec 3.6): 1 V-bar, 2 R-bar, 3 rotating target (spin about body z).
struct ScenarioCase {
  Vector6d x0;
  Eigen::Quaterniond q_lvlh_body;
  Eigen::Vector3d omega_body_rad_s;
};
ScenarioCase dissertation_case(int number, double spin_deg_s = 0.15);

}  // namespace rvd::guidance
