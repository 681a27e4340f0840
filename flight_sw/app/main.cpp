// rvd_flight_sw: the flight software executable (native, or cross-built and run under QEMU).
//
//   RVD_LINK_KEY=<64 hex digits> rvd_flight_sw --connect tcp/127.0.0.1:7447 --run RUN_ID [options]
//
// Exit codes: 0 bye from the host or SIGTERM/SIGINT, 2 bad arguments (or no link key), 3 host lost
// (link down for --host-loss-timeout-s), 4 idle timeout, 5 never connected.
//
// Built a second time as rvd_flight_sw_faulty (RVD_FAULTY_BUILD, test builds only) with --fault,
// which corrupts the commands it sends, so that tests can check the host refuses them.
#include <atomic>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

#include "flight_sw/app/flight_app.hpp"
#include "flight_sw/include/rvd_guidance.h"
#include "flight_sw/nav/margins.hpp"

namespace {

std::atomic<bool> g_stop{false};
extern "C" void on_signal(int) { g_stop.store(true); }

using rvd::guidance::GuidanceParams;
using rvd::guidance::PhaseParams;

const char* kUsage = R"(usage: rvd_flight_sw --run RUN_ID [options]

The run's link key (64 hex digits) comes from $RVD_LINK_KEY or --key-file, never the command line.

Link
  --connect ENDPOINT        Zenoh endpoint of the host simulator (default tcp/127.0.0.1:7447;
                            under QEMU system mode the host is tcp/10.0.2.2:PORT, or
                            semihosting/DIR: host FIFOs, see rvd_pil/qemu/semihosting_link.py)
  --run RUN_ID              the run id: 1-64 characters from A-Z a-z 0-9 _ -
  --key-file PATH           read the link key from PATH (mode 0600, ours), or from a host file
                            through semihosting with semihosting/PATH (QEMU system mode)
  --lease-ms MS             lease announced to the host (default 20000)
  --host-loss-timeout-s S   exit when the link to the host stays down this long (default 4; with
                            a reconnect attempt in progress the exit comes at most 6 s later)
  --idle-timeout-s S        exit when no nav arrives for this long (default 300)
  --connect-timeout-s S     exit when the first connection does not come up (default 60)
  --untimed-link            wait for the host without time limits (QEMU system mode with
                            -icount sleep=off: the guest clock stands still while it waits, so a
                            timeout would fire at once); idle and connect timeouts are off too
  --telemetry-every K       steps between telemetry messages (default 20)
  --session-seed N          fix the ZenohID and initial sequence numbers (reproducibility checks
                            only: every byte the flight software sends then repeats run to run)
Guidance
  --horizon R,A,D           prediction horizons of rendezvous, approach, docking (default 30,15,12)
  --period R,A,D            control periods [s] (default 30,20,5)
  --solver MODE             converged | fixed_barrier (all phases)
  --max-iter N              solver iteration cap (all phases)
  --tol X                   solver tolerance (converged mode)
  --barrier K               barrier weight (fixed_barrier mode)
  --deadline-fraction F     solve budget = F x Ts of the phase, on the flight clock (default 0.5)
  --target-clock CPI,HZ     the flight clock: target time = instructions x CPI / HZ, the instructions
                            counted by the QEMU plugin (user mode), for every deadline and every
                            step and solve time; without it, or when no plugin answers (said so on
                            stderr and in hello/telemetry), this computer's steady_clock. The link's
                            timeouts stay on this computer's clock (they wait for the host).
  --set NAME=VALUE          any guidance or vehicle parameter (--list-params shows them with
                            their values; vectors comma-separated, choices by name); a plug-in
                            law's own parameters as --set law.NAME=VALUE
Error model (navigation filter and robustness margins)
  --nav-sigma P,V           measurement noise, 1 sigma per LVLH axis [m, m/s] (default 0,0:
                            noise-free sensors, the filter passes measurements through)
  --thrust-error-sigma S    1-sigma thrust amplitude error, fraction of the delta-v (default 0)
  --finite-burns on|off     thrusters burn for a finite time (default off: impulsive)
  --nav-filter on|off       Kalman filter between the measurements and the guidance (default on)
  --obstacles on|off|hyperplane
                            plan around the obstacles the host reports (on: direct linearization,
                            hyperplane: rotating hyperplanes; default off: obstacle messages are
                            counted only, the QPs are the obstacle-free ones)
  --margins auto|off        constraint margins derived from the error model (default auto),
                            or none (the nominal MPC); --set margins.*=... overrides one
  --trivial                 answer every nav with zero thrust at once (link latency benchmark)
Reporting
  --cpu-model NAME          CPU model reported in hello (default: the build's -mcpu)
  --markers on|off|auto     QEMU instruction-count markers around each solve (default auto: on for ARM)
  --pmu-instructions        count each solve's user-mode instructions with the CPU's PMU
                            (QEMU system mode; the plugin's markers count in user mode)
  --list-params             print the guidance parameters and exit
  -v, --verbose             log to stderr
)";

std::vector<double> split_numbers(const std::string& s, size_t expect, const char* what) {
  std::vector<double> out;
  size_t pos = 0;
  while (pos <= s.size()) {
    const size_t comma = s.find(',', pos);
    const std::string item = s.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos);
    char* end = nullptr;
    const double v = std::strtod(item.c_str(), &end);
    if (item.empty() || end == item.c_str() || *end != '\0') throw std::invalid_argument(std::string(what) + ": not a number: '" + item + "'");
    out.push_back(v);
    if (comma == std::string::npos) break;
    pos = comma + 1;
  }
  if (out.size() != expect)
    throw std::invalid_argument(std::string(what) + ": expected " + std::to_string(expect) + " comma-separated values");
  return out;
}

double parse_double(const std::string& s, const std::string& what) {
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  if (s.empty() || *end != '\0') throw std::invalid_argument(what + ": not a number: '" + s + "'");
  return v;
}

using AppConfig = rvd::app::AppConfig;

// A named parameter for --set: read and written as text (a number, a comma-separated vector, or a
// name for a choice), so that vectors (Q, R) and choices (terminal weight, objective) are settable too.
struct Param {
  std::function<std::string(const AppConfig&)> get;
  std::function<void(AppConfig&, const std::string&)> set;
};

std::string format_number(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}


Param scalar(std::function<double&(AppConfig&)> ref) {
  return {[ref](const AppConfig& c) { return format_number(ref(const_cast<AppConfig&>(c))); },
          [ref](AppConfig& c, const std::string& v) { ref(c) = parse_double(v, "value"); }};
}

template <int N, class Vec>
Param vector_param(std::function<Vec&(AppConfig&)> ref) {
  return {[ref](const AppConfig& c) {
            const Vec& v = ref(const_cast<AppConfig&>(c));
            std::string out;
            for (int i = 0; i < N; ++i) out += (i ? "," : "") + format_number(v(i));
            return out;
          },
          [ref](AppConfig& c, const std::string& text) {
            const auto v = split_numbers(text, N, "value");
            for (int i = 0; i < N; ++i) ref(c)(i) = v[i];
          }};
}

Param integer(std::function<int&(AppConfig&)> ref) {
  return {[ref](const AppConfig& c) { return std::to_string(ref(const_cast<AppConfig&>(c))); },
          [ref](AppConfig& c, const std::string& v) {
            const double d = parse_double(v, "value");
            if (d != std::floor(d) || std::abs(d) > 1e6) throw std::invalid_argument("not an integer: '" + v + "'");
            ref(c) = static_cast<int>(d);
          }};
}

// A choice among names (also accepted: the index).
template <class T>
Param choice(std::function<T&(AppConfig&)> ref, std::vector<std::string> names) {
  return {[ref, names](const AppConfig& c) { return names.at(static_cast<size_t>(ref(const_cast<AppConfig&>(c)))); },
          [ref, names](AppConfig& c, const std::string& v) {
            for (size_t i = 0; i < names.size(); ++i)
              if (v == names[i] || v == std::to_string(i)) {
                ref(c) = static_cast<T>(i);
                return;
              }
            std::string all;
            for (const auto& n : names) all += (all.empty() ? "" : ", ") + n;
            throw std::invalid_argument("'" + v + "' is not one of " + all);
          }};
}

Param flag(std::function<bool&(AppConfig&)> ref) {
  return {[ref](const AppConfig& c) { return std::string(ref(const_cast<AppConfig&>(c)) ? "on" : "off"); },
          [ref](AppConfig& c, const std::string& v) {
            if (v == "on" || v == "1" || v == "true") ref(c) = true;
            else if (v == "off" || v == "0" || v == "false") ref(c) = false;
            else throw std::invalid_argument("on or off, got '" + v + "'");
          }};
}

// Named parameters for --set: every guidance, vehicle and filter setting a user may want to sweep.
std::map<std::string, Param> named_params() {
  std::map<std::string, Param> m;
  auto d = [&m](const std::string& name, std::function<double&(AppConfig&)> ref) { m[name] = scalar(std::move(ref)); };
  d("orbit_altitude_m", [](AppConfig& c) -> double& { return c.guidance.orbit_altitude_m; });
  d("keepout_radius_m", [](AppConfig& c) -> double& { return c.guidance.keepout_radius_m; });
  d("approach_stop_m", [](AppConfig& c) -> double& { return c.guidance.approach_stop_m; });
  d("dock_tolerance_m", [](AppConfig& c) -> double& { return c.guidance.dock_tolerance_m; });
  d("dock_cone_tolerance_m", [](AppConfig& c) -> double& { return c.guidance.dock_cone_tolerance_m; });
  d("v_max_mps", [](AppConfig& c) -> double& { return c.guidance.v_max_mps; });
  d("rendezvous_setpoint_offset_m", [](AppConfig& c) -> double& { return c.guidance.rendezvous_setpoint_offset_m; });
  d("approach_setpoint_offset_m", [](AppConfig& c) -> double& { return c.guidance.approach_setpoint_offset_m; });
  d("docking_setpoint_offset_m", [](AppConfig& c) -> double& { return c.guidance.docking_setpoint_offset_m; });
  d("docking_stop_penalty", [](AppConfig& c) -> double& { return c.guidance.docking_stop_penalty; });
  d("rendezvous_switch_margin_m", [](AppConfig& c) -> double& { return c.guidance.rendezvous_switch_margin_m; });
  d("approach_switch_margin_m", [](AppConfig& c) -> double& { return c.guidance.approach_switch_margin_m; });
  d("obstacle_margin_m", [](AppConfig& c) -> double& { return c.guidance.obstacle_margin_m; });
  d("obstacle_penalty", [](AppConfig& c) -> double& { return c.guidance.obstacle_penalty; });
  d("obstacle_penalty_quadratic", [](AppConfig& c) -> double& { return c.guidance.obstacle_penalty_quadratic; });
  d("hyperplane_rate_rad_s", [](AppConfig& c) -> double& { return c.guidance.hyperplane_rate_rad_s; });
  d("hyperplane_active_range_m", [](AppConfig& c) -> double& { return c.guidance.hyperplane_active_range_m; });
  d("keepout_rate_cap_factor", [](AppConfig& c) -> double& { return c.guidance.keepout_rate_cap_factor; });
  m["obstacle_method"] = choice<rvd::guidance::ObstacleMethod>(
      [](AppConfig& c) -> rvd::guidance::ObstacleMethod& { return c.guidance.obstacle_method; },
      {"direct_linearization", "rotating_hyperplane"});
  m["obstacle_prediction"] = choice<rvd::guidance::ObstaclePrediction>(
      [](AppConfig& c) -> rvd::guidance::ObstaclePrediction& { return c.guidance.obstacle_prediction; },
      {"constant_velocity", "natural_motion"});
  m["relative_motion"] = choice<rvd::guidance::RelativeMotion>(
      [](AppConfig& c) -> rvd::guidance::RelativeMotion& { return c.guidance.relative_motion; },
      {"clohessy_wiltshire", "double_integrator"});
  d("holding_radius_m", [](AppConfig& c) -> double& { return c.guidance.holding_radius_m; });
  d("holding_radius_min_m", [](AppConfig& c) -> double& { return c.guidance.holding_radius_min_m; });
  d("holding_shrink", [](AppConfig& c) -> double& { return c.guidance.holding_shrink; });
  d("holding_tolerance_m", [](AppConfig& c) -> double& { return c.guidance.holding_tolerance_m; });
  d("holding_attitude_tolerance_deg", [](AppConfig& c) -> double& { return c.guidance.holding_attitude_tolerance_deg; });
  m["holding_phases"] = integer([](AppConfig& c) -> int& { return c.guidance.holding_phases; });
  d("entry_cone_half_angle_deg", [](AppConfig& c) -> double& { return c.guidance.entry_cone_half_angle_deg; });
  d("entry_cone_range_m", [](AppConfig& c) -> double& { return c.guidance.entry_cone_range_m; });
  d("entry_cone_penalty", [](AppConfig& c) -> double& { return c.guidance.entry_cone_penalty; });
  m["entry_cone_phases"] = integer([](AppConfig& c) -> int& { return c.guidance.entry_cone_phases; });
  d("attitude.inertia_kgm2", [](AppConfig& c) -> double& { return c.guidance.attitude.inertia_kgm2; });
  d("attitude.torque_max_nm", [](AppConfig& c) -> double& { return c.guidance.attitude.torque_max_nm; });
  d("attitude.Q_angle", [](AppConfig& c) -> double& { return c.guidance.attitude.Q_angle; });
  d("attitude.Q_rate", [](AppConfig& c) -> double& { return c.guidance.attitude.Q_rate; });
  d("attitude.R_torque", [](AppConfig& c) -> double& { return c.guidance.attitude.R_torque; });
  d("max_range_m", [](AppConfig& c) -> double& { return c.guidance.max_range_m; });
  d("max_speed_mps", [](AppConfig& c) -> double& { return c.guidance.max_speed_mps; });
  d("port_body_x_m", [](AppConfig& c) -> double& { return c.guidance.port_body_m.x(); });
  d("port_body_y_m", [](AppConfig& c) -> double& { return c.guidance.port_body_m.y(); });
  d("port_body_z_m", [](AppConfig& c) -> double& { return c.guidance.port_body_m.z(); });
  // The vehicle the guidance plans with and the harness allocates for (the scenario's, sent by the host).
  d("thrusters.mass_kg", [](AppConfig& c) -> double& { return c.guidance.thrusters.mass_kg; });
  d("thrusters.thrust_N", [](AppConfig& c) -> double& { return c.guidance.thrusters.thrust_N; });
  d("thrusters.min_impulse_bit_s", [](AppConfig& c) -> double& { return c.guidance.thrusters.min_impulse_bit_s; });
  m["rendezvous_objective"] = choice<rvd::guidance::RendezvousObjective>(
      [](AppConfig& c) -> rvd::guidance::RendezvousObjective& { return c.guidance.rendezvous_objective; },
      {"quadratic", "one_norm"});
  m["rendezvous_use_setpoint"] = flag([](AppConfig& c) -> bool& { return c.guidance.rendezvous_use_setpoint; });
  m["keepout_direction"] = choice<rvd::guidance::KeepoutDirection>(
      [](AppConfig& c) -> rvd::guidance::KeepoutDirection& { return c.guidance.keepout_direction; },
      {"natural_motion", "shortest"});
  m["recovery"] = flag([](AppConfig& c) -> bool& { return c.guidance.recovery; });
  d("recovery_weight", [](AppConfig& c) -> double& { return c.guidance.recovery_weight; });
  d("recovery_quadratic", [](AppConfig& c) -> double& { return c.guidance.recovery_quadratic; });
  d("recovery_speed_factor", [](AppConfig& c) -> double& { return c.guidance.recovery_speed_factor; });
  d("max_iter_accept_residual", [](AppConfig& c) -> double& { return c.guidance.max_iter_accept_residual; });
  m["approach_lookahead_steps"] = integer([](AppConfig& c) -> int& { return c.guidance.approach_lookahead_steps; });
  m["approach_lookahead_iterations"] = integer([](AppConfig& c) -> int& { return c.guidance.approach_lookahead_iterations; });
  d("nav.accel_noise_mps2_rthz", [](AppConfig& c) -> double& { return c.nav_filter.accel_noise_mps2_rthz; });
  d("nav.gate_chi2", [](AppConfig& c) -> double& { return c.nav_filter.gate_chi2; });
  d("nav.thrust_error_tau_s", [](AppConfig& c) -> double& { return c.nav_filter.thrust_error_tau_s; });
  d("margins.input_fraction", [](AppConfig& c) -> double& { return c.guidance.margins.input_fraction; });
  d("margins.plan_reserve_fraction", [](AppConfig& c) -> double& { return c.guidance.margins.plan_reserve_fraction; });
  d("margins.keepout_m", [](AppConfig& c) -> double& { return c.guidance.margins.keepout_m; });
  d("margins.estimate_sigmas", [](AppConfig& c) -> double& { return c.guidance.margins.estimate_sigmas; });
  d("margins.approach_entry_brake_fraction", [](AppConfig& c) -> double& { return c.guidance.margins.approach_entry_brake_fraction; });
  d("margins.approach_speed_cap_mps", [](AppConfig& c) -> double& { return c.guidance.margins.approach_speed_cap_mps; });
  d("margins.approach_brake_fraction", [](AppConfig& c) -> double& { return c.guidance.margins.approach_brake_fraction; });
  d("margins.rendezvous_brake_fraction", [](AppConfig& c) -> double& { return c.guidance.margins.rendezvous_brake_fraction; });
  d("margins.rotating_cone_factor", [](AppConfig& c) -> double& { return c.guidance.margins.rotating_cone_factor; });
  d("margins.overshoot_m", [](AppConfig& c) -> double& { return c.guidance.margins.overshoot_m; });
  d("margins.approach_cone_m", [](AppConfig& c) -> double& { return c.guidance.margins.approach_cone_m; });
  d("margins.docking_cone_m", [](AppConfig& c) -> double& { return c.guidance.margins.docking_cone_m; });
  d("margins.v_max_mps", [](AppConfig& c) -> double& { return c.guidance.margins.v_max_mps; });
  const char* phases[] = {"rendezvous", "approach", "docking"};
  for (int i = 0; i < 3; ++i) {
    auto pick = [i](AppConfig& c) -> PhaseParams& {
      return i == 0 ? c.guidance.rendezvous : i == 1 ? c.guidance.approach : c.guidance.docking;
    };
    const std::string p = phases[i];
    m[p + ".N"] = integer([pick](AppConfig& c) -> int& { return pick(c).N; });
    d(p + ".Ts_s", [pick](AppConfig& c) -> double& { return pick(c).Ts_s; });
    m[p + ".Q"] = vector_param<6, rvd::guidance::Vector6d>([pick](AppConfig& c) -> rvd::guidance::Vector6d& { return pick(c).Q_diag; });
    m[p + ".R"] = vector_param<3, Eigen::Vector3d>([pick](AppConfig& c) -> Eigen::Vector3d& { return pick(c).R_diag; });
    m[p + ".terminal_weight"] = choice<rvd::guidance::TerminalWeight>(
        [pick](AppConfig& c) -> rvd::guidance::TerminalWeight& { return pick(c).terminal_weight; }, {"stage", "dare"});
    d(p + ".lambda", [pick](AppConfig& c) -> double& { return pick(c).lambda; });
    d(p + ".los_half_angle_deg", [pick](AppConfig& c) -> double& { return pick(c).los_half_angle_deg; });
    d(p + ".u_max_mps", [pick](AppConfig& c) -> double& { return pick(c).u_max_mps; });
  }
  // phases.NAME: one value for all three phases (a scenario that flies one MPC throughout says so in one
  // setting: the config message carries 512 bytes of settings). Reads back the rendezvous value.
  for (const char* name : {"N", "Ts_s", "Q", "R", "terminal_weight", "lambda", "los_half_angle_deg", "u_max_mps"}) {
    const Param r = m[std::string("rendezvous.") + name], a = m[std::string("approach.") + name],
                d3 = m[std::string("docking.") + name];
    m[std::string("phases.") + name] = {r.get, [r, a, d3](AppConfig& c, const std::string& v) {
                                          r.set(c, v);
                                          a.set(c, v);
                                          d3.set(c, v);
                                        }};
  }
  return m;
}

void set_phase_ints(GuidanceParams& g, const std::vector<double>& v, int PhaseParams::*field) {
  g.rendezvous.*field = static_cast<int>(v[0]);
  g.approach.*field = static_cast<int>(v[1]);
  g.docking.*field = static_cast<int>(v[2]);
}

void for_each_phase(GuidanceParams& g, const std::function<void(PhaseParams&)>& f) {
  f(g.rendezvous);
  f(g.approach);
  f(g.docking);
}

bool on_off(const std::string& v, const std::string& what) {
  if (v == "on") return true;
  if (v == "off") return false;
  throw std::invalid_argument(what + ": on or off, got '" + v + "'");
}

#ifdef RVD_FAULTY_BUILD
// --fault KIND[@STEP]: from step STEP on (default 0), every cmd is sent with one defect.
std::function<void(uint8_t*, size_t)> cmd_fault(const std::string& spec) {
  const size_t at = spec.find('@');
  const std::string kind = spec.substr(0, at);
  const uint32_t from = at == std::string::npos ? 0 : static_cast<uint32_t>(std::stoul(spec.substr(at + 1)));
  using rvd::msg::kHeaderSize;
  const size_t period = kHeaderSize + 8, pulse0 = kHeaderSize + 16 + 6 * 8;  // Cmd layout (schema)
  auto put = [](uint8_t* p, double v) { rvd::msg::wire::put(p, v); };
  std::function<void(uint8_t*)> f;
  if (kind == "zero-period") f = [=](uint8_t* m) { put(m + period, 0.0); };
  else if (kind == "wrong-period") f = [=](uint8_t* m) { put(m + period, 7.0); };
  else if (kind == "negative-pulse") f = [=](uint8_t* m) { put(m + pulse0 + 8 * 2, -0.5); };
  else if (kind == "oversized-pulse") f = [=](uint8_t* m) { put(m + pulse0, 30.0); };
  else if (kind == "nan") f = [=](uint8_t* m) { put(m + pulse0 + 8, std::nan("")); };
  else if (kind == "future-step") f = [=](uint8_t* m) { uint8_t* p = m + kHeaderSize; rvd::msg::wire::put<uint32_t>(p, 1000000); };
  else throw std::invalid_argument("--fault: zero-period, wrong-period, negative-pulse, oversized-pulse, nan or future-step");
  return [=](uint8_t* m, size_t) {
    const uint8_t* p = m + kHeaderSize;
    if (rvd::msg::wire::get<uint32_t>(p) >= from) f(m);
  };
}
#endif

rvd::app::AppConfig parse(int argc, char** argv, bool& list_only, std::string& key_file) {
  rvd::app::AppConfig cfg;
  auto params = named_params();
  bool have_run = false;
  rvd::nav::ErrorModel errors;
  bool auto_margins = true;
  std::vector<std::pair<std::string, std::string>> overrides;  // --set, applied after the derived margins
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw std::invalid_argument(a + " needs a value");
      return argv[++i];
    };
    if (a == "--connect") cfg.endpoint = value();
    else if (a == "--run") { cfg.run_id = value(); have_run = true; }
    else if (a == "--key-file") key_file = value();
    else if (a == "--host-loss-timeout-s") cfg.host_loss_timeout_s = parse_double(value(), a);
#ifdef RVD_FAULTY_BUILD
    else if (a == "--fault") cfg.corrupt_cmd = cmd_fault(value());
#endif
    else if (a == "--lease-ms") cfg.lease_ms = static_cast<uint32_t>(parse_double(value(), a));
    else if (a == "--idle-timeout-s") cfg.idle_timeout_s = parse_double(value(), a);
    else if (a == "--connect-timeout-s") cfg.connect_timeout_s = parse_double(value(), a);
    else if (a == "--untimed-link") cfg.untimed_link = true;
    else if (a == "--session-seed") cfg.session_seed = static_cast<uint64_t>(parse_double(value(), a));
    else if (a == "--telemetry-every") cfg.telemetry_every = static_cast<int>(parse_double(value(), a));
    else if (a == "--horizon") set_phase_ints(cfg.guidance, split_numbers(value(), 3, "--horizon"), &PhaseParams::N);
    else if (a == "--period") {
      const auto v = split_numbers(value(), 3, "--period");
      cfg.guidance.rendezvous.Ts_s = v[0];
      cfg.guidance.approach.Ts_s = v[1];
      cfg.guidance.docking.Ts_s = v[2];
    } else if (a == "--solver") {
      const std::string m = value();
      if (m != "converged" && m != "fixed_barrier") throw std::invalid_argument("--solver: converged or fixed_barrier");
      const auto mode = m == "converged" ? rvd::solver::Mode::Converged : rvd::solver::Mode::FixedBarrier;
      for_each_phase(cfg.guidance, [&](PhaseParams& p) { p.solver.mode = mode; });
    } else if (a == "--max-iter") {
      const int n = static_cast<int>(parse_double(value(), a));
      for_each_phase(cfg.guidance, [&](PhaseParams& p) { p.solver.max_iter = n; });
    } else if (a == "--tol") {
      const double t = parse_double(value(), a);
      for_each_phase(cfg.guidance, [&](PhaseParams& p) { p.solver.tol = t; });
    } else if (a == "--barrier") {
      const double k = parse_double(value(), a);
      for_each_phase(cfg.guidance, [&](PhaseParams& p) { p.solver.barrier = k; });
    } else if (a == "--deadline-fraction") cfg.deadline_fraction = parse_double(value(), a);
    else if (a == "--target-clock") {
      const auto v = split_numbers(value(), 2, "--target-clock");
      if (!(v[0] > 0.0) || !(v[1] > 0.0) || !std::isfinite(v[0]) || !std::isfinite(v[1]))
        throw std::invalid_argument("--target-clock: CPI and clock [Hz] must be > 0");
      cfg.target_clock_cpi = v[0];
      cfg.target_clock_hz = v[1];
    }
    else if (a == "--set") {
      const std::string kv = value();
      const size_t eq = kv.find('=');
      if (eq == std::string::npos) throw std::invalid_argument("--set needs NAME=VALUE, got '" + kv + "'");
      const std::string name = kv.substr(0, eq);
      if (name.rfind("law.", 0) == 0) {  // a plug-in law's own parameter, handed to it in its config
        const std::string law_name = name.substr(4);
        if (law_name.empty() || law_name.size() >= RVD_NAME_SIZE)
          throw std::invalid_argument("--set " + name + ": a law parameter name has 1 to " +
                                      std::to_string(RVD_NAME_SIZE - 1) + " characters");
        rvd_named_value nv{};
        std::snprintf(nv.name, sizeof nv.name, "%s", law_name.c_str());
        nv.value = parse_double(kv.substr(eq + 1), name);
        cfg.law_params.push_back(nv);
        continue;
      }
      if (params.find(name) == params.end())
        throw std::invalid_argument("--set: unknown parameter '" + name + "' (see --list-params)");
      AppConfig probe = cfg;  // the value is checked here, so a bad one names its parameter
      try {
        params[name].set(probe, kv.substr(eq + 1));
      } catch (const std::invalid_argument& e) {
        throw std::invalid_argument("--set " + name + ": " + e.what());
      }
      overrides.emplace_back(name, kv.substr(eq + 1));
    } else if (a == "--nav-sigma") {
      const auto v = split_numbers(value(), 2, "--nav-sigma");
      errors.sigma_position_m = v[0];
      errors.sigma_velocity_mps = v[1];
    } else if (a == "--thrust-error-sigma") errors.thrust_error_sigma = parse_double(value(), a);
    else if (a == "--finite-burns") errors.finite_burns = on_off(value(), a);
    else if (a == "--nav-filter") cfg.nav_filter.enabled = on_off(value(), a);
    else if (a == "--obstacles") {
      const std::string m = value();
      if (m != "on" && m != "off" && m != "hyperplane") throw std::invalid_argument("--obstacles: on, off or hyperplane");
      cfg.guidance.obstacle_capacity = m == "off" ? 0 : rvd::guidance::kMaxObstacles;
      cfg.guidance.obstacle_method = m == "hyperplane" ? rvd::guidance::ObstacleMethod::RotatingHyperplane
                                                       : rvd::guidance::ObstacleMethod::DirectLinearization;
    }
    else if (a == "--margins") {
      const std::string m = value();
      if (m != "auto" && m != "off") throw std::invalid_argument("--margins: auto or off");
      auto_margins = m == "auto";
    } else if (a == "--trivial") cfg.trivial_guidance = true;
    else if (a == "--cpu-model") cfg.cpu_model = value();
    else if (a == "--markers") {
      const std::string m = value();
      if (m == "on") cfg.markers = 1;
      else if (m == "off") cfg.markers = 0;
      else if (m == "auto") cfg.markers = -1;
      else throw std::invalid_argument("--markers: on, off or auto");
    } else if (a == "--pmu-instructions") cfg.pmu_instructions = true;
    else if (a == "--list-params") list_only = true;
    else if (a == "-v" || a == "--verbose") cfg.verbose = true;
    else if (a == "-h" || a == "--help") { std::fputs(kUsage, stdout); std::exit(0); }
    else throw std::invalid_argument("unknown option '" + a + "'");
  }
  cfg.nav_filter.sigma_position_m = errors.sigma_position_m;
  cfg.nav_filter.sigma_velocity_mps = errors.sigma_velocity_mps;
  cfg.nav_filter.thrust_error_sigma = errors.thrust_error_sigma;
  cfg.nav_filter.finite_burns = errors.finite_burns;
  cfg.guidance.finite_burns = errors.finite_burns;
  for (const auto& [name, v] : overrides) params[name].set(cfg, v);  // e.g. the horizon first
  if (auto_margins) cfg.guidance.margins = rvd::nav::derive_margins(errors, cfg.guidance);
  for (const auto& [name, v] : overrides) params[name].set(cfg, v);  // and an explicit margin wins
  if (list_only) {
    for (auto& [name, p] : params) std::printf("%-34s %s\n", name.c_str(), p.get(cfg).c_str());
    return cfg;
  }
  if (!have_run) throw std::invalid_argument("--run RUN_ID is required");
  // The host's config message is applied by parsing these options again behind its --set pairs.
  std::vector<std::string> args(argv + 1, argv + argc);
  cfg.reparse = [args](const std::vector<std::string>& sets) {
    std::vector<std::string> storage{"rvd_flight_sw"};
    for (const std::string& kv : sets) {
      storage.push_back("--set");
      storage.push_back(kv);
    }
    storage.insert(storage.end(), args.begin(), args.end());
    std::vector<char*> av;
    for (std::string& a : storage) av.push_back(a.data());
    bool list = false;
    std::string kf;
    return parse(static_cast<int>(av.size()), av.data(), list, kf);
  };
  if (!rvd::msg::check_run_id(cfg.run_id))
    throw std::invalid_argument("--run '" + cfg.run_id + "': 1 to " + std::to_string(rvd::msg::kRunIdMax) +
                                " characters from A-Z a-z 0-9 _ - (no wildcards, no '/', not empty)");
  return cfg;
}

}  // namespace

namespace rvd::app {
// The flight executable's options as an AppConfig, for a FlightApp built in another process (the
// pybind11 module's in-process path flies exactly what these options make the executable fly).
AppConfig parse_options(const std::vector<std::string>& args) {
  std::vector<std::string> storage{"rvd_flight_sw"};
  storage.insert(storage.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (std::string& a : storage) argv.push_back(a.data());
  bool list_only = false;
  std::string key_file;
  AppConfig cfg = parse(static_cast<int>(argv.size()), argv.data(), list_only, key_file);
  cfg.link_key.fill(0x5a);  // in process there is no link to authenticate; any non-zero key will do
  return cfg;
}
}  // namespace rvd::app

#ifndef RVD_APP_LIBRARY  // the pybind11 module takes the application without its main()
int main(int argc, char** argv) {
  rvd::app::AppConfig cfg;
  bool list_only = false;
  std::string key_file, key_error;
  try {
    cfg = parse(argc, argv, list_only, key_file);
    cfg.law = rvd_guidance_law_entry();  // the law this executable was built with
    cfg.guard_law = true;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "rvd_flight_sw: %s\n\n%s", e.what(), kUsage);
    return 2;
  }
  if (list_only) return 0;
  if (!rvd::app::load_link_key(key_file, cfg.link_key, key_error)) {
    std::fprintf(stderr, "rvd_flight_sw: %s\n", key_error.c_str());
    return 2;
  }
  std::signal(SIGTERM, on_signal);
  std::signal(SIGINT, on_signal);
  std::signal(SIGPIPE, SIG_IGN);  // a peer that vanished is a link status, not a crash
  try {
    rvd::app::FlightApp app(cfg);
    switch (app.run(g_stop)) {
      case rvd::app::ExitReason::Bye:
      case rvd::app::ExitReason::Signal: return 0;
      case rvd::app::ExitReason::LinkLost: return 3;
      case rvd::app::ExitReason::Idle: return 4;
      case rvd::app::ExitReason::NeverConnected: return 5;
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "rvd_flight_sw: %s\n", e.what());
    return 2;
  }
  return 0;
}
#endif  // RVD_APP_LIBRARY
