#include "flight_sw/app/flight_app.hpp"

#include <chrono>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <stdexcept>

#include <csetjmp>
#include <csignal>

#include <sys/resource.h>
#include <sys/time.h>
#include <unistd.h>
#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include "flight_sw/app/build_info.hpp"
#include "flight_sw/guidance/plugin/mpc_law.hpp"

namespace rvd::app {

namespace {
// The link's timeouts are about the host peer, so they stay on the host's clock; the guidance step's
// budget and times are on the flight clock (solver/elapsed.hpp), the target's under emulation.
using Clock = std::chrono::steady_clock;
using solver::StepClock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// Residuals and objective may be NaN/Inf after a failed solve; the wire carries only finite values,
// so "unavailable" travels as -1.
double finite_or(double v, double fallback = -1.0) { return std::isfinite(v) ? v : fallback; }

int phase_index(guidance::Phase p) {
  switch (p) {
    case guidance::Phase::Rendezvous: return 0;
    case guidance::Phase::Approach: return 1;
    default: return 2;
  }
}

uint64_t heap_in_use_bytes() {
#if defined(__GLIBC__) && (__GLIBC__ > 2 || (__GLIBC__ == 2 && __GLIBC_MINOR__ >= 33))
  const struct mallinfo2 mi = mallinfo2();
  return static_cast<uint64_t>(mi.uordblks) + static_cast<uint64_t>(mi.hblkhd);
#else
  return 0;
#endif
}

// The law guard: a crash or a blocked step inside law->step() jumps back into the harness. Only one
// law step runs at a time (the flight software is single-threaded), so one jump buffer will do.
sigjmp_buf g_law_jump;
volatile sig_atomic_t g_in_law = 0;
constexpr int kGuardedSignals[] = {SIGSEGV, SIGBUS, SIGFPE, SIGILL, SIGABRT, SIGALRM};

extern "C" void on_law_signal(int sig) {
  if (g_in_law) {
    g_in_law = 0;
    siglongjmp(g_law_jump, sig);
  }
  if (sig == SIGALRM) return;  // a timer that fired just after the step returned
  std::signal(sig, SIG_DFL);   // the harness's own fault: die as the signal says
  std::raise(sig);
}

void install_law_guard() {
  static bool installed = false;
  if (installed) return;
  installed = true;
  static char alt_stack[64 * 1024];  // a law that overflows its stack still reaches the handler
  stack_t ss{};
  ss.ss_sp = alt_stack;
  ss.ss_size = sizeof alt_stack;
  sigaltstack(&ss, nullptr);
  struct sigaction sa {};
  sa.sa_handler = on_law_signal;
  sigemptyset(&sa.sa_mask);
  sa.sa_flags = SA_ONSTACK | SA_NODEFER;
  for (int sig : kGuardedSignals) sigaction(sig, &sa, nullptr);
}

void arm_timer(double seconds) {
  itimerval it{};
  if (seconds > 0.0) {
    it.it_value.tv_sec = static_cast<time_t>(seconds);
    it.it_value.tv_usec = static_cast<suseconds_t>((seconds - static_cast<double>(it.it_value.tv_sec)) * 1e6);
    if (it.it_value.tv_sec == 0 && it.it_value.tv_usec == 0) it.it_value.tv_usec = 1;
  }
  setitimer(ITIMER_REAL, &it, nullptr);
}

uint64_t max_rss_kb() {
  struct rusage ru {};
  if (getrusage(RUSAGE_SELF, &ru) != 0) return 0;
  return static_cast<uint64_t>(ru.ru_maxrss);
}
}  // namespace

void PhaseLog::add(int i, uint32_t step, double solve_us, bool overrun, uint64_t insns) {
  steps[i] += 1;
  sum_solve_us[i] += solve_us;
  if (steps[i] == 1 || solve_us > max_solve_us[i]) {
    max_solve_us[i] = solve_us;
    max_step[i] = step;
  }
  overruns[i] += overrun ? 1 : 0;
  instructions[i] += insns;
}

void InputCounters::count(msg::Error e) {
  switch (e) {
    case msg::Error::None: return;
    case msg::Error::Oversized: ++oversized; return;
    case msg::Error::Untagged: ++untagged; return;
    case msg::Error::WrongRun: ++wrong_run; return;
    case msg::Error::BadTag: ++bad_tag; return;
    case msg::Error::Replayed: ++replayed; return;
    default: ++malformed; return;
  }
}

const char* to_string(LawFault f) {
  switch (f) {
    case LawFault::None: return "none";
    case LawFault::Failed: return "step returned an error";
    case LawFault::NotFinite: return "NaN or Inf in the command";
    case LawFault::OutOfLimit: return "command outside the phase's limits";
    case LawFault::Overrun: return "step returned after its budget";
    case LawFault::Allocated: return "step allocated heap memory";
    case LawFault::Crashed: return "step crashed (signal); law disabled";
    case LawFault::Blocked: return "step still running at the end of its period; law disabled";
    case LawFault::Disabled: return "law disabled";
  }
  return "unknown";
}

const char* to_string(ExitReason r) {
  switch (r) {
    case ExitReason::Bye: return "bye from the host";
    case ExitReason::Signal: return "signal";
    case ExitReason::LinkLost: return "host lost (link down)";
    case ExitReason::Idle: return "no nav within the idle timeout";
    case ExitReason::NeverConnected: return "never connected";
  }
  return "unknown";
}

FlightApp::FlightApp(AppConfig config)
    : cfg_(std::move(config)),
      counter_(cfg_.markers < 0 ? kSolveMarkersByDefault : cfg_.markers == 1, cfg_.pmu_instructions) {
  if (!(cfg_.deadline_fraction > 0.0)) throw std::invalid_argument("deadline fraction must be > 0");
  if (!msg::check_run_id(cfg_.run_id))
    throw std::invalid_argument("run id '" + cfg_.run_id + "': 1 to " + std::to_string(msg::kRunIdMax) +
                                " characters from A-Z a-z 0-9 _ - (no wildcards, no '/')");
  if (cfg_.link_key == LinkKey{}) throw std::invalid_argument("no link key (all zero)");
  if (!(cfg_.host_loss_timeout_s > 0.0)) throw std::invalid_argument("host loss timeout must be > 0");
  auth_ = msg::LinkAuth(cfg_.link_key.data(), cfg_.link_key.size(), cfg_.run_id, msg::Role::Flight);
  cfg_.link_key.fill(0);  // only the derived keys are kept
  if (cfg_.cpu_model.empty()) cfg_.cpu_model = build_info::kCpuModel;
  // The harness's own parameters (periods, limits, vehicle) must be usable whatever the law.
  if (const std::string err = cfg_.guidance.validate(); !err.empty())
    throw std::invalid_argument("GuidanceParams: " + err);
  if (const char* err = cfg_.nav_filter.validate(); *err) throw std::invalid_argument(err);
  law_ = cfg_.law ? cfg_.law : guidance::mpc_law();
  create_law();
  nav_filter_ = std::make_unique<nav::NavFilter>(cfg_.nav_filter, cfg_.guidance.mean_motion_rad_s());
  if (cfg_.guard_law) install_law_guard();
  if (cfg_.pmu_instructions && !counter_.pmu().usable())
    std::fprintf(stderr, "[flight_sw] no PMU instruction counts: %s\n", counter_.pmu().error().c_str());
  if (cfg_.target_clock_cpi > 0.0) {
    const StepClock c = solver::flight_clock().use_target(cfg_.target_clock_cpi, cfg_.target_clock_hz);
    if (c != StepClock::Target)  // said once here, and in every hello and telemetry (step_clock)
      std::fprintf(stderr, "[flight_sw] --target-clock: no instruction-counting plugin answered: the deadlines "
                           "and step times are on the host's steady_clock\n");
  }
}

void FlightApp::create_law() {
  if (law_->abi_version != RVD_GUIDANCE_ABI_VERSION || !law_->create || !law_->step || !law_->reset || !law_->destroy)
    throw std::invalid_argument(std::string("guidance law '") + (law_->name ? law_->name : "?") +
                                "': built against another rvd_guidance.h (ABI " + std::to_string(law_->abi_version) +
                                ", harness " + std::to_string(RVD_GUIDANCE_ABI_VERSION) + ") or incomplete");
  rvd_guidance_config lc = guidance::generic_config(cfg_.guidance);
  lc.sigma_position_m = cfg_.nav_filter.sigma_position_m;
  lc.sigma_velocity_mps = cfg_.nav_filter.sigma_velocity_mps;
  lc.thrust_error_sigma = cfg_.nav_filter.thrust_error_sigma;
  lc.n_params = static_cast<uint32_t>(cfg_.law_params.size());
  lc.params = cfg_.law_params.empty() ? nullptr : cfg_.law_params.data();
  lc.native = law_ == guidance::mpc_law() ? &cfg_.guidance : nullptr;
  lc.chaser_inertia_kgm2 = cfg_.guidance.attitude.inertia_kgm2;
  lc.torque_max_nm = cfg_.guidance.attitude.torque_max_nm;
  char err[256] = "";
  law_state_ = law_->create(&lc, err, sizeof err);
  if (!law_state_) throw std::invalid_argument(std::string("guidance law '") + law_name() + "': " + (*err ? err : "create failed"));
}

msg::Config FlightApp::config_echo() const {
  msg::Config e;
  const auto& g = cfg_.guidance;
  e.mass_kg = g.thrusters.mass_kg;
  e.thrust_n = g.thrusters.thrust_N;
  e.min_impulse_bit_s = g.thrusters.min_impulse_bit_s;
  const guidance::PhaseParams* ph[3] = {&g.rendezvous, &g.approach, &g.docking};
  for (int i = 0; i < 3; ++i) {
    e.horizon[i] = static_cast<uint16_t>(ph[i]->N);
    e.period_s[i] = ph[i]->Ts_s;
    e.u_max_mps[i] = ph[i]->u_max_mps;
  }
  msg::set_str(e.law, law_name());
  return e;
}

msg::Config FlightApp::apply_config(const msg::Config& host) {
  auto refuse = [&](const std::string& why) {
    msg::Config e = config_echo();
    e.settings = host.settings;
    e.status = 1;
    msg::set_str(e.text, why.substr(0, e.text.size()));
    note("config refused: %s", why.c_str());
    return e;
  };
  if (!cfg_.reparse) return refuse("this flight software takes no config message");
  if (law_disabled_) return refuse("the guidance law is disabled");
  auto number = [](double v) {
    char buf[40];
    std::snprintf(buf, sizeof buf, "%.17g", v);
    return std::string(buf);
  };
  // The host's vehicle and settings go before the command line's options, which so win (pinned).
  std::vector<std::string> sets{"thrusters.mass_kg=" + number(host.mass_kg), "thrusters.thrust_N=" + number(host.thrust_n),
                                "thrusters.min_impulse_bit_s=" + number(host.min_impulse_bit_s)};
  const std::string settings = msg::get_str(host.settings);
  for (size_t pos = 0; pos < settings.size();) {
    const size_t end = std::min(settings.find(';', pos), settings.size());
    if (end > pos) sets.push_back(settings.substr(pos, end - pos));
    pos = end + 1;
  }
  AppConfig next;
  try {
    next = cfg_.reparse(sets);
  } catch (const std::exception& e) {
    return refuse(e.what());
  }
  const AppConfig before = cfg_;
  void* old_state = law_state_;
  cfg_.guidance = next.guidance;
  cfg_.nav_filter = next.nav_filter;
  cfg_.deadline_fraction = next.deadline_fraction;
  cfg_.law_params = next.law_params;
  try {
    if (const std::string err = cfg_.guidance.validate(); !err.empty()) throw std::invalid_argument("GuidanceParams: " + err);
    if (const char* err = cfg_.nav_filter.validate(); *err) throw std::invalid_argument(err);
    create_law();
  } catch (const std::exception& e) {
    cfg_.guidance = before.guidance;
    cfg_.nav_filter = before.nav_filter;
    cfg_.deadline_fraction = before.deadline_fraction;
    cfg_.law_params = before.law_params;
    law_state_ = old_state;
    return refuse(e.what());
  }
  law_->destroy(old_state);
  nav_filter_ = std::make_unique<nav::NavFilter>(cfg_.nav_filter, cfg_.guidance.mean_motion_rad_s());
  phase_ = guidance::Phase::Rendezvous;
  last_cmd_.reset();  // the next run starts with this configuration
  msg::Config e = config_echo();
  e.settings = host.settings;
  e.pinned = static_cast<uint8_t>((e.mass_kg != host.mass_kg ? 1 : 0) | (e.thrust_n != host.thrust_n ? 2 : 0) |
                                  (e.min_impulse_bit_s != host.min_impulse_bit_s ? 4 : 0));
  note("config applied: mass %g kg, thrust %g N, minimum impulse bit %g s%s", e.mass_kg, e.thrust_n,
       e.min_impulse_bit_s, e.pinned ? " (the command line pins part of the vehicle)" : "");
  return e;
}

void FlightApp::receive_config(const uint8_t* data, size_t size) {
  msg::Config c;
  const msg::Error e = msg::receive(auth_, data, size, c);
  if (e != msg::Error::None) {
    note_drop("config", e, size);
    return;
  }
  pending_echo_ = apply_config(c);
}

std::optional<msg::Law> FlightApp::law_message() const {
  if (!last_cmd_ || (last_fault_ == LawFault::None && law_out_.n_named == 0)) return std::nullopt;
  msg::Law m;
  m.step = last_cmd_->step;
  m.fault = static_cast<uint8_t>(last_fault_);
  m.faults = law_faults_total_;
  std::string names;
  const uint32_t n = last_fault_ == LawFault::None ? std::min<uint32_t>(law_out_.n_named, RVD_MAX_NAMED) : 0;
  for (uint32_t i = 0; i < n; ++i) {
    char name[RVD_NAME_SIZE + 1] = {};
    std::memcpy(name, law_out_.named[i].name, RVD_NAME_SIZE);
    names += (i ? "," : "") + std::string(name);
    m.values[i] = finite_or(law_out_.named[i].value, 0.0);
  }
  m.n_values = static_cast<uint8_t>(n);
  msg::set_str(m.names, names.substr(0, m.names.size()));
  return m;
}

FlightApp::~FlightApp() {
  if (law_state_ && !law_disabled_) law_->destroy(law_state_);  // a crashed law's state is not touched again
}

LawFault FlightApp::step_law(const rvd_nav_input& in, double budget_s, double hard_limit_s, double& step_us) {
  law_out_ = rvd_guidance_output{};
  step_us = 0.0;
  if (law_disabled_) return LawFault::Disabled;
  const uint64_t heap_before = heap_in_use_bytes();
  volatile int rc = 0;
  int sig = 0;
  const solver::TimePoint t0 = solver::clock_now();
  if (cfg_.guard_law) {
    arm_timer(hard_limit_s);
    sig = sigsetjmp(g_law_jump, 1);
    if (sig == 0) {
      g_in_law = 1;
      counter_.before_solve();
      rc = law_->step(law_state_, &in, budget_s, &law_out_);
      g_in_law = 0;
    }
    arm_timer(0.0);
  } else {
    counter_.before_solve();
    rc = law_->step(law_state_, &in, budget_s, &law_out_);
  }
  counter_.after_solve();
  step_us = solver::elapsed_us(t0);
  if (sig != 0) {
    law_disabled_ = true;
    law_out_ = rvd_guidance_output{};
    return sig == SIGALRM ? LawFault::Blocked : LawFault::Crashed;
  }
  if (rc != 0) return LawFault::Failed;
  const rvd_guidance_output& o = law_out_;
  for (double v : o.dv_lvlh_mps)
    if (!std::isfinite(v)) return LawFault::NotFinite;
  if (o.phase < RVD_PHASE_RENDEZVOUS || o.phase > RVD_PHASE_DOCKED ||
      o.phase < static_cast<uint8_t>(phase_) || o.status > RVD_STATUS_RECOVERED || o.n_named > RVD_MAX_NAMED)
    return LawFault::OutOfLimit;
  const double dv_max = cfg_.guidance.phase(static_cast<guidance::Phase>(o.phase)).u_max_mps;
  for (double v : o.dv_lvlh_mps)
    if (std::abs(v) > dv_max * (1.0 + 1e-12)) return LawFault::OutOfLimit;
  if (in.chaser_attitude_fresh) {
    for (double v : o.torque_body_nm) {
      if (!std::isfinite(v)) return LawFault::NotFinite;
      if (std::abs(v) > cfg_.guidance.attitude.torque_max_nm * (1.0 + 1e-12)) return LawFault::OutOfLimit;
    }
  }
  // Late: the command is not used, unless the law itself saw its budget run out and answered with
  // its own deadline fallback (a plan computed before, or zero), as the MPC does.
  const bool own_fallback = o.solver_status == RVD_SOLVER_TIME_LIMIT &&
                            (o.status == RVD_STATUS_SHIFTED_PLAN || o.status == RVD_STATUS_ZERO_THRUST);
  if (step_us > budget_s * 1e6 && !own_fallback) return LawFault::Overrun;
  if (heap_in_use_bytes() > heap_before) return LawFault::Allocated;
  return LawFault::None;
}

std::string FlightApp::key(const char* kind) const { return "rvd/" + cfg_.run_id + "/" + kind; }

void FlightApp::note(const char* fmt, ...) const {
  if (!cfg_.verbose) return;
  std::va_list ap;
  va_start(ap, fmt);
  std::fprintf(stderr, "[flight_sw] ");
  std::vfprintf(stderr, fmt, ap);
  std::fprintf(stderr, "\n");
  va_end(ap);
}

msg::Hello FlightApp::hello(uint32_t session) const {
  msg::Hello h;
  msg::set_str(h.arch, build_info::kArch);
  msg::set_str(h.cpu_model, cfg_.cpu_model);
  msg::set_str(h.compiler, build_info::compiler());
  msg::set_str(h.build, build_info::kBuildFlags);
  const auto& g = cfg_.guidance;
  h.solver_mode = g.rendezvous.solver.mode == solver::Mode::FixedBarrier ? 0 : 1;
  h.solver_max_iter = static_cast<uint16_t>(g.rendezvous.solver.max_iter);
  h.solver_tol = g.rendezvous.solver.tol;
  h.horizon = {static_cast<uint16_t>(g.rendezvous.N), static_cast<uint16_t>(g.approach.N),
               static_cast<uint16_t>(g.docking.N)};
  h.period_s = {g.rendezvous.Ts_s, g.approach.Ts_s, g.docking.Ts_s};
  h.max_pulse_s = {guidance::max_pulse_s(g.rendezvous.u_max_mps, g.thrusters),
                   guidance::max_pulse_s(g.approach.u_max_mps, g.thrusters),
                   guidance::max_pulse_s(g.docking.u_max_mps, g.thrusters)};
  h.deadline_fraction = cfg_.deadline_fraction;
  h.step_clock = static_cast<uint8_t>(solver::flight_clock().source());
  h.pid = static_cast<uint32_t>(getpid());
  h.session = session;
  return h;
}

msg::Telemetry FlightApp::telemetry() const {
  msg::Telemetry t;
  for (int i = 0; i < 3; ++i) {
    t.steps[i] = log_.steps[i];
    t.overruns[i] = log_.overruns[i];
    t.mean_solve_us[i] = log_.steps[i] ? log_.sum_solve_us[i] / log_.steps[i] : 0.0;
    t.max_solve_us[i] = log_.max_solve_us[i];
    t.max_step[i] = log_.max_step[i];
    t.total_instructions[i] = log_.instructions[i];
  }
  t.step_clock = static_cast<uint32_t>(solver::flight_clock().source());
  t.peak_heap_bytes = peak_heap_bytes_;
  t.max_rss_kb = max_rss_kb();
  const InputCounters& d = dropped_;
  t.nav_rejected = d.malformed;
  t.nav_duplicates = d.duplicates;
  t.nav_stale = d.stale;
  t.nav_future = d.future;
  t.nav_coalesced = d.coalesced;
  t.rx_untagged = d.untagged;
  t.rx_wrong_run = d.wrong_run;
  t.rx_bad_tag = d.bad_tag;
  t.rx_replayed = d.replayed;
  t.rx_oversized = d.oversized;
  if (session_) {
    const link::ZenohStats& z = session_->stats();
    auto u32 = [](uint64_t v) { return static_cast<uint32_t>(std::min<uint64_t>(v, UINT32_MAX)); };
    t.rx_oversized = u32(d.oversized + z.rx_oversized);
    t.link_losses = u32(z.link_losses);
    t.link_resyncs = u32(z.resyncs);
    t.link_rx_rejected = u32(z.rx_rejected);
    t.link_rx_unmatched = u32(z.rx_unmatched);
  }
  return t;
}

std::optional<msg::Cmd> FlightApp::handle_nav(const msg::Nav& nav) {
  const bool first = (nav.flags & 1u) != 0;
  if (last_cmd_ && nav.step == last_cmd_->step) {
    ++dropped_.duplicates;  // a resend: same answer, guidance state untouched
    return last_cmd_;
  }
  if (first) {
    if (nav.step != 0) {  // a run starts at step 0
      ++dropped_.future;
      return std::nullopt;
    }
    if (!law_disabled_) law_->reset(law_state_);  // a (re)started run
    phase_ = guidance::Phase::Rendezvous;
    nav_filter_->reset();
    log_ = PhaseLog{};
    overruns_ = 0;
    last_cmd_.reset();
    last_torque_.reset();
  } else if (!last_cmd_ || nav.step > last_cmd_->step + static_cast<uint64_t>(cfg_.max_step_ahead)) {
    ++dropped_.future;  // nothing started yet, or far beyond the next step: never adopted
    return std::nullopt;
  } else if (nav.step < last_cmd_->step) {
    ++dropped_.stale;  // older than what we answered: a late duplicate, nothing to do
    return std::nullopt;
  }

  msg::Cmd out;
  out.step = nav.step;
  if (cfg_.trivial_guidance) {
    out.phase = static_cast<uint8_t>(guidance::Phase::Rendezvous);
    out.guidance_status = static_cast<uint8_t>(guidance::StepStatus::ZeroThrust);
    out.solver_status = 255;
    out.period_s = cfg_.guidance.rendezvous.Ts_s;
    last_cmd_ = out;
    return out;
  }

  guidance::NavInput in;
  in.step = nav.step;
  in.t_s = nav.t_s;
  guidance::Vector6d z;
  for (int i = 0; i < 3; ++i) {
    z(i) = nav.position_lvlh_m[i];
    z(3 + i) = nav.velocity_lvlh_mps[i];
  }
  // The filter is part of the timed, counted guidance step.
  counter_.start_step(nav.step);
  const solver::TimePoint t_filter = solver::clock_now();
  counter_.before_solve();
  const nav::NavEstimate& est = nav_filter_->update(nav.t_s, z);
  counter_.after_solve();
  const double filter_us = solver::elapsed_us(t_filter);
  in.x_lvlh = est.update == nav::NavUpdate::Invalid ? z : est.x;  // an invalid input stays invalid
  in.quality.position_m = std::sqrt(est.P.diagonal().head<3>().maxCoeff());
  in.quality.velocity_mps = std::sqrt(est.P.diagonal().tail<3>().maxCoeff());
  for (int j = 0; j < 6; ++j) in.quality.thrust_scale[j] = 1.0 + est.thrust_error(j);
  in.quality.thrust_scale_sigma = est.thrust_error_sigma;
  in.q_lvlh_body = Eigen::Quaterniond(nav.q_lvlh_body[0], nav.q_lvlh_body[1], nav.q_lvlh_body[2], nav.q_lvlh_body[3]);
  in.omega_body_rad_s = Eigen::Vector3d(nav.omega_body_rad_s[0], nav.omega_body_rad_s[1], nav.omega_body_rad_s[2]);

  const int phase_before = phase_index(phase_);
  const double period_s = cfg_.guidance.phase(phase_).Ts_s;
  const double budget_us = cfg_.deadline_fraction * period_s * 1e6;
  rvd_nav_input li{};
  li.step = nav.step;
  li.first = first ? 1 : 0;
  li.t_s = nav.t_s;
  for (int i = 0; i < 3; ++i) {
    li.position_lvlh_m[i] = in.x_lvlh(i);
    li.velocity_lvlh_mps[i] = in.x_lvlh(3 + i);
    li.omega_body_rad_s[i] = nav.omega_body_rad_s[i];
  }
  for (int i = 0; i < 4; ++i) li.q_lvlh_body[i] = nav.q_lvlh_body[i];
  li.sigma_position_m = in.quality.position_m;
  li.sigma_velocity_mps = in.quality.velocity_mps;
  for (int j = 0; j < 6; ++j) li.thrust_scale[j] = in.quality.thrust_scale[j];
  li.thrust_scale_sigma = in.quality.thrust_scale_sigma;
  li.valid = est.update == nav::NavUpdate::Invalid ? 0 : 1;
  const bool obstacles_fresh = have_obstacles_;
  if (obstacles_fresh) put_obstacles(li);
  if (have_attitude_) {  // the chaser's own attitude (planar truth): this step commands a torque
    li.chaser_attitude_fresh = 1;
    for (int i = 0; i < 4; ++i) li.q_lvlh_chaser[i] = pending_attitude_.q_lvlh_chaser[i];
    for (int i = 0; i < 3; ++i) li.omega_chaser_rad_s[i] = pending_attitude_.omega_chaser_rad_s[i];
    have_attitude_ = false;
  }

  // The law's step, bracketed by the instruction counters (step_law), under the deadline: it gets
  // what the filter left of the budget, and a step still running at the end of the period is stopped.
  // The stop is a host timer: under the target clock the host's time says nothing about the
  // target's (emulation runs many times slower), so it then only stops a law that never returns,
  // after the flight's idle timeout, the longest the flight waits for its host anyway.
  const solver::TimePoint t_law = solver::clock_now();
  double law_us = 0.0;
  const double hard_limit_s = solver::flight_clock().source() == StepClock::Target
                                  ? std::max(period_s, cfg_.idle_timeout_s) : period_s;
  const LawFault fault = step_law(li, std::max(budget_us - filter_us, 1e-3) * 1e-6, hard_limit_s, law_us);
  const uint64_t insns = counter_.instructions();
  const rvd_guidance_output& lo = law_out_;
  Eigen::Vector3d dv = Eigen::Vector3d::Zero();
  guidance::Phase phase = phase_;
  uint8_t status = RVD_STATUS_LAW_FAULT;
  if (fault == LawFault::None) {
    phase = static_cast<guidance::Phase>(lo.phase);
    status = lo.status;
    if (phase != guidance::Phase::Docked && status != RVD_STATUS_DOCKED)
      dv = Eigen::Vector3d(lo.dv_lvlh_mps[0], lo.dv_lvlh_mps[1], lo.dv_lvlh_mps[2]);
  } else {
    ++law_faults_[static_cast<int>(fault)];
    ++law_faults_total_;
    if (fault != last_fault_ || fault != LawFault::Disabled)
      note("step %u: guidance law '%s': %s: zero thrust", nav.step, law_name(), to_string(fault));
    if (fault == LawFault::OutOfLimit && lo.phase >= static_cast<uint8_t>(phase_) && lo.phase <= RVD_PHASE_DOCKED)
      phase = static_cast<guidance::Phase>(lo.phase);  // a valid phase switch still counts
  }
  last_fault_ = fault;
  if (obstacles_fresh) note_obstacles_held(li);
  if (li.chaser_attitude_fresh) {  // a faulty step commands no torque either
    msg::Torque tq;
    tq.step = nav.step;
    for (int i = 0; i < 3; ++i) tq.torque_body_nm[i] = fault == LawFault::None ? law_out_.torque_body_nm[i] : 0.0;
    tq.torque_max_nm = cfg_.guidance.attitude.torque_max_nm;
    last_torque_ = tq;
  }
  phase_ = phase;
  const guidance::PhaseParams& pp = cfg_.guidance.phase(phase);
  // A pulse never outlasts its period (a law on a vehicle too weak for its delta-v limit).
  const double pulse_cap_s = std::min(guidance::max_pulse_s(pp.u_max_mps, cfg_.guidance.thrusters), pp.Ts_s);
  const guidance::Allocation a =
      guidance::allocate_thrusters(dv, pulse_cap_s, cfg_.guidance.thrusters, in.quality.thrust_scale);
  const double step_us = filter_us + solver::elapsed_us(t_law);
  nav_filter_->command(nav.t_s, a.dv_nominal_mps, a.pulse_s);

  const bool computed = fault == LawFault::None && lo.computed != 0;
  const double solve_us = computed ? (lo.solve_time_us >= 0.0 ? finite_or(lo.solve_time_us, 0.0) : law_us) : 0.0;
  const bool overrun = (fault == LawFault::None && lo.solver_status == RVD_SOLVER_TIME_LIMIT) ||
                       fault == LawFault::Overrun || fault == LawFault::Blocked || step_us > budget_us;
  overruns_ += overrun ? 1 : 0;
  if (computed) log_.add(phase_before, nav.step, solve_us, overrun, insns);
  peak_heap_bytes_ = std::max(peak_heap_bytes_, heap_in_use_bytes());

  out.phase = static_cast<uint8_t>(phase);
  out.guidance_status = status;
  out.solver_status = fault == LawFault::None ? lo.solver_status : static_cast<uint8_t>(RVD_SOLVER_NONE);
  out.overrun = overrun ? 1 : 0;
  out.period_s = pp.Ts_s;
  for (int i = 0; i < 3; ++i) {
    out.dv_cmd_lvlh_mps[i] = dv(i);
    out.dv_alloc_lvlh_mps[i] = finite_or(a.dv_alloc_mps(i), 0.0);
  }
  for (int i = 0; i < 6; ++i) out.pulse_s[i] = finite_or(a.pulse_s[i], 0.0);
  out.solve_time_us = solve_us;
  out.step_time_us = finite_or(step_us, 0.0);
  out.instructions = insns;
  out.iterations = static_cast<uint16_t>(computed ? std::min<uint32_t>(lo.iterations, UINT16_MAX) : 0);
  out.overruns = overruns_;
  out.primal_residual = computed ? finite_or(lo.primal_residual) : -1.0;
  out.dual_residual = computed ? finite_or(lo.dual_residual) : -1.0;
  out.objective = computed ? finite_or(lo.objective, 0.0) : 0.0;
  last_cmd_ = out;
  return out;
}

void FlightApp::receive_nav(const uint8_t* data, size_t size) {
  msg::Nav nav;
  const msg::Error e = msg::receive(auth_, data, size, nav);
  if (e != msg::Error::None) {
    note_drop("nav", e, size);
    return;
  }
  if (have_nav_) ++dropped_.coalesced;  // the previous one was never handled
  pending_nav_ = nav;
  have_nav_ = true;
}

void FlightApp::receive_obstacles(const uint8_t* data, size_t size) {
  msg::Obstacles m;
  const msg::Error e = msg::receive(auth_, data, size, m);
  if (e != msg::Error::None) {
    note_drop("obstacles", e, size);
    return;
  }
  accept_obstacles(m);
}

void FlightApp::accept_obstacles(const msg::Obstacles& m) {
  if (m.count > m.id.size()) {  // more than the message holds: its own fault, not adopted
    ++obstacles_rejected_;
    note("obstacles for step %u refused: count %u > %zu slots", m.step, m.count, m.id.size());
    return;
  }
  pending_obstacles_ = m;
  have_obstacles_ = true;
}

void FlightApp::receive_chaser_attitude(const uint8_t* data, size_t size) {
  msg::ChaserAttitude m;
  const msg::Error e = msg::receive(auth_, data, size, m);
  if (e != msg::Error::None) {
    note_drop("chaser_attitude", e, size);
    return;
  }
  accept_chaser_attitude(m);
}

void FlightApp::accept_chaser_attitude(const msg::ChaserAttitude& m) {
  pending_attitude_ = m;
  have_attitude_ = true;
}

void FlightApp::put_obstacles(rvd_nav_input& li) const {
  const msg::Obstacles& m = pending_obstacles_;
  static_assert(sizeof(m.id) / sizeof(m.id[0]) == RVD_MAX_OBSTACLES, "one rvd_obstacle per link slot");
  li.obstacles_fresh = 1;
  li.n_obstacles = m.count;
  li.obstacles_sensed = m.sensed > m.count ? m.sensed : m.count;
  li.obstacles_t_s = m.t_s;
  for (int k = 0; k < m.count; ++k) {
    rvd_obstacle& o = li.obstacles[k];
    o.id = m.id[k];
    o.t_seen_s = m.t_seen_s[k];
    for (int j = 0; j < 3; ++j) {
      o.position_lvlh_m[j] = m.position_lvlh_m[3 * k + j];
      o.velocity_lvlh_mps[j] = m.velocity_lvlh_mps[3 * k + j];
      o.semi_axes_m[j] = m.semi_axes_m[3 * k + j];
    }
    for (int j = 0; j < 4; ++j) o.q_lvlh_body[j] = m.q_lvlh_body[4 * k + j];
  }
}

void FlightApp::note_obstacles_held(const rvd_nav_input& li) {
  const rvd_guidance_output& lo = law_out_;
  const uint32_t dropped_before = obstacles_held_.dropped_total;
  obstacles_held_ = msg::ObstacleStatus{};
  obstacles_held_.step = pending_obstacles_.step;
  obstacles_held_.received = static_cast<uint16_t>(std::min<uint32_t>(li.obstacles_sensed, UINT16_MAX));
  obstacles_held_.held = static_cast<uint16_t>(std::min<uint32_t>(lo.obstacles_held, RVD_MAX_OBSTACLES));
  obstacles_held_.capacity = static_cast<uint16_t>(std::min<uint32_t>(lo.obstacles_capacity, UINT16_MAX));
  obstacles_held_.dropped_total = lo.obstacles_dropped_total;
  obstacles_held_.rejected_total = lo.obstacles_rejected_total;  // the law's; obstacle_status() adds the harness's
  for (int k = 0; k < obstacles_held_.held; ++k) obstacles_held_.held_id[k] = lo.obstacle_held_id[k];
  if (obstacles_held_.dropped_total != dropped_before)
    note("obstacles step %u: %u sensed, holding the nearest %u (capacity %u)", pending_obstacles_.step,
         li.obstacles_sensed, static_cast<unsigned>(obstacles_held_.held), static_cast<unsigned>(obstacles_held_.capacity));
  have_obstacles_ = false;
  obstacle_status_due_ = true;
}

msg::ObstacleStatus FlightApp::obstacle_status() const {
  msg::ObstacleStatus s = obstacles_held_;
  s.rejected_total += obstacles_rejected_;  // whole messages refused here count at once
  return s;
}

void FlightApp::receive_bye(const uint8_t* data, size_t size) {
  msg::Bye b;
  const msg::Error e = msg::receive(auth_, data, size, b);
  if (e != msg::Error::None) {
    note_drop("bye", e, size);
    return;
  }
  bye_received_ = true;
}

void FlightApp::note_drop(const char* kind, msg::Error e, size_t size) {
  dropped_.count(e);
  // The first drops are logged one by one; a flood is only counted (telemetry has the totals).
  constexpr uint32_t kLogged = 50;
  if (++drops_noted_ <= kLogged) note("%s dropped: %s (%zu bytes)", kind, msg::to_string(e), size);
  if (drops_noted_ == kLogged) note("further drops are only counted");
}

std::optional<msg::Nav> FlightApp::take_nav() {
  if (!have_nav_) return std::nullopt;
  have_nav_ = false;
  return pending_nav_;
}

template <class M>
void FlightApp::publish_msg(const char* kind, const M& m) {
  uint8_t buf[M::kSize];
  msg::Error e = msg::Error::None;
  size_t n = msg::encode(m, buf, sizeof buf, &e);
  if (n != 0 && M::kType == msg::Type::Cmd && cfg_.corrupt_cmd) cfg_.corrupt_cmd(buf, n);
  if (n != 0 && (e = auth_.seal(buf, n)) != msg::Error::None) n = 0;
  if (n == 0) {
    note("cannot send %s: %s", kind, msg::to_string(e));
    return;
  }
  const link::LinkStatus st = session_->put(key(kind), buf, n);
  if (st != link::LinkStatus::Ok) note("put %s: %s", kind, link::to_string(st));
}

ExitReason FlightApp::run(const std::atomic<bool>& stop) {
  link::ZenohConfig zc;
  zc.endpoint = cfg_.endpoint;
  zc.lease_ms = cfg_.lease_ms;
  zc.untimed = cfg_.untimed_link;
  zc.seed = cfg_.session_seed;
  zc.max_reassembled_bytes = 4096;  // every rvd message fits one batch: a fragmented one is oversized
  session_ = std::make_unique<link::ZenohSession>(zc);
  session_->declare_subscriber(key("nav"), [this](const link::Sample& s) { receive_nav(s.payload, s.size); });
  session_->declare_subscriber(key("bye"), [this](const link::Sample& s) { receive_bye(s.payload, s.size); });
  session_->declare_subscriber(key("obstacles"), [this](const link::Sample& s) { receive_obstacles(s.payload, s.size); });
  session_->declare_subscriber(key("config"), [this](const link::Sample& s) { receive_config(s.payload, s.size); });
  session_->declare_subscriber(key("chaser_attitude"),
                               [this](const link::Sample& s) { receive_chaser_attitude(s.payload, s.size); });
  link::LinkStatus st = session_->open();
  note("connecting to %s: %s%s%s", cfg_.endpoint.c_str(), link::to_string(st),
       st == link::LinkStatus::Ok ? "" : ": ", st == link::LinkStatus::Ok ? "" : session_->last_error().c_str());

  const auto t_start = Clock::now();
  auto t_last_nav = Clock::now();
  auto t_link_up = Clock::now();  // the last time the link was seen up
  uint64_t hello_for_connect = 0;
  uint32_t answered = 0;
  ExitReason reason = ExitReason::Bye;
  for (;;) {
    if (stop.load()) {
      reason = ExitReason::Signal;
      break;
    }
    const uint64_t connects = session_->stats().connects;
    if (session_->connected() && connects != hello_for_connect) {  // first connection or a reconnect
      publish_msg("hello", hello(static_cast<uint32_t>(connects)));
      hello_for_connect = connects;
      t_last_nav = Clock::now();
      const auto& zid = session_->link_info().local_zid;
      note("session %llu up (our ZenohID %02x%02x%02x%02x...)", static_cast<unsigned long long>(connects),
           zid.bytes[0], zid.bytes[1], zid.bytes[2], zid.bytes[3]);
    }
    st = session_->poll(cfg_.untimed_link ? -1 : 100);
    if (pending_echo_) {  // the host's config: the echo, then a hello with the limits it implies
      publish_msg("config_echo", *pending_echo_);
      pending_echo_.reset();
      publish_msg("hello", hello(static_cast<uint32_t>(session_->stats().connects)));
    }
    if (auto nav = take_nav()) {
      t_last_nav = Clock::now();
      if (auto cmd = handle_nav(*nav)) {
        if (take_obstacle_status_due()) publish_msg("obstacle_status", obstacle_status());
        if (auto tq = torque_for(cmd->step)) publish_msg("torque", *tq);
        publish_msg("cmd", *cmd);
        if (auto lm = law_message()) publish_msg("law", *lm);
        if (++answered % static_cast<uint32_t>(std::max(cfg_.telemetry_every, 1)) == 0)
          publish_msg("telemetry", telemetry());
      }
    }
    if (bye_received_) {
      reason = ExitReason::Bye;
      break;
    }
    if (st == link::LinkStatus::ReconnectExhausted || st == link::LinkStatus::NotConnected) {
      reason = hello_for_connect ? ExitReason::LinkLost : ExitReason::NeverConnected;
      break;
    }
    if (cfg_.untimed_link) continue;
    if (session_->connected()) t_link_up = Clock::now();
    if (hello_for_connect != 0 && seconds_since(t_link_up) > cfg_.host_loss_timeout_s) {
      note("link down for %.1f s (limit %.1f s): %s", seconds_since(t_link_up), cfg_.host_loss_timeout_s,
           session_->last_error().c_str());
      reason = ExitReason::LinkLost;
      break;
    }
    if (hello_for_connect == 0 && seconds_since(t_start) > cfg_.connect_timeout_s) {
      reason = ExitReason::NeverConnected;
      break;
    }
    if (hello_for_connect != 0 && seconds_since(t_last_nav) > cfg_.idle_timeout_s) {
      reason = ExitReason::Idle;
      break;
    }
  }
  if (session_->connected()) {
    publish_msg("telemetry", telemetry());
    msg::Bye bye;
    bye.reason = reason == ExitReason::Bye ? 0 : reason == ExitReason::Signal ? 4 : 3;
    bye.last_step = last_cmd_ ? last_cmd_->step : 0;
    msg::set_str(bye.text, std::string("flight_sw exit: ") + to_string(reason));
    publish_msg("bye", bye);
    session_->close();
  }
  const InputCounters& d = dropped_;
  note("exit: %s (overruns %u; dropped: malformed %u, duplicates %u, stale %u, future %u, coalesced %u, "
       "oversized %u, untagged %u, wrong run %u, bad tag %u, replayed %u; link resyncs %llu)",
       to_string(reason), overruns_, d.malformed, d.duplicates, d.stale, d.future, d.coalesced, d.oversized,
       d.untagged, d.wrong_run, d.bad_tag, d.replayed, static_cast<unsigned long long>(session_->stats().resyncs));
  return reason;
}

}  // namespace rvd::app
