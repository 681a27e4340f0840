// Python binding of the three-phase guidance: parameters, the Guidance step, the phase-QP builders
// (returned as the lists solve_ocp_qp takes) and the in-process closed loop against a CW plant.
// Quaternions cross the boundary as [w, x, y, z] (LVLH <- target body); units are SI.
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <sstream>
#include <stdexcept>
#include <string>

#include "flight_sw/guidance/closed_loop.hpp"
#include "flight_sw/guidance/guidance.hpp"

namespace py = pybind11;
using namespace rvd::guidance;
namespace solver = rvd::solver;

namespace {

Eigen::Quaterniond quat(const Eigen::Vector4d& wxyz) { return Eigen::Quaterniond(wxyz(0), wxyz(1), wxyz(2), wxyz(3)); }
Eigen::Vector4d wxyz(const Eigen::Quaterniond& q) { return Eigen::Vector4d(q.w(), q.x(), q.y(), q.z()); }

TargetState target_of(const Eigen::Vector4d& q_wxyz, const Eigen::Vector3d& omega) {
  TargetState t;
  const Eigen::Quaterniond q = quat(q_wxyz);
  if (!q.coeffs().allFinite() || q.norm() < 1e-9) throw py::value_error("q_lvlh_body must be a finite quaternion [w, x, y, z]");
  t.q_lvlh_body = q.normalized();
  t.omega_body_rad_s = omega;
  return t;
}

// A step's solver status by name; "not_run" where the flight link sends 255.
std::string solver_status_name(bool solved, solver::Status status) {
  return solver_status_reported(solved, status) ? solver::to_string(status) : "not_run";
}

py::dict qp_lists(const solver::OcpQp& qp, const Vector6d& x0) {
  py::list A, B, b, Q, q, R, r, C, D, d, idxs, zs, Zs;
  for (int i = 0; i <= qp.dims.N; ++i) {
    if (!qp.dims.ns.empty()) {
      idxs.append(py::cast(qp.idxs[i]));
      zs.append(py::cast(qp.zs[i]));
      Zs.append(py::cast(qp.Zs[i]));
    }
    if (i < qp.dims.N) {
      A.append(py::cast(qp.A[i]));
      B.append(py::cast(qp.B[i]));
      b.append(py::cast(qp.b[i]));
    }
    Q.append(py::cast(qp.Q[i]));
    q.append(py::cast(qp.q[i]));
    R.append(py::cast(qp.R[i]));
    r.append(py::cast(qp.r[i]));
    C.append(py::cast(qp.C[i]));
    D.append(py::cast(qp.D[i]));
    d.append(py::cast(qp.d[i]));
  }
  py::dict out;
  out["A"] = A; out["B"] = B; out["b"] = b; out["Q"] = Q; out["q"] = q; out["R"] = R; out["r"] = r;
  out["C"] = C; out["D"] = D; out["d"] = d;
  if (!qp.dims.ns.empty()) {  // soft rows: row indices, linear and quadratic penalties
    out["idxs"] = idxs; out["zs"] = zs; out["Zs"] = Zs;
  }
  out["x0"] = py::cast(Eigen::VectorXd(x0));
  return out;
}

Phase active_phase(Phase p) {
  if (p == Phase::Docked) throw py::value_error("no QP in phase Docked");
  return p;
}

void check_x(const Vector6d& x) {
  if (!x.allFinite()) throw py::value_error("x_lvlh must be 6 finite numbers [m, m/s]");
}

// Solver settings of a phase, exposed as plain attributes (mode as the solver binding's strings).
std::string mode_name(solver::Mode m) { return m == solver::Mode::Converged ? "converged" : "fixed_barrier"; }
solver::Mode mode_of(const std::string& s) {
  if (s == "converged") return solver::Mode::Converged;
  if (s == "fixed_barrier") return solver::Mode::FixedBarrier;
  throw py::value_error("solver_mode must be 'converged' or 'fixed_barrier', got '" + s + "'");
}

template <class T>
py::array_t<T> column(const std::vector<ClosedLoopStep>& log, T (*get)(const ClosedLoopStep&)) {
  py::array_t<T> a(static_cast<py::ssize_t>(log.size()));
  auto m = a.template mutable_unchecked<1>();
  for (size_t k = 0; k < log.size(); ++k) m(k) = get(log[k]);
  return a;
}

Eigen::MatrixXd rows(const std::vector<ClosedLoopStep>& log, int width, Eigen::VectorXd (*get)(const ClosedLoopStep&)) {
  Eigen::MatrixXd M(log.size(), width);
  for (size_t k = 0; k < log.size(); ++k) M.row(k) = get(log[k]).transpose();
  return M;
}

py::dict totals(const PhaseTotals& p) {
  py::dict d;
  d["dv_mps"] = p.dv_mps;
  d["dv_l1_mps"] = p.dv_l1_mps;
  d["time_s"] = p.time_s;
  d["steps"] = p.steps;
  return d;
}

}  // namespace

void bind_guidance(py::module_& m) {
  py::enum_<Phase>(m, "Phase")
      .value("Rendezvous", Phase::Rendezvous)
      .value("Approach", Phase::Approach)
      .value("Docking", Phase::Docking)
      .value("Docked", Phase::Docked);
  py::enum_<StepStatus>(m, "StepStatus")
      .value("Ok", StepStatus::Ok)
      .value("ShiftedPlan", StepStatus::ShiftedPlan)
      .value("ZeroThrust", StepStatus::ZeroThrust)
      .value("InvalidState", StepStatus::InvalidState)
      .value("Docked", StepStatus::Docked)
      .value("Recovered", StepStatus::Recovered);
  py::enum_<Fallback>(m, "Fallback")
      .value("None_", Fallback::None)
      .value("ShiftedPlan", Fallback::ShiftedPlan)
      .value("ZeroThrust", Fallback::ZeroThrust);
  py::enum_<TerminalWeight>(m, "TerminalWeight")
      .value("StageWeight", TerminalWeight::StageWeight)
      .value("Dare", TerminalWeight::Dare);
  py::enum_<RendezvousObjective>(m, "RendezvousObjective")
      .value("Quadratic", RendezvousObjective::Quadratic)
      .value("OneNorm", RendezvousObjective::OneNorm);
  py::enum_<RelativeMotion>(m, "RelativeMotion")
      .value("ClohessyWiltshire", RelativeMotion::ClohessyWiltshire)
      .value("DoubleIntegrator", RelativeMotion::DoubleIntegrator);
  py::enum_<KeepoutDirection>(m, "KeepoutDirection")
      .value("NaturalMotion", KeepoutDirection::NaturalMotion)
      .value("Shortest", KeepoutDirection::Shortest);

  py::enum_<ObstaclePrediction>(m, "ObstaclePrediction")
      .value("ConstantVelocity", ObstaclePrediction::ConstantVelocity)
      .value("NaturalMotion", ObstaclePrediction::NaturalMotion);
  py::enum_<ObstacleMethod>(m, "ObstacleMethod")
      .value("DirectLinearization", ObstacleMethod::DirectLinearization)
      .value("RotatingHyperplane", ObstacleMethod::RotatingHyperplane);
  m.attr("MAX_OBSTACLES") = kMaxObstacles;

  py::class_<Obstacle>(m, "Obstacle", "An ellipsoidal keep-out zone as the guidance is told it (LVLH, SI).")
      .def(py::init([](uint32_t id, const Eigen::Vector3d& r, const Eigen::Vector3d& v, const Eigen::Vector3d& axes,
                       const Eigen::Vector4d& q, double t_state_s, double t_seen_s) {
             Obstacle o;
             o.id = id;
             o.position_lvlh_m = r;
             o.velocity_lvlh_mps = v;
             o.semi_axes_m = axes;
             o.q_lvlh_body = quat(q);
             o.t_state_s = t_state_s;
             o.t_seen_s = t_seen_s;
             return o;
           }),
           py::arg("id"), py::arg("position_lvlh_m"), py::arg("velocity_lvlh_mps") = Eigen::Vector3d::Zero(),
           py::arg("semi_axes_m") = Eigen::Vector3d::Ones(), py::arg("q_lvlh_body") = Eigen::Vector4d(1, 0, 0, 0),
           py::arg("t_state_s") = 0.0, py::arg("t_seen_s") = 0.0)
      .def_readwrite("id", &Obstacle::id)
      .def_readwrite("position_lvlh_m", &Obstacle::position_lvlh_m)
      .def_readwrite("velocity_lvlh_mps", &Obstacle::velocity_lvlh_mps)
      .def_readwrite("semi_axes_m", &Obstacle::semi_axes_m)
      .def_readwrite("t_state_s", &Obstacle::t_state_s)
      .def_readwrite("t_seen_s", &Obstacle::t_seen_s);
  m.def(
      "linearize_obstacle",
      [](const Eigen::Vector3d& centre, const Eigen::Matrix3d& S, const Eigen::Vector3d& p) {
        const ObstacleRow r = linearize_obstacle(centre, S, p, Eigen::Vector3d::UnitX());
        return py::make_tuple(r.normal, r.bound_m);
      },
      py::arg("centre"), py::arg("S"), py::arg("p"),
      "the linearized keep-out row about p: (unit normal n, bound b) of n'r >= b");

  py::class_<ThrusterParams>(m, "ThrusterParams", "Six on/off thrusters on +-x, +-y, +-z of LVLH.")
      .def(py::init<>())
      .def_readwrite("mass_kg", &ThrusterParams::mass_kg)
      .def_readwrite("thrust_N", &ThrusterParams::thrust_N)
      .def_readwrite("min_impulse_bit_s", &ThrusterParams::min_impulse_bit_s);

  py::class_<PhaseParams>(m, "PhaseParams", "MPC parameters of one phase (dissertation Table 3.1).")
      .def(py::init<>())
      .def_readwrite("N", &PhaseParams::N, "prediction horizon [steps]")
      .def_readwrite("Ts_s", &PhaseParams::Ts_s, "control period [s]")
      .def_readwrite("Q_diag", &PhaseParams::Q_diag, "state weight diagonal (assign the whole array)")
      .def_readwrite("R_diag", &PhaseParams::R_diag, "delta-v weight diagonal (assign the whole array)")
      .def_readwrite("lambda_", &PhaseParams::lambda, "line-of-sight cone penalty weight")
      .def_readwrite("los_half_angle_deg", &PhaseParams::los_half_angle_deg)
      .def_readwrite("u_max_mps", &PhaseParams::u_max_mps, "|delta-v|_inf bound per period [m/s]")
      .def_readwrite("terminal_weight", &PhaseParams::terminal_weight)
      .def_property(
          "solver_mode", [](const PhaseParams& p) { return mode_name(p.solver.mode); },
          [](PhaseParams& p, const std::string& s) { p.solver.mode = mode_of(s); })
      .def_property(
          "solver_max_iter", [](const PhaseParams& p) { return p.solver.max_iter; },
          [](PhaseParams& p, int v) { p.solver.max_iter = v; })
      .def_property(
          "solver_tol", [](const PhaseParams& p) { return p.solver.tol; },
          [](PhaseParams& p, double v) { p.solver.tol = v; })
      .def_property(
          "solver_barrier", [](const PhaseParams& p) { return p.solver.barrier; },
          [](PhaseParams& p, double v) { p.solver.barrier = v; })
      .def_property(
          "solver_warm_start", [](const PhaseParams& p) { return p.solver.warm_start; },
          [](PhaseParams& p, bool v) { p.solver.warm_start = v; })
      .def_property(
          "solver_active_set_max_inputs", [](const PhaseParams& p) { return p.solver.active_set_max_inputs; },
          [](PhaseParams& p, int v) { p.solver.active_set_max_inputs = v; },
          "converged mode: the dual active-set method up to this many inputs (N nu), 0: the interior point")
      .def_property(
          "solver_active_set_bulk", [](const PhaseParams& p) { return p.solver.active_set_bulk; },
          [](PhaseParams& p, int v) {
            if (v < 0 || v > solver::Settings::kMaxActiveSetBulk)
              throw py::value_error("solver_active_set_bulk must be in 0.." + std::to_string(solver::Settings::kMaxActiveSetBulk));
            p.solver.active_set_bulk = v;
          },
          "cold active-set solves: violated rows that may join the most violated one per primal point (0: one at a time)")
      .def_property(
          "solver_cold_slack_floor", [](const PhaseParams& p) { return p.solver.cold_slack_floor; },
          [](PhaseParams& p, double v) {
            if (!(v > 0.0)) throw py::value_error("solver_cold_slack_floor must be > 0");
            p.solver.cold_slack_floor = v;
          },
          "the interior point's cold start: a hard row's least slack, in the row's units");

  py::class_<EstimateQuality>(m, "EstimateQuality", "How well the guidance knows its state and thrusters.")
      .def(py::init<>())
      .def_readwrite("position_m", &EstimateQuality::position_m, "1-sigma position error, worst axis")
      .def_readwrite("velocity_mps", &EstimateQuality::velocity_mps, "1-sigma velocity error, worst axis")
      .def_readwrite("thrust_scale", &EstimateQuality::thrust_scale, "relative force per thruster (+x, -x, ...)")
      .def_readwrite("thrust_scale_sigma", &EstimateQuality::thrust_scale_sigma, "its 1-sigma, worst thruster");

  py::class_<Margins>(m, "Margins", "Constraint tightening against the error model (README: Robustness margins).")
      .def(py::init<>())
      .def_readwrite("input_fraction", &Margins::input_fraction)
      .def_readwrite("plan_reserve_fraction", &Margins::plan_reserve_fraction)
      .def_readwrite("keepout_m", &Margins::keepout_m)
      .def_readwrite("overshoot_m", &Margins::overshoot_m)
      .def_readwrite("approach_cone_m", &Margins::approach_cone_m)
      .def_readwrite("docking_cone_m", &Margins::docking_cone_m)
      .def_readwrite("v_max_mps", &Margins::v_max_mps)
      .def_readwrite("rotating_cone_factor", &Margins::rotating_cone_factor)
      .def_readwrite("estimate_sigmas", &Margins::estimate_sigmas)
      .def_readwrite("approach_entry_brake_fraction", &Margins::approach_entry_brake_fraction)
      .def_readwrite("approach_speed_cap_mps", &Margins::approach_speed_cap_mps)
      .def_readwrite("approach_brake_fraction", &Margins::approach_brake_fraction)
      .def_readwrite("rendezvous_brake_fraction", &Margins::rendezvous_brake_fraction);

  py::class_<GuidanceParams>(m, "GuidanceParams",
                             "Every guidance parameter; defaults from dissertation Table 3.1 and "
                             "flight_sw/guidance/README.md. Nested phase parameters are edited in place: "
                             "p.rendezvous.N = 45.")
      .def(py::init<>())
      .def_readwrite("rendezvous", &GuidanceParams::rendezvous)
      .def_readwrite("approach", &GuidanceParams::approach)
      .def_readwrite("docking", &GuidanceParams::docking)
      .def_readwrite("orbit_altitude_m", &GuidanceParams::orbit_altitude_m)
      .def_readwrite("keepout_radius_m", &GuidanceParams::keepout_radius_m, "r1")
      .def_readwrite("approach_stop_m", &GuidanceParams::approach_stop_m, "r2 (overshoot plane)")
      .def_readwrite("dock_tolerance_m", &GuidanceParams::dock_tolerance_m, "r3 (distance to the port)")
      .def_readwrite("v_max_mps", &GuidanceParams::v_max_mps, "docking |v|_inf bound")
      .def_readwrite("dock_cone_tolerance_m", &GuidanceParams::dock_cone_tolerance_m)
      .def_readwrite("port_body_m", &GuidanceParams::port_body_m)
      .def_readwrite("rendezvous_objective", &GuidanceParams::rendezvous_objective)
      .def_readwrite("rendezvous_use_setpoint", &GuidanceParams::rendezvous_use_setpoint)
      .def_readwrite("rendezvous_setpoint_offset_m", &GuidanceParams::rendezvous_setpoint_offset_m)
      .def_readwrite("approach_setpoint_offset_m", &GuidanceParams::approach_setpoint_offset_m)
      .def_readwrite("docking_setpoint_offset_m", &GuidanceParams::docking_setpoint_offset_m,
                     "docking set point this far beyond the tightened docking cone's apex, inside r3")
      .def_readwrite("docking_stop_penalty", &GuidanceParams::docking_stop_penalty,
                     "penalty per metre past the docking stop plane through the set point (0: no plane)")
      .def_readwrite("rendezvous_switch_margin_m", &GuidanceParams::rendezvous_switch_margin_m)
      .def_readwrite("approach_switch_margin_m", &GuidanceParams::approach_switch_margin_m)
      .def_readwrite("keepout_rate_cap_factor", &GuidanceParams::keepout_rate_cap_factor)
      .def_readwrite("keepout_direction", &GuidanceParams::keepout_direction)
      .def_readwrite("thrusters", &GuidanceParams::thrusters)
      .def_readwrite("max_range_m", &GuidanceParams::max_range_m)
      .def_readwrite("max_speed_mps", &GuidanceParams::max_speed_mps)
      .def_readwrite("max_spin_rad_s", &GuidanceParams::max_spin_rad_s)
      .def_readwrite("recovery", &GuidanceParams::recovery)
      .def_readwrite("recovery_weight", &GuidanceParams::recovery_weight)
      .def_readwrite("recovery_quadratic", &GuidanceParams::recovery_quadratic)
      .def_readwrite("max_iter_accept_residual", &GuidanceParams::max_iter_accept_residual)
      .def_readwrite("approach_lookahead_steps", &GuidanceParams::approach_lookahead_steps)
      .def_readwrite("approach_lookahead_iterations", &GuidanceParams::approach_lookahead_iterations)
      .def_readwrite("obstacle_capacity", &GuidanceParams::obstacle_capacity, "0 or MAX_OBSTACLES")
      .def_readwrite("obstacle_margin_m", &GuidanceParams::obstacle_margin_m)
      .def_readwrite("obstacle_penalty", &GuidanceParams::obstacle_penalty)
      .def_readwrite("obstacle_penalty_quadratic", &GuidanceParams::obstacle_penalty_quadratic)
      .def_readwrite("obstacle_prediction", &GuidanceParams::obstacle_prediction)
      .def_readwrite("obstacle_method", &GuidanceParams::obstacle_method)
      .def_readwrite("hyperplane_rate_rad_s", &GuidanceParams::hyperplane_rate_rad_s)
      .def_readwrite("hyperplane_active_range_m", &GuidanceParams::hyperplane_active_range_m)
      .def_readwrite("relative_motion", &GuidanceParams::relative_motion)
      .def_readwrite("holding_radius_m", &GuidanceParams::holding_radius_m, "r_hold,0 (0: off)")
      .def_readwrite("holding_radius_min_m", &GuidanceParams::holding_radius_min_m)
      .def_readwrite("holding_shrink", &GuidanceParams::holding_shrink, "gamma")
      .def_readwrite("holding_tolerance_m", &GuidanceParams::holding_tolerance_m, "eta")
      .def_readwrite("holding_attitude_tolerance_deg", &GuidanceParams::holding_attitude_tolerance_deg, "epsilon")
      .def_readwrite("holding_phases", &GuidanceParams::holding_phases, "bit mask: 1 rendezvous, 2 approach")
      .def_readwrite("entry_cone_half_angle_deg", &GuidanceParams::entry_cone_half_angle_deg, "(0: off)")
      .def_readwrite("entry_cone_range_m", &GuidanceParams::entry_cone_range_m)
      .def_readwrite("entry_cone_penalty", &GuidanceParams::entry_cone_penalty)
      .def_readwrite("entry_cone_phases", &GuidanceParams::entry_cone_phases, "bit mask: 1 rendezvous, 2 approach, 4 docking")
      .def_readwrite("margins", &GuidanceParams::margins)
      .def_readwrite("finite_burns", &GuidanceParams::finite_burns)
      .def("mean_motion_rad_s", &GuidanceParams::mean_motion_rad_s)
      .def("validate", &GuidanceParams::validate, "empty string when usable, else what is wrong")
      .def("phase", py::overload_cast<Phase>(&GuidanceParams::phase), py::return_value_policy::reference_internal)
      .def("__copy__", [](const GuidanceParams& p) { return GuidanceParams(p); })
      .def("__deepcopy__", [](const GuidanceParams& p, py::dict) { return GuidanceParams(p); });

  py::class_<NavInput>(m, "NavInput")
      .def(py::init([](uint32_t step, double t_s, const Vector6d& x, const Eigen::Vector4d& q, const Eigen::Vector3d& w) {
             NavInput n;
             n.step = step;
             n.t_s = t_s;
             n.x_lvlh = x;
             n.q_lvlh_body = quat(q);  // not normalised here: the guidance judges it
             n.omega_body_rad_s = w;
             return n;
           }),
           py::arg("step"), py::arg("t_s"), py::arg("x_lvlh"), py::arg("q_lvlh_body") = Eigen::Vector4d(1, 0, 0, 0),
           py::arg("omega_body_rad_s") = Eigen::Vector3d::Zero())
      .def_readwrite("step", &NavInput::step)
      .def_readwrite("t_s", &NavInput::t_s)
      .def_readwrite("x_lvlh", &NavInput::x_lvlh)
      .def_property(
          "q_lvlh_body", [](const NavInput& n) { return wxyz(n.q_lvlh_body); },
          [](NavInput& n, const Eigen::Vector4d& q) { n.q_lvlh_body = quat(q); })
      .def_readwrite("omega_body_rad_s", &NavInput::omega_body_rad_s)
      .def_readwrite("quality", &NavInput::quality, "how well x_lvlh and the thrusters are known")
      .def_readwrite("chaser_attitude_error_rad", &NavInput::chaser_attitude_error_rad,
                     "the chaser's angle from its docking attitude (NaN: not sensed)");

  py::class_<Command>(m, "Command")
      .def_readonly("step", &Command::step)
      .def_readonly("t_s", &Command::t_s)
      .def_readonly("phase", &Command::phase)
      .def_readonly("period_s", &Command::period_s)
      .def_readonly("dv_cmd_mps", &Command::dv_cmd_mps)
      .def_readonly("dv_alloc_mps", &Command::dv_alloc_mps)
      .def_readonly("dv_nominal_mps", &Command::dv_nominal_mps)
      .def_property_readonly("pulse_s", [](const Command& c) { return Eigen::Matrix<double, 6, 1>(c.pulse_s.data()); })
      .def_readonly("status", &Command::status)
      .def_readonly("fallback", &Command::fallback)
      .def_readonly("solved", &Command::solved)
      .def_readonly("plan_age", &Command::plan_age)
      .def_readonly("step_time_us", &Command::step_time_us)
      .def_readonly("range_m", &Command::range_m)
      .def_readonly("port_distance_m", &Command::port_distance_m)
      .def_property_readonly("solver_status", [](const Command& c) { return solver_status_name(c.solved, c.solver.status); },
                             "the phase QP's solve, or 'not_run' (as the link's 255) when no QP went to the solver this step")
      .def_property_readonly("iterations", [](const Command& c) { return c.solver.iterations; })
      .def_property_readonly("solve_time_us", [](const Command& c) { return c.solver.solve_time_us; })
      .def_property_readonly("primal_residual", [](const Command& c) { return c.solver.primal_residual; })
      .def_property_readonly("objective", [](const Command& c) { return c.solver.objective; })
      .def_property_readonly("recovery_status", [](const Command& c) { return std::string(solver::to_string(c.recovery.status)); })
      .def_property_readonly("recovery_iterations", [](const Command& c) { return c.recovery.iterations; })
      .def_property_readonly("lookahead_status", [](const Command& c) { return std::string(solver::to_string(c.lookahead.status)); })
      .def_property_readonly("lookahead_iterations", [](const Command& c) { return c.lookahead.iterations; })
      .def_property_readonly("active_set_changes", [](const Command& c) { return c.solver.active_set_changes; })
      .def_property_readonly("rows_compressed", [](const Command& c) { return c.solver.rows_compressed; })
      .def_property_readonly("lookahead_active_set_changes", [](const Command& c) { return c.lookahead.active_set_changes; })
      .def("__repr__", [](const Command& c) {
        std::ostringstream s;
        s << "Command(step=" << c.step << ", phase=" << to_string(c.phase) << ", status=" << to_string(c.status)
          << ", dv_cmd=[" << c.dv_cmd_mps.transpose() << "])";
        return s.str();
      });

  py::class_<Guidance>(m, "Guidance", "Three-phase MPC guidance (dissertation Algorithm 1).")
      .def(py::init([](const GuidanceParams& p) {
             try {
               return new Guidance(p);
             } catch (const std::invalid_argument& e) {
               throw py::value_error(e.what());
             }
           }),
           py::arg("params"))
      .def("step", &Guidance::step, py::arg("nav"), py::arg("time_limit_us") = 0.0,
           py::call_guard<py::gil_scoped_release>())
      .def_property_readonly("phase", &Guidance::phase)
      .def(
          "set_obstacles",
          [](Guidance& g, const std::vector<Obstacle>& list, double t_s, const Eigen::Vector3d& chaser) {
            g.set_obstacles(list.data(), static_cast<int>(list.size()), t_s, chaser);
          },
          py::arg("obstacles"), py::arg("t_s"), py::arg("chaser_lvlh_m"))
      .def_property_readonly("held_obstacle_ids",
                             [](const Guidance& g) {
                               std::vector<uint32_t> ids;
                               for (int k = 0; k < g.obstacles().count; ++k) ids.push_back(g.obstacles().items[k].id);
                               return ids;
                             })
      .def_property_readonly("obstacles_dropped", [](const Guidance& g) { return g.obstacles().dropped_total; })
      .def_property_readonly("holding_radius_m", [](const Guidance& g) { return g.holding().radius(); },
                             "the holding radius the last step planned with")
      .def_property_readonly("holding_shrinks", [](const Guidance& g) { return g.holding().shrinks(); })
      .def_property_readonly("obstacles_rejected", [](const Guidance& g) { return g.obstacles().rejected_total; })
      .def("reset", &Guidance::reset, py::arg("start") = Phase::Rendezvous)
      .def(
          "last_qp",
          [](const Guidance& g, Phase p, bool recovery) {
            const PhaseQp& b = g.phase_qp(active_phase(p), recovery);
            return qp_lists(b.qp(), b.x0());
          },
          py::arg("phase"), py::arg("recovery") = false,
          "the phase's QP (or its recovery QP) as last built, as solve_ocp_qp's arguments")
      .def(
          "last_solution_u",
          [](const Guidance& g, Phase p) { return g.solver(active_phase(p)).u(); }, py::arg("phase"),
          "the delta-v inputs [m/s] per stage of the phase solver's last solve, as it answered (its warm start "
          "shifts a copy of its own)");

  py::class_<PhaseQp>(m, "PhaseQp", "Builder of one phase QP (allocates once; build() refills).")
      .def(py::init([](Phase phase, const GuidanceParams& p, bool recovery) {
             const std::string err = p.validate();
             if (!err.empty()) throw py::value_error("GuidanceParams: " + err);
             return new PhaseQp(active_phase(phase), p, recovery);
           }),
           py::arg("phase"), py::arg("params"), py::arg("recovery") = false)
      .def(
          "build",
          [](PhaseQp& b, const Vector6d& x, const Eigen::Vector4d& q, const Eigen::Vector3d& w) {
            check_x(x);
            b.build(x, target_of(q, w));
            return qp_lists(b.qp(), x);
          },
          py::arg("x_lvlh"), py::arg("q_lvlh_body") = Eigen::Vector4d(1, 0, 0, 0),
          py::arg("omega_body_rad_s") = Eigen::Vector3d::Zero(), "build and return solve_ocp_qp's arguments")
      .def_property_readonly("N", &PhaseQp::N)
      .def_property_readonly("Ts_s", &PhaseQp::Ts_s)
      .def_property_readonly("u_max_mps", &PhaseQp::u_max_mps)
      .def_property_readonly("nu", [](const PhaseQp& b) { return b.dims().nu; })
      .def_property_readonly("nc", [](const PhaseQp& b) { return b.dims().nc; })
      .def_property_readonly("terminal_weight", &PhaseQp::terminal_weight, "Q_f in the dissertation's units")
      .def_property_readonly("keepout_normals", &PhaseQp::keepout_normals,
                             "N+1 unit normals of the last build ([0] is the chaser's direction)")
      .def_property_readonly("keepout_radius_used_m", &PhaseQp::keepout_radius_used_m)
      .def_property_readonly("keepout_step_rad", [](const PhaseQp& b) { return b.keepout_plan().step_rad; })
      .def_property_readonly("keepout_total_rad", [](const PhaseQp& b) { return b.keepout_plan().total_rad; })
      .def_property_readonly("keepout_rotation_axis", [](const PhaseQp& b) { return b.keepout_plan().rotation_axis; })
      .def_property_readonly("keepout_natural_way", [](const PhaseQp& b) { return b.keepout_plan().natural_way; })
      .def_property_readonly("reference", &PhaseQp::reference, "set point / port track per stage, N+1 x 6")
      .def("keepout_row", &PhaseQp::keepout_row, py::arg("stage"))
      .def("cone_row", &PhaseQp::cone_row, py::arg("stage"))
      .def("velocity_row", &PhaseQp::velocity_row, py::arg("stage"))
      .def("stop_row", &PhaseQp::stop_row, py::arg("stage"))
      .def("entry_row", &PhaseQp::entry_row, py::arg("stage"))
      .def("set_holding_radius", &PhaseQp::set_holding_radius, py::arg("radius_m"))
      .def_property_readonly("entry_cone_active", &PhaseQp::entry_cone_active);

  m.def(
      "build_phase_qp",
      [](const GuidanceParams& p, Phase phase, const Vector6d& x, const Eigen::Vector4d& q, const Eigen::Vector3d& w) {
        const std::string err = p.validate();
        if (!err.empty()) throw py::value_error("GuidanceParams: " + err);
        check_x(x);
        PhaseQp b(active_phase(phase), p);
        b.build(x, target_of(q, w));
        return qp_lists(b.qp(), x);
      },
      py::arg("params"), py::arg("phase"), py::arg("x_lvlh"), py::arg("q_lvlh_body") = Eigen::Vector4d(1, 0, 0, 0),
      py::arg("omega_body_rad_s") = Eigen::Vector3d::Zero(),
      "The phase QP for this chaser state and target attitude/rate, as a dict of solve_ocp_qp's arguments "
      "(A, B, b, Q, q, R, r, C, D, d, x0): flight_sw.solve_ocp_qp(**qp).");

  py::class_<ClosedLoopResult>(m, "ClosedLoopResult")
      .def_readonly("docked", &ClosedLoopResult::docked)
      .def_readonly("reason", &ClosedLoopResult::reason)
      .def_readonly("t_final_s", &ClosedLoopResult::t_final_s)
      .def_property_readonly("steps", [](const ClosedLoopResult& r) { return r.log.size(); })
      .def_property_readonly("t_s", [](const ClosedLoopResult& r) { return column<double>(r.log, [](const ClosedLoopStep& s) { return s.t_s; }); })
      .def_property_readonly("x", [](const ClosedLoopResult& r) { return rows(r.log, 6, [](const ClosedLoopStep& s) { return Eigen::VectorXd(s.x); }); })
      .def_property_readonly("q_lvlh_body", [](const ClosedLoopResult& r) { return rows(r.log, 4, [](const ClosedLoopStep& s) { return Eigen::VectorXd(wxyz(s.q_lvlh_body)); }); })
      .def_property_readonly("phase", [](const ClosedLoopResult& r) { return column<int>(r.log, [](const ClosedLoopStep& s) { return static_cast<int>(s.phase); }); })
      .def_property_readonly("period_s", [](const ClosedLoopResult& r) { return column<double>(r.log, [](const ClosedLoopStep& s) { return s.period_s; }); })
      .def_property_readonly("dv_cmd_mps", [](const ClosedLoopResult& r) { return rows(r.log, 3, [](const ClosedLoopStep& s) { return Eigen::VectorXd(s.dv_cmd_mps); }); })
      .def_property_readonly("dv_alloc_mps", [](const ClosedLoopResult& r) { return rows(r.log, 3, [](const ClosedLoopStep& s) { return Eigen::VectorXd(s.dv_alloc_mps); }); })
      .def_property_readonly("status", [](const ClosedLoopResult& r) { return column<int>(r.log, [](const ClosedLoopStep& s) { return static_cast<int>(s.status); }); })
      .def_property_readonly("solver_status", [](const ClosedLoopResult& r) {
        std::vector<std::string> v;
        for (const auto& s : r.log) v.push_back(solver_status_name(s.solved, s.solver_status));
        return v;
      })
      .def_property_readonly("iterations", [](const ClosedLoopResult& r) { return column<int>(r.log, [](const ClosedLoopStep& s) { return s.iterations; }); })
      .def_property_readonly("active_set_changes", [](const ClosedLoopResult& r) { return column<int>(r.log, [](const ClosedLoopStep& s) { return s.active_set_changes; }); })
      .def_property_readonly("solve_time_us", [](const ClosedLoopResult& r) { return column<double>(r.log, [](const ClosedLoopStep& s) { return s.solve_time_us; }); })
      .def_property_readonly("step_time_us", [](const ClosedLoopResult& r) { return column<double>(r.log, [](const ClosedLoopStep& s) { return s.step_time_us; }); })
      .def_property_readonly("phases", [](const ClosedLoopResult& r) {
        py::dict d;
        d["rendezvous"] = totals(r.phases[0]);
        d["approach"] = totals(r.phases[1]);
        d["docking"] = totals(r.phases[2]);
        return d;
      }, "delta-v (sum of |dv_alloc|_2 and _1) and time per phase")
      .def_property_readonly("total", [](const ClosedLoopResult& r) { return totals(r.total); })
      .def_readonly("min_range_outside_cone_m", &ClosedLoopResult::min_range_outside_cone_m)
      .def_readonly("keepout_violations", &ClosedLoopResult::keepout_violations)
      .def_readonly("max_approach_cone_violation_m", &ClosedLoopResult::max_approach_cone_violation_m)
      .def_readonly("max_docking_cone_violation_m", &ClosedLoopResult::max_docking_cone_violation_m)
      .def_readonly("max_u_inf_ratio", &ClosedLoopResult::max_u_inf_ratio)
      .def_readonly("max_docking_speed_inf_mps", &ClosedLoopResult::max_docking_speed_inf_mps)
      .def_readonly("fallbacks", &ClosedLoopResult::fallbacks)
      .def_readonly("recoveries", &ClosedLoopResult::recoveries)
      .def_readonly("final_port_distance_m", &ClosedLoopResult::final_port_distance_m)
      .def_readonly("final_closing_speed_mps", &ClosedLoopResult::final_closing_speed_mps)
      .def_property_readonly("qps", [](const ClosedLoopResult& r) {
        py::list out;
        for (const RecordedQp& q : r.qps) {
          py::dict d;
          d["step"] = q.step;
          d["phase"] = q.phase;
          d["status"] = std::string(solver::to_string(q.status));
          d["u0"] = q.u0;
          d["qp"] = qp_lists(q.qp, q.x0);
          out.append(d);
        }
        return out;
      }, "every QP solved (when record_qps=True): step, phase, solver status, first delta-v, qp (solve_ocp_qp's arguments)");

  m.def(
      "run_closed_loop",
      [](const GuidanceParams& p, const Vector6d& x0, const Eigen::Vector4d& q0, const Eigen::Vector3d& w,
         double timeout_s, bool record_qps, double time_limit_us) {
        const std::string err = p.validate();
        if (!err.empty()) throw py::value_error("GuidanceParams: " + err);
        check_x(x0);
        const TargetState t = target_of(q0, w);
        py::gil_scoped_release release;
        return run_closed_loop(p, x0, t.q_lvlh_body, w, timeout_s, record_qps, time_limit_us);
      },
      py::arg("params"), py::arg("x0"), py::arg("q_lvlh_body") = Eigen::Vector4d(1, 0, 0, 0),
      py::arg("omega_body_rad_s") = Eigen::Vector3d::Zero(), py::arg("timeout_s") = 200.0 * 60.0,
      py::arg("record_qps") = false, py::arg("time_limit_us") = 0.0,
      "Closed loop against the impulsive CW plant x+ = Phi(Ts)(x + [0; dv_alloc]) until docked or timeout.");

  m.def(
      "dissertation_case",
      [](int k, double spin_deg_s) {
        const ScenarioCase c = dissertation_case(k, spin_deg_s);
        py::dict d;
        d["x0"] = c.x0;
        d["q_lvlh_body"] = wxyz(c.q_lvlh_body);
        d["omega_body_rad_s"] = c.omega_body_rad_s;
        return d;
      },
      py::arg("number"), py::arg("spin_deg_s") = 0.15,
      "Cases 1 (V-bar), 2 (R-bar), 3 (rotating) of the dissertation: x0, q_lvlh_body [w,x,y,z], omega_body_rad_s");

  m.def("mean_motion_rad_s", [](double alt) { return mean_motion_rad_s(alt); }, py::arg("altitude_m"));
  m.def("cw_stm", &cw_stm, py::arg("n_rad_s"), py::arg("t_s"), "closed-form CW state transition matrix");
  m.def("cw_system_matrix", &cw_system_matrix, py::arg("n_rad_s"));
  m.def(
      "allocate_thrusters",
      [](const Eigen::Vector3d& dv, double max_pulse, const ThrusterParams& thr) {
        const Allocation a = allocate_thrusters(dv, max_pulse, thr);
        return py::make_tuple(Eigen::Matrix<double, 6, 1>(a.pulse_s.data()), a.dv_alloc_mps);
      },
      py::arg("dv_cmd_mps"), py::arg("max_pulse_s"), py::arg("thrusters") = ThrusterParams(),
      "(pulse_s for +x,-x,+y,-y,+z,-z; realised dv) for a commanded LVLH delta-v");
  m.def(
      "holding_position",
      [](const Eigen::Vector4d& q, const Eigen::Vector3d& port, double r) { return holding_position(quat(q).normalized(), port, r); },
      py::arg("q_lvlh_body"), py::arg("port_body_m"), py::arg("radius_m"),
      "the holding position on the sphere of radius_m in front of the port (eq. 9)");
  m.def(
      "entry_cone",
      [](const Eigen::Vector4d& q, const Eigen::Vector3d& port, double a) {
        const EntryCone c = entry_cone(quat(q).normalized(), port, a);
        return py::make_tuple(Eigen::MatrixXd(c.rows), Eigen::VectorXd(c.bounds));
      },
      py::arg("q_lvlh_body"), py::arg("port_body_m"), py::arg("half_angle_rad"),
      "(rows 2x3, bounds 2) of the entry cone rows . rho <= bounds (eq. 10)");
  m.def("max_pulse_s", &max_pulse_s, py::arg("u_max_mps"), py::arg("thrusters") = ThrusterParams());
  m.def(
      "pyramid_rows_lvlh", [](const Eigen::Vector4d& q, double a) { return pyramid_rows_lvlh(quat(q).normalized(), a); },
      py::arg("q_lvlh_body"), py::arg("half_angle_rad"));
}
