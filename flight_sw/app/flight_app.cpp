#include "flight_sw/app/flight_app.hpp"

#include <chrono>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <stdexcept>

#include <sys/resource.h>
#include <unistd.h>
#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include "flight_sw/app/build_info.hpp"

namespace rvd::app {

namespace {
using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// Residuals and objective may be NaN/Inf after a failed solve; the wire carries only finite values,
// so "unavailable" travels as -1.
double finite_or(double v, double fallback = -1.0) { return std::isfinite(v) ? v : fallback; }

uint8_t solver_status_code(const guidance::Command& c) {
  if (c.solver.status == solver::Status::TimeLimit) return static_cast<uint8_t>(c.solver.status);  // even unsolved
  if (!c.solved) return 255;
  return static_cast<uint8_t>(c.solver.status);
}

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
  guidance_ = std::make_unique<guidance::Guidance>(cfg_.guidance);  // validates the parameters
  if (const char* err = cfg_.nav_filter.validate(); *err) throw std::invalid_argument(err);
  nav_filter_ = std::make_unique<nav::NavFilter>(cfg_.nav_filter, cfg_.guidance.mean_motion_rad_s());
  guidance_->set_solve_observer(&counter_);
  if (cfg_.pmu_instructions && !counter_.pmu().usable())
    std::fprintf(stderr, "[flight_sw] no PMU instruction counts: %s\n", counter_.pmu().error().c_str());
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
    guidance_->reset();  // a (re)started run
    nav_filter_->reset();
    log_ = PhaseLog{};
    overruns_ = 0;
    last_cmd_.reset();
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
  const auto t_filter = Clock::now();
  counter_.before_solve();
  const nav::NavEstimate& est = nav_filter_->update(nav.t_s, z);
  counter_.after_solve();
  const double filter_us = std::chrono::duration<double, std::micro>(Clock::now() - t_filter).count();
  in.x_lvlh = est.update == nav::NavUpdate::Invalid ? z : est.x;  // an invalid input stays invalid
  in.quality.position_m = std::sqrt(est.P.diagonal().head<3>().maxCoeff());
  in.quality.velocity_mps = std::sqrt(est.P.diagonal().tail<3>().maxCoeff());
  for (int j = 0; j < 6; ++j) in.quality.thrust_scale[j] = 1.0 + est.thrust_error(j);
  in.quality.thrust_scale_sigma = est.thrust_error_sigma;
  in.q_lvlh_body = Eigen::Quaterniond(nav.q_lvlh_body[0], nav.q_lvlh_body[1], nav.q_lvlh_body[2], nav.q_lvlh_body[3]);
  in.omega_body_rad_s = Eigen::Vector3d(nav.omega_body_rad_s[0], nav.omega_body_rad_s[1], nav.omega_body_rad_s[2]);

  if (have_obstacles_) take_obstacles(in.x_lvlh.head<3>());
  const int phase_before = phase_index(guidance_->phase());
  const double budget_us = cfg_.deadline_fraction * cfg_.guidance.phase(guidance_->phase()).Ts_s * 1e6;
  guidance::Command c = guidance_->step(in, std::max(budget_us - filter_us, 1e-3));  // > 0: a budget
  c.step_time_us += filter_us;
  nav_filter_->command(nav.t_s, c.dv_nominal_mps, c.pulse_s);
  const uint64_t insns = counter_.instructions();

  const bool overrun = c.solver.status == solver::Status::TimeLimit || c.step_time_us > budget_us;
  overruns_ += overrun ? 1 : 0;
  if (c.solved) log_.add(phase_before, nav.step, c.solver.solve_time_us, overrun, insns);
  peak_heap_bytes_ = std::max(peak_heap_bytes_, heap_in_use_bytes());

  out.phase = static_cast<uint8_t>(c.phase);
  out.guidance_status = static_cast<uint8_t>(c.status);
  out.solver_status = solver_status_code(c);
  out.overrun = overrun ? 1 : 0;
  out.period_s = c.period_s;
  for (int i = 0; i < 3; ++i) {
    out.dv_cmd_lvlh_mps[i] = finite_or(c.dv_cmd_mps(i), 0.0);
    out.dv_alloc_lvlh_mps[i] = finite_or(c.dv_alloc_mps(i), 0.0);
  }
  for (int i = 0; i < 6; ++i) out.pulse_s[i] = finite_or(c.pulse_s[i], 0.0);
  out.solve_time_us = c.solved ? finite_or(c.solver.solve_time_us, 0.0) : 0.0;
  out.step_time_us = finite_or(c.step_time_us, 0.0);
  out.instructions = insns;
  out.iterations = static_cast<uint16_t>(c.solved ? c.solver.iterations : 0);
  out.overruns = overruns_;
  out.primal_residual = c.solved ? finite_or(c.solver.primal_residual) : -1.0;
  out.dual_residual = c.solved ? finite_or(c.solver.dual_residual) : -1.0;
  out.objective = c.solved ? finite_or(c.solver.objective, 0.0) : 0.0;
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

void FlightApp::take_obstacles(const Eigen::Vector3d& chaser_lvlh_m) {
  const msg::Obstacles& m = pending_obstacles_;
  std::array<guidance::Obstacle, 8> list{};
  static_assert(sizeof(m.id) / sizeof(m.id[0]) == 8, "one guidance::Obstacle per slot");
  for (int k = 0; k < m.count; ++k) {
    guidance::Obstacle& o = list[k];
    o.id = m.id[k];
    o.t_state_s = m.t_s;
    o.t_seen_s = m.t_seen_s[k];
    for (int j = 0; j < 3; ++j) {
      o.position_lvlh_m(j) = m.position_lvlh_m[3 * k + j];
      o.velocity_lvlh_mps(j) = m.velocity_lvlh_mps[3 * k + j];
      o.semi_axes_m(j) = m.semi_axes_m[3 * k + j];
    }
    o.q_lvlh_body = Eigen::Quaterniond(m.q_lvlh_body[4 * k], m.q_lvlh_body[4 * k + 1], m.q_lvlh_body[4 * k + 2],
                                       m.q_lvlh_body[4 * k + 3]);
  }
  const uint32_t dropped_before = guidance_->obstacles().dropped_total;
  guidance_->set_obstacles(list.data(), m.count, m.t_s, chaser_lvlh_m);
  // The host sensed more than it could send: those are dropped too, for lack of wire capacity.
  if (m.sensed > m.count) guidance_->count_dropped_obstacles(m.sensed - m.count);
  if (guidance_->obstacles().dropped_total != dropped_before)
    note("obstacles step %u: %u sensed, holding the nearest %d (capacity %d)", m.step, m.sensed,
         guidance_->obstacles().count, cfg_.guidance.obstacle_capacity);
  obstacles_step_ = m.step;
  obstacles_received_ = m.sensed > m.count ? m.sensed : m.count;
  have_obstacles_ = false;
  obstacle_status_due_ = true;
}

msg::ObstacleStatus FlightApp::obstacle_status() const {
  const guidance::ObstacleSet& set = guidance_->obstacles();
  msg::ObstacleStatus s;
  s.step = obstacles_step_;
  s.received = static_cast<uint16_t>(std::min<uint32_t>(obstacles_received_, UINT16_MAX));
  s.held = static_cast<uint16_t>(set.count);
  s.capacity = static_cast<uint16_t>(cfg_.guidance.obstacle_capacity);
  s.dropped_total = set.dropped_total;
  s.rejected_total = set.rejected_total + obstacles_rejected_;
  for (int k = 0; k < set.count && k < static_cast<int>(s.held_id.size()); ++k) s.held_id[k] = set.items[k].id;
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
    if (auto nav = take_nav()) {
      t_last_nav = Clock::now();
      if (auto cmd = handle_nav(*nav)) {
        if (take_obstacle_status_due()) publish_msg("obstacle_status", obstacle_status());
        publish_msg("cmd", *cmd);
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
