// rvd_flight_sw: the flight software executable (native, or cross-built and run under QEMU).
//
//   rvd_flight_sw --connect tcp/127.0.0.1:7447 --run RUN_ID [options]
//
// Exit codes: 0 bye from the host or SIGTERM/SIGINT, 2 bad arguments, 3 link lost, 4 idle timeout,
// 5 never connected.
#include <atomic>
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

namespace {

std::atomic<bool> g_stop{false};
extern "C" void on_signal(int) { g_stop.store(true); }

using rvd::guidance::GuidanceParams;
using rvd::guidance::PhaseParams;

const char* kUsage = R"(usage: rvd_flight_sw --run RUN_ID [options]

Link
  --connect ENDPOINT        Zenoh endpoint of the host simulator (default tcp/127.0.0.1:7447;
                            under QEMU system mode the host is tcp/10.0.2.2:PORT, or
                            semihosting/DIR: host FIFOs, see qemu/semihosting_link.py)
  --lease-ms MS             lease announced to the host (default 20000)
  --idle-timeout-s S        exit when no nav arrives for this long (default 300)
  --connect-timeout-s S     exit when the first connection does not come up (default 60)
  --untimed-link            wait for the host without time limits (QEMU system mode with
                            -icount sleep=off: the guest clock stands still while it waits, so a
                            timeout would fire at once); idle and connect timeouts are off too
  --telemetry-every K       steps between telemetry messages (default 20)
Guidance
  --horizon R,A,D           prediction horizons of rendezvous, approach, docking (default 30,15,12)
  --period R,A,D            control periods [s] (default 30,20,5)
  --solver MODE             converged | fixed_barrier (all phases)
  --max-iter N              solver iteration cap (all phases)
  --tol X                   solver tolerance (converged mode)
  --barrier K               barrier weight (fixed_barrier mode)
  --deadline-fraction F     solve budget = F x Ts of the phase, on this computer's clock (default 0.5)
  --set NAME=VALUE          any guidance parameter (--list-params shows them)
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

// Named guidance parameters for --set: every scalar a user may want to sweep.
std::map<std::string, std::function<double&(GuidanceParams&)>> scalar_params() {
  std::map<std::string, std::function<double&(GuidanceParams&)>> m;
  m["orbit_altitude_m"] = [](GuidanceParams& g) -> double& { return g.orbit_altitude_m; };
  m["keepout_radius_m"] = [](GuidanceParams& g) -> double& { return g.keepout_radius_m; };
  m["approach_stop_m"] = [](GuidanceParams& g) -> double& { return g.approach_stop_m; };
  m["dock_tolerance_m"] = [](GuidanceParams& g) -> double& { return g.dock_tolerance_m; };
  m["v_max_mps"] = [](GuidanceParams& g) -> double& { return g.v_max_mps; };
  m["rendezvous_setpoint_offset_m"] = [](GuidanceParams& g) -> double& { return g.rendezvous_setpoint_offset_m; };
  m["approach_setpoint_offset_m"] = [](GuidanceParams& g) -> double& { return g.approach_setpoint_offset_m; };
  m["rendezvous_switch_margin_m"] = [](GuidanceParams& g) -> double& { return g.rendezvous_switch_margin_m; };
  m["approach_switch_margin_m"] = [](GuidanceParams& g) -> double& { return g.approach_switch_margin_m; };
  m["keepout_rate_cap_factor"] = [](GuidanceParams& g) -> double& { return g.keepout_rate_cap_factor; };
  m["port_body_x_m"] = [](GuidanceParams& g) -> double& { return g.port_body_m.x(); };
  m["port_body_y_m"] = [](GuidanceParams& g) -> double& { return g.port_body_m.y(); };
  m["port_body_z_m"] = [](GuidanceParams& g) -> double& { return g.port_body_m.z(); };
  const char* phases[] = {"rendezvous", "approach", "docking"};
  for (int i = 0; i < 3; ++i) {
    auto pick = [i](GuidanceParams& g) -> PhaseParams& { return i == 0 ? g.rendezvous : i == 1 ? g.approach : g.docking; };
    const std::string p = phases[i];
    m[p + ".Ts_s"] = [pick](GuidanceParams& g) -> double& { return pick(g).Ts_s; };
    m[p + ".lambda"] = [pick](GuidanceParams& g) -> double& { return pick(g).lambda; };
    m[p + ".los_half_angle_deg"] = [pick](GuidanceParams& g) -> double& { return pick(g).los_half_angle_deg; };
    m[p + ".u_max_mps"] = [pick](GuidanceParams& g) -> double& { return pick(g).u_max_mps; };
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

rvd::app::AppConfig parse(int argc, char** argv, bool& list_only) {
  rvd::app::AppConfig cfg;
  auto params = scalar_params();
  bool have_run = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw std::invalid_argument(a + " needs a value");
      return argv[++i];
    };
    if (a == "--connect") cfg.endpoint = value();
    else if (a == "--run") { cfg.run_id = value(); have_run = true; }
    else if (a == "--lease-ms") cfg.lease_ms = static_cast<uint32_t>(parse_double(value(), a));
    else if (a == "--idle-timeout-s") cfg.idle_timeout_s = parse_double(value(), a);
    else if (a == "--connect-timeout-s") cfg.connect_timeout_s = parse_double(value(), a);
    else if (a == "--untimed-link") cfg.untimed_link = true;
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
    else if (a == "--set") {
      const std::string kv = value();
      const size_t eq = kv.find('=');
      if (eq == std::string::npos) throw std::invalid_argument("--set needs NAME=VALUE, got '" + kv + "'");
      const std::string name = kv.substr(0, eq);
      auto it = params.find(name);
      if (it == params.end()) throw std::invalid_argument("--set: unknown parameter '" + name + "' (see --list-params)");
      it->second(cfg.guidance) = parse_double(kv.substr(eq + 1), name);
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
  if (list_only) {
    for (auto& [name, ref] : params) std::printf("%-34s %g\n", name.c_str(), ref(cfg.guidance));
    return cfg;
  }
  if (!have_run) throw std::invalid_argument("--run RUN_ID is required");
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
  return parse(static_cast<int>(argv.size()), argv.data(), list_only);
}
}  // namespace rvd::app

#ifndef RVD_APP_LIBRARY  // the pybind11 module takes the application without its main()
int main(int argc, char** argv) {
  rvd::app::AppConfig cfg;
  bool list_only = false;
  try {
    cfg = parse(argc, argv, list_only);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "rvd_flight_sw: %s\n\n%s", e.what(), kUsage);
    return 2;
  }
  if (list_only) return 0;
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
