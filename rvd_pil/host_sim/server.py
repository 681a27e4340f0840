"""The host side of the PIL link: serves navigation over Zenoh and applies the flight software's commands.

One control step k (lockstep, the default):

    measure -> put nav k -> wait for cmd k (resend nav k on timeout) -> apply pulses -> record step k

Simulated time advances only when cmd k has arrived, so an emulated CPU 40x slower than real time
still gives exact results. A flight software that stays silent through every resend is a recorded
fault ("flight software lost"), never a hang. In real-time pacing mode the server does not wait: each
period lasts `period_s / speedup` of wall time, and a command that misses it is recorded as late and
not applied.

Every message is sealed and opened with the run's key (messages.LinkAuth): what another Zenoh
session publishes on the run's keys is dropped and counted by kind (untagged, bad tag, replayed,
wrong run, oversized, malformed), never applied. Every command is checked against the limits the
flight software declared in its hello (`check_cmd`: its step, the period of its phase, finite pulses
between 0 and the phase's longest pulse, no phase going back); one that breaks them is a recorded
flight fault that ends the run, and it is not applied.

The command is applied after a control delay taken from the command itself (`delay_model`):
"none" applies it at t_k (the dissertation's assumption), "reported" at t_k + the flight computer's
measured guidance step time, "estimated" at t_k + instructions x CPI / f_clk of a CPU model.
"""
from __future__ import annotations

import math
import queue
import secrets
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from rvd_pil.host_sim import messages as msg
from rvd_pil.host_sim.obstacles import ObstacleField
from rvd_pil.host_sim.scenario import settings_text
from rvd_pil.host_sim.safety import UNITS as SAFETY_UNITS, SafetyMonitor, describe as describe_safety_episode

PHASE_NAMES = {1: "rendezvous", 2: "approach", 3: "docking", 4: "docked"}
SOLVER_STATUS = {0: "solved", 1: "max_iter", 2: "infeasible", 3: "invalid_input", 4: "numerical_error",
                 5: "time_limit", 255: "not_run"}
GUIDANCE_STATUS = {0: "ok", 1: "shifted_plan", 2: "zero_thrust", 3: "invalid_state", 4: "docked", 5: "recovered",
                   6: "law_fault"}
#: What went wrong with a guidance law's step (the law message's fault; flight_sw/app LawFault).
LAW_FAULTS = {1: "step returned an error", 2: "NaN or Inf in the command", 3: "command outside the phase's limits",
              4: "step returned after its budget", 5: "step allocated heap memory",
              6: "step crashed (signal); law disabled", 7: "step still running at the end of its period; law disabled",
              8: "law disabled"}


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """A TCP port nobody listens on right now (bind to port 0 and let the kernel pick)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


#: Obstacle slots of one obstacles message (schema/rvd_messages.toml).
OBSTACLE_SLOTS = 8


def obstacles_message(field: ObstacleField, step: int, t_s: float, chaser_lvlh_m) -> msg.Obstacles:
    """What the chaser senses at t_s as the obstacles message of step k: the nearest OBSTACLE_SLOTS
    (distance to the zone's surface along the line to its centre), their true states (the sensor
    model is exact), shapes and first-seen times."""
    chaser = np.asarray(chaser_lvlh_m, float)
    seen = field.sensed(t_s, chaser)

    def surface_distance(item):
        o, x, _ = item
        d = chaser - x[0:3]
        scaled = math.sqrt(max(float(d @ field.shape(o) @ d), 0.0))
        return float(np.linalg.norm(d)) * (1.0 - 1.0 / scaled) if scaled > 0.0 else -min(o.semi_axes_m)

    nearest = sorted(seen, key=surface_distance)[:OBSTACLE_SLOTS]
    pad = OBSTACLE_SLOTS - len(nearest)
    ids, seen_t, pos, vel, axes, q = [], [], [], [], [], []
    for o, x, first in nearest:
        ids.append(int(o.id))
        seen_t.append(float(first))
        pos += [float(v) for v in x[0:3]]
        vel += [float(v) for v in x[3:6]]
        axes += [float(v) for v in o.semi_axes_m]
        q += [float(v) for v in np.asarray(o.q_lvlh_body, float) / np.linalg.norm(o.q_lvlh_body)]
    return msg.Obstacles(step=int(step), count=len(nearest), sensed=len(seen), t_s=float(t_s),
                         id=tuple(ids + [0] * pad), t_seen_s=tuple(seen_t + [0.0] * pad),
                         position_lvlh_m=tuple(pos + [0.0] * 3 * pad), velocity_lvlh_mps=tuple(vel + [0.0] * 3 * pad),
                         semi_axes_m=tuple(axes + [0.0] * 3 * pad), q_lvlh_body=tuple(q + [0.0] * 4 * pad))


@dataclass
class InvalidMessage:
    """An authentic message from the flight software whose content breaks the rules (e.g. NaN):
    queued like a message, so that the control loop records it as a flight fault."""
    kind: str      # "hello", "cmd", ...
    step: int      # the step field for a cmd (read from the raw bytes), else -1
    reason: str


#: What the host counts when it drops a message from the link (MessageError.kind).
DISCARD_KINDS = ("oversized", "untagged", "wrong_run", "bad_tag", "replayed", "malformed")


class ZenohLink:
    """The host's Zenoh session for one run: publishes nav/bye, queues what the flight side sends.

    `mode` is "peer" or "router"; either way it listens on `endpoint` (e.g. "tcp/127.0.0.1:7447") and the
    flight software connects to it as a Zenoh client. Every message goes out sealed and comes in opened
    with `link_key` (messages.LinkAuth, the host's end); what does not open is counted by kind in
    `discarded` and kept with the reason in `rejected` (key, kind, reason), never raised into the
    control loop.
    """

    def __init__(self, run_id: str, endpoint: str, mode: str = "peer", lease_ms: int | None = None,
                 zenoh_id: str | None = None, link_key: bytes | None = None):
        import zenoh  # imported here so that host_sim's physics does not need Zenoh

        if mode not in ("peer", "router"):
            raise ValueError(f"mode must be 'peer' or 'router', not {mode!r}")
        msg.check_run_id(run_id)
        self.run_id, self.endpoint, self.mode, self.lease_ms = run_id, endpoint, mode, lease_ms
        self.zenoh_id = zenoh_id
        self.link_key = link_key if link_key is not None else secrets.token_bytes(msg.KEY_SIZE)
        self.auth = msg.LinkAuth(self.link_key, run_id, "host")
        self._zenoh = zenoh
        self.inbox: "queue.Queue[tuple[float, object]]" = queue.Queue()
        self.rejected: "queue.Queue[tuple[str, str, str]]" = queue.Queue()
        self.discarded = {k: 0 for k in DISCARD_KINDS}
        self._count_lock = threading.Lock()
        self.session = None
        self._subs = []

    def open(self) -> None:
        z = self._zenoh
        conf = z.Config()
        conf.insert_json5("mode", f'"{self.mode}"')
        conf.insert_json5("listen/endpoints", f'["{self.endpoint}"]')
        conf.insert_json5("scouting/multicast/enabled", "false")
        if self.zenoh_id:  # Zenoh derives the initial sequence numbers from both ZenohIDs
            conf.insert_json5("id", f'"{self.zenoh_id}"')
        if self.lease_ms:  # keep-alives go out every lease/4 when the link is idle
            conf.insert_json5("transport/link/tx/lease", str(int(self.lease_ms)))
        self.session = z.open(conf)
        # indirect=False: run the (short) callback on Zenoh's receive thread. The default gives each
        # subscriber its own Python thread, which reorders messages across keys (a bye overtaking
        # the telemetry sent before it); the flight side's order is part of the protocol.
        # allowed_origin REMOTE: the host's own bye (same key) is not delivered back to it.
        for kind, cls in (("hello", msg.Hello), ("cmd", msg.Cmd), ("telemetry", msg.Telemetry), ("bye", msg.Bye),
                          ("obstacle_status", msg.ObstacleStatus), ("config_echo", msg.Config), ("law", msg.Law),
                          ("torque", msg.Torque)):
            self._subs.append(self.session.declare_subscriber(
                msg.key(kind, self.run_id),
                z.handlers.Callback(lambda sample, kind=kind, cls=cls: self._on_sample(sample, kind, cls),
                                    indirect=False),
                allowed_origin=z.Locality.REMOTE))

    def _on_sample(self, sample, kind: str, cls) -> None:
        data = sample.payload.to_bytes()
        try:
            m = self.auth.open(data, expect=cls)
        except msg.MessageError as exc:
            if exc.kind == "invalid":  # authentic: the flight software's own fault
                step = int.from_bytes(data[msg.HEADER_SIZE:msg.HEADER_SIZE + 4], "little") if cls is msg.Cmd else -1
                self.inbox.put((time.monotonic(), InvalidMessage(kind, step, str(exc))))
                return
            with self._count_lock:
                self.discarded[exc.kind if exc.kind in self.discarded else "malformed"] += 1
            self.rejected.put((str(sample.key_expr), exc.kind, str(exc)))
            return
        self.inbox.put((time.monotonic(), m))

    def discarded_total(self) -> int:
        with self._count_lock:
            return sum(self.discarded.values())

    def put(self, kind: str, message) -> None:
        self.put_raw(kind, self.auth.seal(message))

    def put_raw(self, kind: str, data: bytes) -> None:
        """Publish arbitrary bytes on a message key (also for fault-injection tests). Blocking congestion
        control: Zenoh's default for puts drops a message when the transmission queue has no room
        within a millisecond, which a loaded machine can hit; every host message must arrive (a lost
        nav costs a resend timeout), and a dead peer still ends the wait when Zenoh closes its link."""
        self.session.put(msg.key(kind, self.run_id), data,
                         congestion_control=self._zenoh.CongestionControl.BLOCK)

    def get(self, timeout_s: float):
        """Next decoded message from the flight side, or None after `timeout_s`."""
        try:
            return self.inbox.get(timeout=max(timeout_s, 0.0))[1]
        except queue.Empty:
            return None

    def close(self) -> None:
        for s in self._subs:
            try:
                s.undeclare()
            except Exception:  # the session may already be gone; closing must not fail
                pass
        self._subs.clear()
        if self.session is not None:
            self.session.close()
            self.session = None

    def restart(self) -> None:
        """Close and reopen the session on the same endpoint (the flight side must reconnect)."""
        self.close()
        self.open()


@dataclass
class ServerConfig:
    run_id: str = "run"
    endpoint: str = "tcp/127.0.0.1:7447"
    mode: str = "peer"                 # Zenoh mode of the host session: "peer" or "router"
    zenoh_lease_ms: int | None = None  # host session lease (None: Zenoh's 10 s); keep-alives every lease/4
    # Fixed ZenohID of the host session (hex; None: random). When the flight's ZID repeats too,
    # every message of a run is the same byte for byte from run to run (Zenoh derives the initial
    # sequence numbers from the two ZIDs), as the bit-exact system-mode timing check needs.
    zenoh_id: str | None = None
    lockstep: bool = True              # False: real-time pacing
    speedup: float = 1.0               # real-time pacing: simulated seconds per wall second
    hello_timeout_s: float = 60.0      # wait for the flight software to connect (QEMU boots take seconds)
    cmd_timeout_s: float = 10.0        # lockstep: wait this long for cmd k before resending nav k
    nav_retries: int = 3               # lockstep: resends of nav k before declaring the flight software lost
    delay_model: str = "none"          # "none", "reported" or "estimated"
    cpi: float = 1.0                   # "estimated" delay: cycles per instruction of the target CPU model
    clock_hz: float = 1.0e9            # "estimated" delay: target clock
    # Truth distance chaser-port that confirms the flight software's "docked": its r3 (0.5 m) plus
    # 3 sigma of the 3-D position noise it decides on (5 cm per axis: 0.26 m).
    docking_tolerance_m: float = 0.75
    collision_radius_m: float = 0.3    # truth distance to the target CoM that counts as a collision
    max_steps: int = 100000
    # The run's link key (KEY_SIZE bytes); None: a fresh random one. Handed to the flight software
    # outside its command line (rvd_pil.host_sim.pil), never written to the record.
    link_key: bytes | None = field(default=None, repr=False)
    drop_nav: Callable[[int, int], bool] = field(default=lambda k, attempt: False)  # fault injection
    # One configuration: the scenario's vehicle and [guidance] settings go to the flight software after
    # its hello (config message); the run starts only when its echo names the vehicle the truth
    # simulates, unless a mismatch is asked for (a robustness study: the flight plans with another one).
    send_config: bool = True
    allow_vehicle_mismatch: bool = False

    def host_speed_dependent(self, hello=None) -> dict:
        """The settings whose effect depends on how fast this host (or the emulator on it) runs,
        each with what it changes: named in the summary and the run record."""
        out = {}
        # The flight clock on target time (hello step_clock 1: instructions x CPI / f_clk) makes the
        # flight's step times and deadlines independent of this host; otherwise they are its clock's.
        target_clock = getattr(hello, "step_clock", 0) == 1
        if self.delay_model == "reported" and not target_clock:
            out["delay_model"] = "reported: each command is applied after the flight computer's measured step time"
        elif self.delay_model == "estimated" and not target_clock:
            out["delay_model"] = ("estimated: instructions x CPI / f_clk, or the measured step time where no "
                                  "instruction count came")
        if not self.lockstep:
            out["pacing"] = f"real time at {self.speedup:g}x: a command later than its period is not applied"
        else:
            out["cmd_timeout_s"] = (f"{self.cmd_timeout_s:g} s per attempt, {self.nav_retries + 1} attempts: a "
                                    "slower flight computer is declared lost")
        out["hello_timeout_s"] = f"{self.hello_timeout_s:g} s for the flight software to connect"
        if hello is not None and not target_clock:
            out["flight_deadline_fraction"] = (f"{hello.deadline_fraction:g} x Ts on the flight computer's clock: a "
                                               "slower one falls back to the shifted plan or zero thrust")
        return out


@dataclass
class RunSummary:
    end: str                            # "docked", "held", "collision", "timeout", "flight software lost", ...
    steps: int
    t_s: float
    dv_total_mps: float
    dv_per_phase_mps: dict
    time_per_phase_s: dict
    docked: bool
    final_range_to_port_m: float
    dv_l1_mps: float = 0.0              # sum of thruster delta-v magnitudes (propellant view)
    hello: Optional[object] = None
    telemetry: Optional[object] = None
    nav_resends: int = 0
    late_commands: int = 0
    rejected_messages: int = 0          # messages the host dropped (sum of `discarded`)
    stale_commands: int = 0             # cmds for an older step (duplicate_commands included)
    duplicate_commands: int = 0         # cmds for the step just applied (the answer to a resent nav)
    future_commands: int = 0            # cmds for a step not asked for yet
    obstacle_status: Optional[object] = None  # the flight software's newest ObstacleStatus (runs with obstacles)
    invalid_commands: int = 0           # authentic cmds outside the declared limits: flight faults
    discarded: dict = field(default_factory=dict)          # host side, by kind (DISCARD_KINDS)
    flight_discarded: dict = field(default_factory=dict)   # flight side, from its last telemetry
    host_speed_dependent: dict = field(default_factory=dict)
    events: list = field(default_factory=list)
    safety: dict = field(default_factory=dict)    # rvd_pil.host_sim.safety.SafetyMonitor.summary(): verdict on truth
    flight_config: Optional[dict] = None          # the flight software's config echo: what it plans with
    law_faults: int = 0                           # guidance law faults (the harness commanded zero thrust)
    law_values: list = field(default_factory=list)  # (step, {name: value}) the law logged
    held: bool = False                            # a rendezvous to a holding distance reached it (scenario hold_range_m)

    @property
    def reached(self) -> bool:
        """The run did what its scenario asks: docked, or reached its holding distance."""
        return self.docked or self.held

    def table(self) -> str:
        lines = [f"{'phase':<12}{'delta-v [m/s]':>15}{'time [s]':>12}"]
        for ph in ("rendezvous", "approach", "docking"):
            lines.append(f"{ph:<12}{self.dv_per_phase_mps.get(ph, 0.0):>15.4f}{self.time_per_phase_s.get(ph, 0.0):>12.1f}")
        lines.append(f"{'total':<12}{self.dv_total_mps:>15.4f}{self.t_s:>12.1f}")
        return "\n".join(lines)


#: The flight software's discard counters in its telemetry (Telemetry field names).
FLIGHT_DISCARD_FIELDS: tuple[str, ...] = (
    "nav_rejected", "nav_duplicates", "nav_stale", "nav_future", "nav_coalesced", "rx_oversized",
    "rx_untagged", "rx_wrong_run", "rx_bad_tag", "rx_replayed", "link_losses", "link_resyncs",
    "link_rx_rejected", "link_rx_unmatched",
)


def check_cmd(cmd, hello, step: int, last_phase: int) -> Optional[str]:
    """Why an authentic command breaks the limits the flight software declared in `hello`, or None.

    Checked: the step it answers, a known phase not going back, the control period of that phase
    (exactly as declared), every number finite, every pulse between 0 and the phase's longest
    declared pulse (and never longer than the period)."""
    if cmd.step != step:
        return f"answers step {cmd.step}, not {step}"
    if cmd.phase not in PHASE_NAMES:
        return f"unknown phase {cmd.phase}"
    if cmd.phase < last_phase:
        return f"phase {PHASE_NAMES[cmd.phase]} after {PHASE_NAMES[last_phase]}"
    i = min(cmd.phase, 3) - 1
    period = float(hello.period_s[i])
    values = [cmd.period_s, *cmd.pulse_s, *cmd.dv_cmd_lvlh_mps, *cmd.dv_alloc_lvlh_mps]
    if not all(math.isfinite(v) for v in values):
        return "NaN or Inf in the command"
    if cmd.period_s != period:
        return f"period_s {cmd.period_s!r} s is not the declared period {period!r} s of {PHASE_NAMES[min(cmd.phase, 3)]}"
    cap = min(float(hello.max_pulse_s[i]), period)
    for j, p in enumerate(cmd.pulse_s):
        if p < 0.0:
            return f"pulse_s[{j}] = {p!r} s is negative"
        if p > cap * (1 + 1e-12):
            return f"pulse_s[{j}] = {p!r} s is longer than the declared {cap!r} s"
    return None


def vehicle_mismatch(echo, scenario) -> Optional[str]:
    """How the vehicle the flight software plans with (its config echo) differs from the truth's, or None."""
    truth = {"mass_kg": scenario.chaser.mass_kg, "thrust_n": scenario.thrusters.force_n,
             "min_impulse_bit_s": scenario.thrusters.minimum_impulse_bit_s}
    diff = [f"{k} {getattr(echo, k)!r} (truth {v!r})" for k, v in truth.items() if getattr(echo, k) != v]
    return ", ".join(diff) or None


def check_hello(hello) -> Optional[str]:
    """Why a hello cannot serve as the flight software's declared limits, or None."""
    for name in ("period_s", "max_pulse_s"):
        v = getattr(hello, name)
        if not all(math.isfinite(x) and x > 0 for x in v):
            return f"{name} {tuple(v)} must be finite and positive"
    return None


#: Per-step columns the server adds to the run record (flight-side telemetry of each command).
FLIGHT_COLUMNS: tuple[str, ...] = (
    "phase", "guidance_status", "solver_status", "overrun", "overruns", "cmd_period_s",
    "solve_time_us", "step_time_us", "instructions", "iterations",
    "primal_residual", "dual_residual", "objective",
    "dv_cmd_x_mps", "dv_cmd_y_mps", "dv_cmd_z_mps", "dv_alloc_x_mps", "dv_alloc_y_mps", "dv_alloc_z_mps",
    "nav_attempts", "round_trip_ms",
)
#: Per-step columns of a planar run (the chaser's rotation): true angle and rate at the step, the
#: measured angle, the torque applied over the period.
PLANAR_COLUMNS: tuple[str, ...] = ("chaser_angle_rad", "chaser_rate_rad_s", "meas_chaser_angle_rad", "torque_z_nm")
#: Per-step columns of the safety monitor: the worst true margins over the period's path
#: (corridor: distance outside the approach corridor; axial: distance along the docking axis;
#: dock cone: distance outside the docking cone; speed: |v|_inf).
SAFETY_COLUMNS: tuple[str, ...] = ("safety_corridor_m", "safety_axial_m", "safety_dock_cone_m",
                                   "safety_speed_inf_mps", "safety_range_m")


_FALLBACK_MEANING = {
    1: "the previous plan's next delta-v was commanded",
    2: "zero thrust was commanded (no plan of this phase left)",
    3: "the navigation input was rejected; the previous plan's next delta-v or zero was commanded",
    5: "the phase QP was infeasible; the recovery QP (hard state rows made elastic) was solved and its first "
       "delta-v commanded",
}


def _fallback_text(cmd) -> str:
    status = GUIDANCE_STATUS.get(cmd.guidance_status, str(cmd.guidance_status))
    solver = SOLVER_STATUS.get(cmd.solver_status, str(cmd.solver_status))
    dv = ", ".join(f"{v:+.4f}" for v in cmd.dv_cmd_lvlh_mps)
    return (f"{PHASE_NAMES.get(cmd.phase, cmd.phase)}: {status} (solver {solver}): "
            f"{_FALLBACK_MEANING.get(cmd.guidance_status, '')}; dv [{dv}] m/s")


class PilServer:
    """Runs one scenario against a flight software connected over Zenoh.

    `sim` is a host_sim Simulator; `record` a RunRecorder created with `extra_columns=FLIGHT_COLUMNS`
    (or None). `on_step(k, summary_so_far)` is called after every step (progress display).
    """

    def __init__(self, sim, config: ServerConfig, record=None, on_step=None,
                 flight_exited: Optional[Callable[[], Optional[str]]] = None):
        """`flight_exited()` returns None while the flight software runs, else why it is gone (e.g. its
        exit code): the server then stops waiting at once instead of running out its timeouts."""
        self.sim, self.cfg, self.record, self.on_step = sim, config, record, on_step
        self.flight_exited = flight_exited or (lambda: None)
        self.link = ZenohLink(config.run_id, config.endpoint, config.mode, config.zenoh_lease_ms, config.zenoh_id,
                              link_key=config.link_key)
        self.summary = RunSummary(end="running", steps=0, t_s=0.0, dv_total_mps=0.0,
                                  dv_per_phase_mps={p: 0.0 for p in ("rendezvous", "approach", "docking")},
                                  time_per_phase_s={p: 0.0 for p in ("rendezvous", "approach", "docking")},
                                  docked=False, final_range_to_port_m=math.nan)
        self._stop = threading.Event()
        self._rejection_events: dict[str, int] = {}
        self._torques: dict[int, object] = {}  # planar runs: the torque message of each step, until applied
        self.planar = bool(getattr(sim.scenario, "is_planar", False))
        sigma_w = math.sqrt(sim.scenario.thrust_error.steady_state_covariance()[0, 0])
        # The scenario's obstacles, moving with the truth's mean motion (rvd_pil.host_sim.obstacles).
        self.obstacles = ObstacleField(sim.scenario.obstacles, sim.mean_motion_rad_s)
        self.safety = SafetyMonitor(sim.scenario.safety, sim.target_state, sigma_w, on_event=self._safety_event,
                                    obstacles=self.obstacles)

    # -- helpers -----------------------------------------------------------------------------------
    def event(self, kind: str, detail: str = "", step: Optional[int] = None) -> None:
        self.summary.events.append((self.sim.t_s, kind, detail))
        if self.record is not None:
            self.record.log_event(kind, detail, step=step, t_s=self.sim.t_s)

    def _safety_event(self, kind: str, episode) -> None:
        detail = describe_safety_episode(kind, episode, SAFETY_UNITS[episode.limit])
        self.summary.events.append((episode.worst_t_s, kind, detail))
        if self.record is not None:
            self.record.log_event(kind, detail, step=episode.worst_step, t_s=episode.worst_t_s)

    def stop(self) -> None:
        """Ask a running run() to end after the current step (e.g. on SIGINT)."""
        self._stop.set()

    # At most this many events per kind of dropped message; the rest are counted (a flood must not
    # fill the record).
    MAX_REJECTION_EVENTS = 50

    def _log_rejections(self) -> None:
        """Record what the link dropped since the last call (one event each, up to a cap per kind)."""
        while True:
            try:
                key, kind, reason = self.link.rejected.get_nowait()
            except queue.Empty:
                break
            self._rejection_events[kind] = n = self._rejection_events.get(kind, 0) + 1
            if n <= self.MAX_REJECTION_EVENTS:
                self.event("rejected_message", f"{kind}: {key}: {reason}")
            elif n == self.MAX_REJECTION_EVENTS + 1:
                self.event("rejected_message_cap", f"{kind}: more than {self.MAX_REJECTION_EVENTS}; only counted from now on")

    def _take(self, message):
        """Route side messages (hello, telemetry, bye); return a Cmd, a Bye or an InvalidMessage, else None."""
        self._log_rejections()
        if isinstance(message, msg.Hello):
            self.summary.hello = message
            self.event("hello", f"{message.arch} {message.cpu_model} session {message.session}")
        elif isinstance(message, msg.Telemetry):
            self._take_telemetry(message)
        elif isinstance(message, msg.ObstacleStatus):
            self._take_obstacle_status(message)
        elif isinstance(message, msg.Law):
            self._take_law(message)
        elif isinstance(message, msg.Torque):
            self._torques[message.step] = message
            for old in [k for k in self._torques if k < message.step - 4]:
                del self._torques[old]
        elif isinstance(message, msg.Config):
            return message
        elif isinstance(message, (msg.Cmd, msg.Bye, InvalidMessage)):
            return message
        return None

    def _take_law(self, m) -> None:
        """A guidance law's named values for a step (kept for the record), or a law fault (an event)."""
        if m.fault:
            self.summary.law_faults = max(self.summary.law_faults, m.faults)
            n = self._rejection_events["law_fault"] = self._rejection_events.get("law_fault", 0) + 1
            if n <= self.MAX_REJECTION_EVENTS:
                self.event("law_fault", f"step {m.step}: {LAW_FAULTS.get(m.fault, m.fault)}: the flight software "
                                        "commanded zero thrust", step=m.step)
            elif n == self.MAX_REJECTION_EVENTS + 1:
                self.event("law_fault_cap", f"more than {self.MAX_REJECTION_EVENTS} law faults; only counted from now on")
        if m.n_values:
            names = m.names.split(",")[:m.n_values]
            self.summary.law_values.append((m.step, dict(zip(names, m.values[:m.n_values]))))

    def _configure(self) -> bool:
        """Send the scenario's vehicle and guidance settings, take the echo and the hello that follows it;
        False (the run's end set) when the flight software refuses them or plans with another vehicle."""
        cfg, s, sc = self.cfg, self.summary, self.sim.scenario
        settings = settings_text(getattr(sc, "guidance", {}) or {})
        host = msg.Config(mass_kg=float(sc.chaser.mass_kg), thrust_n=float(sc.thrusters.force_n),
                          min_impulse_bit_s=float(sc.thrusters.minimum_impulse_bit_s), settings=settings)
        self.link.put("config", host)
        deadline = time.monotonic() + cfg.hello_timeout_s
        echo, hello = None, None
        while (echo is None or hello is None) and time.monotonic() < deadline:
            before = s.hello
            m = self._take(self.link.get(min(deadline - time.monotonic(), 0.2)))
            if isinstance(m, msg.Config):
                echo = m
            elif isinstance(m, InvalidMessage):
                s.end = f"flight fault: invalid {m.kind} ({m.reason})"
                self.event("flight_fault", s.end)
                return False
            elif echo is not None and s.hello is not before:
                hello = s.hello
            if echo is None and self.flight_exited() is not None and self.inbox_empty():
                break
        if echo is None or hello is None:
            s.end = "flight software did not answer the configuration"
            self.event("fault", f"no config echo and hello within {cfg.hello_timeout_s:g} s")
            return False
        s.flight_config = {k: getattr(echo, k) for k in msg.field_names(msg.Config)}
        self.event("flight_config", f"law {echo.law}: mass {echo.mass_kg!r} kg, thrust {echo.thrust_n!r} N, "
                                    f"minimum impulse bit {echo.min_impulse_bit_s!r} s, horizons {tuple(echo.horizon)}, "
                                    f"periods {tuple(echo.period_s)} s, settings '{echo.settings}'")
        if echo.status != 0:
            s.end = f"flight software refused the configuration: {echo.text}"
            self.event("config_refused", s.end)
            return False
        if (why := vehicle_mismatch(echo, sc)) is not None:
            if not cfg.allow_vehicle_mismatch:
                s.end = f"vehicle mismatch: the flight software plans with {why}"
                self.event("vehicle_mismatch", s.end + "; refused (allow a mismatch explicitly for a robustness study)")
                return False
            self.event("vehicle_mismatch", f"allowed: the flight software plans with {why}")
        return True

    def _take_telemetry(self, t) -> None:
        """Keep the newest telemetry; record what the flight software dropped since the last one."""
        before = self.summary.flight_discarded
        now = {f: int(getattr(t, f)) for f in FLIGHT_DISCARD_FIELDS}
        grew = {f: v - before.get(f, 0) for f, v in now.items() if v > before.get(f, 0)}
        if grew:
            self.event("flight_discarded", ", ".join(f"{f} +{d}" for f, d in grew.items()))
        self.summary.telemetry = t
        self.summary.flight_discarded = now

    def _take_obstacle_status(self, st) -> None:
        """Keep the newest; an event whenever what the flight software holds changes."""
        before = self.summary.obstacle_status
        held = tuple(st.held_id[:st.held])
        if before is None or held != tuple(before.held_id[:before.held]) or st.dropped_total != before.dropped_total \
                or st.rejected_total != before.rejected_total:
            self.event("flight_obstacles",
                       f"holds {st.held} of {st.received} (capacity {st.capacity}): ids {list(held)}; dropped "
                       f"{st.dropped_total}, rejected {st.rejected_total} so far", step=st.step)
        self.summary.obstacle_status = st

    def _put_obstacles(self, k: int, t_s: float) -> None:
        """The obstacles message of step k, before its nav (only in scenarios with obstacles), and on an
        air-bearing table the chaser's measured attitude."""
        if len(self.obstacles):
            self.link.put("obstacles", obstacles_message(self.obstacles, k, t_s, self.sim.truth_lvlh()[0:3]))
        if self.planar:
            meas = self.sim.measure()
            self.link.put("chaser_attitude", msg.ChaserAttitude(
                step=int(k), reserved=0, t_s=float(t_s), q_lvlh_chaser=tuple(float(v) for v in meas.chaser_q_lvlh),
                omega_chaser_rad_s=tuple(float(v) for v in meas.chaser_omega_rad_s)))

    def _torque(self, k: int) -> tuple[float, Optional[str]]:
        """Planar runs: the torque about z the flight software commanded with cmd k (0 when none came),
        or why it cannot be applied."""
        m = self._torques.pop(k, None)
        if m is None:
            self.event("no_torque", f"no torque message for step {k}: zero torque applied", step=k)
            return 0.0, None
        limit = self.sim.scenario.planar.torque_max_nm
        if any(abs(v) > limit * (1.0 + 1e-9) for v in m.torque_body_nm):
            return 0.0, f"torque {tuple(m.torque_body_nm)} N m beyond the limit +-{limit} N m"
        return float(m.torque_body_nm[2]), None

    # After the flight process has exited, what it sent last (its bye) may still be in Zenoh's
    # receive path: wait this long with an empty inbox before calling the flight software lost.
    EXIT_DRAIN_S = 0.5

    def _wait_for_cmd(self, k: int, deadline: float):
        exited_at = None
        while True:
            now = time.monotonic()
            left = deadline - now
            if left <= 0:
                return None
            m = self._take(self.link.get(min(left, 0.1 if exited_at is not None else 0.2)))
            if m is None and self.inbox_empty() and self.flight_exited() is not None:
                exited_at = exited_at or time.monotonic()
                if time.monotonic() - exited_at >= self.EXIT_DRAIN_S:
                    return None
            if isinstance(m, msg.Bye):
                self.event("flight_bye", f"reason {m.reason}: {m.text}")
                return m
            step = m.step if isinstance(m, (msg.Cmd, InvalidMessage)) else None
            if step == k or (isinstance(m, InvalidMessage) and m.kind != "cmd"):
                return m
            if step is None:
                continue
            s = self.summary
            if step > k:  # never asked for: counted, ignored
                s.future_commands += 1
                self.event("future_cmd", f"cmd for step {step} while waiting for {k}: dropped", step=k)
            else:  # an answer to an older nav (a resend crossed it)
                s.stale_commands += 1
                s.duplicate_commands += step == k - 1

    @staticmethod
    def _nav_message(k: int, meas) -> msg.Nav:
        return msg.Nav(
            step=k, flags=1 if k == 0 else 0, t_s=float(meas.t_s),
            position_lvlh_m=tuple(float(v) for v in meas.position_lvlh_m),
            velocity_lvlh_mps=tuple(float(v) for v in meas.velocity_lvlh_mps),
            q_lvlh_body=tuple(float(v) for v in meas.q_lvlh_body),
            omega_body_rad_s=tuple(float(v) for v in meas.omega_body_rad_s),
        )

    def _delay_s(self, cmd) -> float:
        model = self.cfg.delay_model
        if model == "none":
            return 0.0
        if model == "reported":
            delay = cmd.step_time_us * 1e-6
        elif model == "estimated":
            delay = cmd.instructions * self.cfg.cpi / self.cfg.clock_hz if cmd.instructions else cmd.step_time_us * 1e-6
        else:
            raise ValueError(f"unknown delay model {model!r}")
        return min(delay, cmd.period_s)  # a command later than its period is an overrun, applied at the end

    # -- the run -----------------------------------------------------------------------------------
    def run(self) -> RunSummary:
        """Serve the run to its end; the link is opened here unless the caller opened it already."""
        if self.link.session is None:
            self.link.open()
        try:
            self._run()
        except Exception as exc:  # record why, then let the caller see it
            self.summary.end = f"host error: {type(exc).__name__}: {exc}"
            self.event("host_error", self.summary.end)
            raise
        finally:
            self._finish()
        return self.summary

    def inbox_empty(self) -> bool:
        return self.link.inbox.empty()

    def _finish(self) -> None:
        s = self.summary
        s.t_s = self.sim.t_s
        s.final_range_to_port_m = self.sim.range_to_port_m()
        s.dv_total_mps = sum(s.dv_per_phase_mps.values())
        self.safety.finish()
        s.safety = self.safety.summary()
        try:
            if self.link.session is not None:
                self.link.put("bye", msg.Bye(reason=1 if s.docked else 0, last_step=max(s.steps - 1, 0),
                                             text=s.end[:60]))
                # The flight side answers bye with its final telemetry and its own bye.
                t_end = time.monotonic() + 2.0
                while time.monotonic() < t_end:
                    if isinstance(self._take(self.link.get(t_end - time.monotonic())), msg.Bye):
                        break
        finally:
            self.link.close()
            self._log_rejections()
            s.discarded = dict(self.link.discarded)
            s.rejected_messages = sum(s.discarded.values())
            s.host_speed_dependent = self.cfg.host_speed_dependent(s.hello)
            counts = {**{f"host_{k}": v for k, v in s.discarded.items()},
                      "host_stale_commands": s.stale_commands, "host_future_commands": s.future_commands,
                      **{f"flight_{k}": v for k, v in s.flight_discarded.items()}}
            self.event("discarded_inputs", ", ".join(f"{k} {v}" for k, v in counts.items()))

    def _exchange_lockstep(self, k: int, nav):
        """Put nav k and wait for cmd k, resending nav k on timeout. Returns (cmd or Bye or None, attempts)."""
        cfg = self.cfg
        for attempt in range(cfg.nav_retries + 1):
            if self.flight_exited() is not None and self.inbox_empty():
                # No point resending to a dead process; collect what it sent last (its bye), if any.
                return self._wait_for_cmd(k, time.monotonic() + self.EXIT_DRAIN_S + 0.2), attempt
            if attempt > 0:
                self.summary.nav_resends += 1
                self.event("nav_resend", f"no cmd {k} within {cfg.cmd_timeout_s:g} s, attempt {attempt}", step=k)
            if not cfg.drop_nav(k, attempt):
                self._put_obstacles(k, nav.t_s)
                self.link.put("nav", nav)
            cmd = self._wait_for_cmd(k, time.monotonic() + cfg.cmd_timeout_s)
            if cmd is not None:
                return cmd, attempt + 1
        return None, cfg.nav_retries + 1

    def _run(self) -> None:
        cfg, sim, s = self.cfg, self.sim, self.summary
        deadline = time.monotonic() + cfg.hello_timeout_s
        while s.hello is None and time.monotonic() < deadline:
            early = self._take(self.link.get(min(deadline - time.monotonic(), 0.2)))
            if isinstance(early, InvalidMessage):
                s.end = f"flight fault: invalid {early.kind} ({early.reason})"
                self.event("flight_fault", s.end)
                return
            gone = self.flight_exited()
            if s.hello is None and gone is not None and self.inbox_empty():
                s.end = f"flight software exited before connecting ({gone})"
                self.event("fault", s.end)
                return
        if s.hello is None:
            s.end = "flight software never connected"
            self.event("fault", f"no hello from the flight software within {cfg.hello_timeout_s:g} s")
            return
        if (why := check_hello(s.hello)) is not None:
            s.end = f"flight fault: invalid hello ({why})"
            self.event("flight_fault", s.end)
            return
        if cfg.send_config:
            if not self._configure():
                return
            if (why := check_hello(s.hello)) is not None:
                s.end = f"flight fault: invalid hello ({why})"
                self.event("flight_fault", s.end)
                return
        last_period = float(s.hello.period_s[0])  # until a cmd says otherwise: the rendezvous period
        last_phase = 1
        wall0 = time.monotonic()
        for k in range(cfg.max_steps):
            if self._stop.is_set():
                s.end = "stopped"
                return
            meas = sim.measure()
            target = sim.target_state()
            truth = sim.truth_lvlh()
            nav = self._nav_message(k, meas)
            t_put = time.monotonic()
            if cfg.lockstep:
                cmd, attempts = self._exchange_lockstep(k, nav)
            else:
                if not cfg.drop_nav(k, 0):
                    self._put_obstacles(k, nav.t_s)
                    self.link.put("nav", nav)
                cmd, attempts = self._wait_for_cmd(k, wall0 + (sim.t_s + last_period) / cfg.speedup), 1
            rtt_ms = (time.monotonic() - t_put) * 1e3
            if isinstance(cmd, msg.Bye):
                s.end = f"flight software ended the run ({cmd.text})"
                self._log_without_cmd(meas, target, truth)
                return
            what, why = ("command" if cmd.kind == "cmd" else cmd.kind, cmd.reason) if isinstance(cmd, InvalidMessage) \
                else ("command", check_cmd(cmd, s.hello, k, last_phase) if isinstance(cmd, msg.Cmd) else None)
            if why is not None:  # the flight software's own message breaks its declared limits
                s.invalid_commands += what == "command"
                s.end = f"flight fault: invalid {what} for step {k}: {why}"
                self.event("flight_fault", f"invalid {what} for step {k}, not applied: {why}", step=k)
                self._log_without_cmd(meas, target, truth)
                return
            if cmd is None and cfg.lockstep:
                gone = self.flight_exited()
                s.end = "flight software lost"
                self.event("flight_software_lost",
                           f"no cmd for step {k}: the flight software exited ({gone})" if gone is not None else
                           f"no cmd for step {k} after {cfg.nav_retries} resends of {cfg.cmd_timeout_s:g} s", step=k)
                self._log_without_cmd(meas, target, truth)
                return
            if cmd is None:  # real time: a late command is not applied, the chaser coasts this period
                s.late_commands += 1
                self.event("late_cmd", f"no cmd for step {k} within its period", step=k)
                result = sim.apply_command(np.zeros(6), last_period, 0.0)
                margins = self.safety.period(last_phase, k, result.path_t_s, result.path_lvlh, None,
                                             result.dv_lvlh_mps)
                self._log(k, meas, target, result, None, attempts, rtt_ms, margins=margins)
            else:
                last_period, last_phase = cmd.period_s, cmd.phase
                if cmd.phase == 4:  # the flight software declares docked: check it against the truth
                    self.safety.contact(k, sim.t_s, truth)
                    s.docked = sim.range_to_port_m() <= cfg.docking_tolerance_m
                    s.end = "docked" if s.docked else "flight software reports docked, truth disagrees"
                    self._log(k, meas, target, None, cmd, attempts, rtt_ms, truth=truth)
                    return
                torque = 0.0
                if self.planar:
                    torque, why = self._torque(k)
                    if why is not None:
                        s.end = f"flight fault: invalid torque for step {k}: {why}"
                        self.event("flight_fault", f"invalid torque for step {k}, not applied: {why}", step=k)
                        self._log_without_cmd(meas, target, truth)
                        return
                result = sim.apply_command(np.asarray(cmd.pulse_s, dtype=float), cmd.period_s, self._delay_s(cmd),
                                           torque_nm=torque)
                margins = self.safety.period(cmd.phase, k, result.path_t_s, result.path_lvlh, cmd.dv_cmd_lvlh_mps,
                                             result.dv_lvlh_mps)
                if cmd.guidance_status not in (0, 4):  # not a plain solve: say what was flown and why
                    self.event("guidance_fallback", _fallback_text(cmd), step=k)
                phase = PHASE_NAMES.get(cmd.phase)
                if phase in s.dv_per_phase_mps:
                    # The resultant |dv|_2 per period, as the dissertation's tables; dv_l1 is what six
                    # axis thrusters actually burn.
                    s.dv_per_phase_mps[phase] += float(np.linalg.norm(result.dv_lvlh_mps))
                    s.dv_l1_mps += float(np.sum(np.abs(result.dv_thruster_mps)))
                    s.time_per_phase_s[phase] += cmd.period_s
                self._log(k, meas, target, result, cmd, attempts, rtt_ms, margins=margins)
            if not cfg.lockstep:
                self._sleep_until(wall0 + sim.t_s / cfg.speedup)
            hold = getattr(sim.scenario, "hold_range_m", 0.0)
            if hold and sim.range_to_com_m() <= hold:
                s.held = True
                s.end = "held"
                self.event("held", f"true range to the target CoM {sim.range_to_com_m():.3f} m <= the holding "
                                   f"distance {hold:g} m", step=k)
                return
            if sim.range_to_com_m() < cfg.collision_radius_m:
                s.end = "collision"
                self.event("collision", f"true range to the target CoM {sim.range_to_com_m():.3f} m", step=k)
                return
            if sim.t_s >= sim.scenario.timeout_s:
                s.end = "timeout"
                self.event("timeout", f"t = {sim.t_s:.0f} s >= {sim.scenario.timeout_s:.0f} s", step=k)
                return
        s.end = "step limit"

    @staticmethod
    def _sleep_until(t_wall: float) -> None:
        left = t_wall - time.monotonic()
        if left > 0:
            time.sleep(left)

    def _log_without_cmd(self, meas, target, truth) -> None:
        """The step the run ended on without a command: truth and measurement only."""
        if self.record is not None:
            self.record.log_step(meas, None, target=target, truth_lvlh=truth)

    def _log(self, k, meas, target, result, cmd, attempts, rtt_ms, truth=None, margins=None) -> None:
        self.summary.steps = k + 1
        if self.record is not None:
            extra = {"nav_attempts": attempts, "round_trip_ms": rtt_ms}
            if self.planar and "chaser_angle_rad" in self.record.extra_columns:
                att = result.attitude_before if result is not None else self.sim.chaser_attitude()
                extra.update(chaser_angle_rad=float(att[0]), chaser_rate_rad_s=float(att[1]),
                             meas_chaser_angle_rad=2.0 * math.atan2(meas.chaser_q_lvlh[3], meas.chaser_q_lvlh[0]),
                             torque_z_nm=result.torque_nm if result is not None else 0.0)
            if margins is not None and "safety_corridor_m" in self.record.extra_columns:
                extra.update(safety_corridor_m=margins["corridor_m"], safety_axial_m=margins["axial_m"],
                             safety_dock_cone_m=margins["dock_cone_m"], safety_speed_inf_mps=margins["speed_inf_mps"],
                             safety_range_m=margins["range_m"])
            if cmd is not None:
                extra.update(
                    phase=cmd.phase, guidance_status=cmd.guidance_status, solver_status=cmd.solver_status,
                    overrun=cmd.overrun, overruns=cmd.overruns, cmd_period_s=cmd.period_s,
                    solve_time_us=cmd.solve_time_us, step_time_us=cmd.step_time_us, instructions=cmd.instructions,
                    iterations=cmd.iterations, primal_residual=cmd.primal_residual,
                    dual_residual=cmd.dual_residual, objective=cmd.objective,
                )
                for i, ax in enumerate("xyz"):
                    extra[f"dv_cmd_{ax}_mps"] = cmd.dv_cmd_lvlh_mps[i]
                    extra[f"dv_alloc_{ax}_mps"] = cmd.dv_alloc_lvlh_mps[i]
            self.record.log_step(meas, result, target=target, truth_lvlh=truth, **extra)
        if self.on_step is not None:
            self.on_step(k, self.summary, cmd)
