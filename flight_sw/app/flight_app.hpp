// The flight software as a program: link (Zenoh client + message codec) -> guidance -> link.
//
// On every nav message it runs one step of its guidance law (a plug-in behind
// flight_sw/include/rvd_guidance.h; the three-phase MPC by default) under a deadline (a fraction of the phase's control
// period, on the flight clock: this computer's, or the target's under emulation), publishes the cmd, and keeps the per-phase solve-time
// log that it also sends as telemetry. A nav it already answered (a resend after a lost message) is
// answered again from the cached cmd, so a resend never changes the trajectory. Every message it
// takes must carry this run's tag (msg::LinkAuth, the run's key from link_key.hpp); whatever it
// drops (untagged, mistagged, replayed, another run's, oversized, malformed, stale, too far ahead,
// overtaken) is counted and reported in telemetry. It leaves cleanly on the host's bye or SIGTERM,
// and when the host is gone (link down for host_loss_timeout_s) or silent (idle_timeout_s) it gives
// up after that bound instead of waiting for ever.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "flight_sw/app/link_key.hpp"
#include "flight_sw/app/pmu_counter.hpp"
#include "flight_sw/app/solve_marker.hpp"
#include "flight_sw/guidance/guidance.hpp"
#include "flight_sw/guidance/plugin/mpc_law.hpp"
#include "flight_sw/include/rvd_guidance.h"
#include "flight_sw/link/messages.hpp"
#include "flight_sw/link/zenoh_session.hpp"
#include "flight_sw/nav/nav_filter.hpp"

namespace rvd::app {

struct AppConfig {
  std::string endpoint = "tcp/127.0.0.1:7447";
  std::string run_id = "run";      // msg::check_run_id: letters, digits, '_' and '-'
  LinkKey link_key{};              // the run's key (link_key.hpp); all zero is refused
  // Leave when the link to the host has been down this long (TCP closed or refused, lease expired,
  // handshakes failing): a dead host ends the run within this bound plus one reconnect attempt in
  // progress (at most 3 x 2 s). Not applied with untimed_link.
  double host_loss_timeout_s = 4.0;
  // A nav more than this many steps beyond the last one answered is dropped (counted as future),
  // never adopted: the host numbers its steps 0, 1, 2, ... and only ever moves to the next one.
  uint32_t max_step_ahead = 16;
  // The harness's view of guidance: vehicle, per-phase period, horizon and delta-v limit, geometry
  // (every law gets them in its rvd_guidance_config), and the built-in MPC's full parameters.
  guidance::GuidanceParams guidance;
  // The law: nullptr is the built-in three-phase MPC (guidance::mpc_law()); a plug-in executable
  // passes rvd_guidance_law_entry(). law_params: its --set law.NAME=VALUE parameters.
  const rvd_guidance_law* law = nullptr;
  std::vector<rvd_named_value> law_params;
  // Catch a law's crash (SIGSEGV, SIGBUS, SIGFPE, SIGILL, SIGABRT) and a step still running at the
  // end of its period (SIGALRM) and disable the law instead of dying: the flight executable turns it
  // on; an embedding process (the Python module) keeps its own signal handlers.
  bool guard_law = false;
  // The options this configuration was parsed from, parsed again with --set NAME=VALUE assignments
  // put before them (so the command line still wins: what it sets is pinned). The host's config
  // message is applied through it (main.cpp sets it); empty: config messages are refused.
  std::function<AppConfig(const std::vector<std::string>& sets)> reparse;
  // The navigation filter between the measurements and the guidance; its noise settings are the
  // error model's (the host passes the scenario's sensor and thrust models).
  nav::NavFilterParams nav_filter;
  double deadline_fraction = 0.5;  // solve budget = fraction x Ts of the current phase, on the flight clock
  // The flight clock (solver/elapsed.hpp): 0 = the host's steady_clock; > 0 = target time, the QEMU
  // plugin's instruction count x target_clock_cpi / target_clock_hz (steady_clock, said so, when no
  // plugin answers). Process-wide: the FlightApp sets it when built.
  double target_clock_cpi = 0.0, target_clock_hz = 0.0;
  bool trivial_guidance = false;   // answer every nav with zero thrust at once (link latency benchmark)
  double idle_timeout_s = 300.0;   // give up when no nav arrives for this long after hello
  double connect_timeout_s = 60.0; // give up when the first connection does not come up in this time
  uint32_t lease_ms = 20000;       // generous: emulator stalls must not trip the host's lease check
  // Wait for the host without time limits (link::ZenohConfig::untimed): for QEMU system mode with
  // -icount sleep=off, where the guest clock stands still while the guest waits. The idle and
  // connect timeouts are then not applied either; the host-side runner's limit covers a silent host.
  bool untimed_link = false;
  uint64_t session_seed = 0;       // link::ZenohConfig::seed: 0 random; fixed only for reproducibility checks
  int telemetry_every = 20;        // steps between telemetry messages (and one at the end)
  int markers = -1;                // instruction markers: -1 auto (ARM builds), 0 off, 1 on
  // Count the solves' user-mode instructions with the CPU's own PMU (perf_event_open). For QEMU
  // system mode, where the plugin's markers do not reach: QEMU's emulated PMU counts retired
  // instructions exactly under -icount (Cortex-A53 on virt; the A9 model has no PMU). Never under
  // qemu-user: there the syscall would count the host's instructions.
  bool pmu_instructions = false;
  std::string cpu_model;           // reported in hello (defaults to the build's -mcpu)
  bool verbose = false;
  // Test builds only (rvd_flight_sw_faulty): changes each encoded cmd before it is tagged, to
  // check that the host refuses commands outside the declared limits. Empty in the flight build.
  std::function<void(uint8_t* cmd, size_t size)> corrupt_cmd;
};

// What the flight software did not take as a new step, by reason (telemetry).
struct InputCounters {
  uint32_t malformed = 0;   // layout, type or NaN/Inf (Telemetry::nav_rejected)
  uint32_t duplicates = 0;  // resends, answered again from the cached cmd
  uint32_t stale = 0, future = 0, coalesced = 0;
  uint32_t oversized = 0, untagged = 0, wrong_run = 0, bad_tag = 0, replayed = 0;
  void count(msg::Error e);
};

// Per-phase solve-time log (telemetry). Index 0 rendezvous, 1 approach, 2 docking.
struct PhaseLog {
  std::array<uint32_t, 3> steps{}, overruns{}, max_step{};
  std::array<double, 3> sum_solve_us{}, max_solve_us{};
  std::array<uint64_t, 3> instructions{};
  void add(int phase_index, uint32_t step, double solve_us, bool overrun, uint64_t insns);
};

// What went wrong with a law's step (the harness then commanded zero thrust): cmd guidance_status
// law_fault, counted in telemetry and logged.
enum class LawFault : uint8_t { None = 0, Failed, NotFinite, OutOfLimit, Overrun, Allocated, Crashed, Blocked, Disabled };
const char* to_string(LawFault f);

enum class ExitReason { Bye = 0, Signal = 1, LinkLost = 3, Idle = 4, NeverConnected = 5 };  // LinkLost: the host is gone
const char* to_string(ExitReason r);

// Brackets each solver call with the instruction counters and sums the counts of a step: the QEMU
// plugin's markers (user mode) or the PMU (system mode, when enabled and available).
class SolveCounter : public guidance::SolveObserver {
 public:
  SolveCounter(bool markers, bool pmu) : marker_(markers) {
    if (pmu) pmu_.open();
  }
  void start_step(uint32_t step) { step_ = step; instructions_ = 0; }
  void before_solve() override {
    marker_.begin(step_);
    pmu_.start();
  }
  void after_solve() override {
    const uint64_t pmu = pmu_.stop();
    const uint64_t plugin = marker_.end(step_);
    instructions_ += plugin ? plugin : pmu;
  }
  uint64_t instructions() const { return instructions_; }
  const PmuCounter& pmu() const { return pmu_; }

 private:
  SolveMarker marker_;
  PmuCounter pmu_;
  uint32_t step_ = 0;
  uint64_t instructions_ = 0;
};

class FlightApp {
 public:
  explicit FlightApp(AppConfig config);  // throws std::invalid_argument on unusable parameters (run id, key, ...)
  // Runs until bye, `stop` becoming true, a permanently lost link or the idle timeout.
  ExitReason run(const std::atomic<bool>& stop);

  // One nav -> one cmd, without the link (also what the tests drive). nullopt for a nav that is
  // dropped (older than the last one answered, too far ahead, not starting a run): nothing to send.
  std::optional<msg::Cmd> handle_nav(const msg::Nav& nav);
  // The bytes of one sample from the host, as the link delivers them: checked (LinkAuth::open,
  // decode), counted when dropped; a nav becomes the pending one (a pending nav it replaces is
  // counted as coalesced), a genuine bye ends the run.
  void receive_nav(const uint8_t* data, size_t size);
  void receive_bye(const uint8_t* data, size_t size);
  // An obstacles message: checked like a nav, kept until the next nav is handled, which gives it
  // to the guidance (the nearest it can hold) before its step; obstacle_status() then says what it holds.
  void receive_obstacles(const uint8_t* data, size_t size);
  void accept_obstacles(const msg::Obstacles& m);  // an authentic, decoded one (the in-process path)
  msg::ObstacleStatus obstacle_status() const;
  // A chaser_attitude message (the planar truth): checked like a nav, given to the law with the next
  // nav; the torque the law commands then goes out before that step's cmd (torque_for()).
  void receive_chaser_attitude(const uint8_t* data, size_t size);
  void accept_chaser_attitude(const msg::ChaserAttitude& m);  // an authentic, decoded one (the in-process path)
  // The torque message of step k, when that step had the chaser's attitude (also for a resent nav).
  std::optional<msg::Torque> torque_for(uint32_t step) const {
    if (last_torque_ && last_torque_->step == step) return last_torque_;
    return std::nullopt;
  }
  void receive_config(const uint8_t* data, size_t size);
  // The host's vehicle and guidance settings: rebuilds the law with them (the command line wins for
  // what it sets) and returns the echo, what the flight software now uses (status 1 and the reason
  // when they cannot be applied; the previous configuration then stays).
  msg::Config apply_config(const msg::Config& host);
  // The law message of the last step (its named values and faults), if there is anything to say.
  std::optional<msg::Law> law_message() const;
  // True once after a step that took an obstacles message: its obstacle_status goes out before the cmd.
  bool take_obstacle_status_due() {
    const bool due = obstacle_status_due_;
    obstacle_status_due_ = false;
    return due;
  }
  // Takes the pending nav, if any.
  std::optional<msg::Nav> take_nav();
  bool bye_received() const { return bye_received_; }
  const InputCounters& dropped() const { return dropped_; }
  const PhaseLog& log() const { return log_; }
  msg::Telemetry telemetry() const;
  msg::Hello hello(uint32_t session) const;
  const char* law_name() const { return law_->name ? law_->name : "unnamed"; }
  // The built-in MPC's guidance (its last QPs and plans), or nullptr when a plug-in law flies.
  const guidance::Guidance* built_in_guidance() const {
    return law_ == guidance::mpc_law() ? guidance::mpc_law_guidance(law_state_) : nullptr;
  }
  // Law faults so far, by kind (index LawFault), and the last one.
  const std::array<uint32_t, 9>& law_faults() const { return law_faults_; }
  LawFault last_law_fault() const { return last_fault_; }
  // The law's named telemetry values of the last step.
  const rvd_guidance_output& last_law_output() const { return law_out_; }
  ~FlightApp();

 private:
  template <class M> void publish_msg(const char* kind, const M& m);
  void note_drop(const char* kind, msg::Error e, size_t size);
  std::string key(const char* kind) const;
  void note(const char* fmt, ...) const;

  AppConfig cfg_;
  msg::LinkAuth auth_;
  // Runs the law's step under the harness's guard; fills law_out_. Returns what went wrong.
  LawFault step_law(const rvd_nav_input& in, double budget_s, double hard_limit_s, double& step_us);
  void create_law();  // from cfg_ (throws std::invalid_argument)
  msg::Config config_echo() const;

  const rvd_guidance_law* law_ = nullptr;
  void* law_state_ = nullptr;
  bool law_disabled_ = false;
  guidance::Phase phase_ = guidance::Phase::Rendezvous;  // the law's phase after its last step
  rvd_guidance_output law_out_{};
  std::array<uint32_t, 9> law_faults_{};
  uint32_t law_faults_total_ = 0;
  std::optional<msg::Config> pending_echo_;  // to publish (run loop)
  LawFault last_fault_ = LawFault::None;
  std::unique_ptr<nav::NavFilter> nav_filter_;
  std::unique_ptr<link::ZenohSession> session_;
  SolveCounter counter_;
  PhaseLog log_;
  std::optional<msg::Cmd> last_cmd_;
  msg::Nav pending_nav_{};
  bool have_nav_ = false;
  bool bye_received_ = false;
  msg::Obstacles pending_obstacles_{};
  bool have_obstacles_ = false, obstacle_status_due_ = false;
  uint32_t obstacles_step_ = 0, obstacles_received_ = 0, obstacles_rejected_ = 0;
  // The pending obstacles into the law's input; after its step, what it holds (for obstacle_status).
  void put_obstacles(rvd_nav_input& li) const;
  void note_obstacles_held(const rvd_nav_input& li);
  msg::ObstacleStatus obstacles_held_{};
  msg::ChaserAttitude pending_attitude_{};
  bool have_attitude_ = false;
  std::optional<msg::Torque> last_torque_;
  InputCounters dropped_;
  uint32_t drops_noted_ = 0;
  uint32_t overruns_ = 0;
  uint64_t peak_heap_bytes_ = 0;
};

}  // namespace rvd::app
