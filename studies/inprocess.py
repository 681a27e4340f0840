"""The fast path: the flight software's guidance in this process (pybind11 module `flight_sw`), served
by the very same host_sim Simulator and PilServer as a PIL run, without Zenoh or a flight process.

    summary, run_dir = run_in_process(scenario, settings, seed=3, truth="nonlinear", run_dir=...)

`InProcessFlight` does per nav what the flight executable does (flight_sw/app/flight_app.cpp,
`FlightApp::handle_nav`): one guidance step under the deadline budget, the command fields made
finite the same way, resends answered from the cached command. `InProcessLink` takes the place of
the server's ZenohLink: what the server publishes goes straight to that flight logic, and its
answers are queued as if they had arrived. The server's loop, delay model, docking check, stop
conditions and record are therefore the PIL run's own, and the record is the same bit for bit
except for what measures time (solve/step wall time, round trip) and the flight's self-description
(hello); tests/test_studies.py checks this against the native flight executable over Zenoh.
"""
from __future__ import annotations

import platform
import queue
import time
import uuid
from pathlib import Path
from typing import Optional

from host_sim import messages as msg
from host_sim import server as server_module
from host_sim.record import RunRecorder
from host_sim.scenario import Scenario
from host_sim.server import FLIGHT_COLUMNS, PilServer, RunSummary, ServerConfig
from host_sim.simulator import Simulator

from .settings import GuidanceSettings

# Solver status codes on the wire (schema/rvd_messages.toml, cmd.solver_status).
_SOLVER_CODE = {"solved": 0, "max_iter": 1, "infeasible": 2, "invalid_input": 3, "numerical_error": 4,
                "time_limit": 5}
NOT_RUN = 255
TELEMETRY_EVERY = 20  # the flight executable's default --telemetry-every


def _finite_or(v: float, fallback: float = -1.0) -> float:
    v = float(v)
    return v if v == v and abs(v) != float("inf") else fallback


def check_supported() -> None:
    """Refuses a flight software whose application does more per message than this mirror: a
    navigation filter between the measurements and the guidance (and the error-model options that
    configure it and the guidance's margins) lives in FlightApp::handle_nav, not in Guidance, so the
    in-process path would fly another guidance than the executable. Use mode "native" then."""
    import flight_sw

    if hasattr(flight_sw, "NavFilter"):
        raise RuntimeError("mode 'in-process' does not reproduce this flight software's per-message logic "
                           "(its navigation filter and error-model margins run in the flight application): "
                           "use mode 'native'")


class InProcessFlight:
    """The flight application's per-message logic around an in-process flight_sw.Guidance."""

    def __init__(self, settings: GuidanceSettings):
        import flight_sw

        check_supported()
        self.settings = settings
        self.params = settings.guidance_params()
        self.guidance = flight_sw.Guidance(self.params)
        self._phase_enum = flight_sw.Phase
        self.deadline_fraction = settings.deadline_fraction
        self.last_cmd: Optional[msg.Cmd] = None
        self.overruns = 0
        self.nav_duplicates = 0
        self.answered = 0
        self._log = {"steps": [0, 0, 0], "overruns": [0, 0, 0], "sum": [0.0, 0.0, 0.0], "max": [0.0, 0.0, 0.0],
                     "max_step": [0, 0, 0]}

    def hello(self) -> msg.Hello:
        p = self.params
        return msg.Hello(arch=platform.machine()[:16], cpu_model="host (in-process)", compiler="flight_sw module",
                         build="in-process", solver_mode=0 if p.rendezvous.solver_mode == "fixed_barrier" else 1,
                         solver_max_iter=int(p.rendezvous.solver_max_iter), solver_tol=float(p.rendezvous.solver_tol),
                         horizon=(p.rendezvous.N, p.approach.N, p.docking.N),
                         period_s=(p.rendezvous.Ts_s, p.approach.Ts_s, p.docking.Ts_s),
                         deadline_fraction=self.deadline_fraction, pid=0, session=1)

    def telemetry(self) -> msg.Telemetry:
        lg = self._log
        return msg.Telemetry(steps=tuple(lg["steps"]), overruns=tuple(lg["overruns"]),
                             mean_solve_us=tuple(s / n if n else 0.0 for s, n in zip(lg["sum"], lg["steps"])),
                             max_solve_us=tuple(lg["max"]), max_step=tuple(lg["max_step"]),
                             total_instructions=(0, 0, 0), nav_duplicates=self.nav_duplicates)

    def handle_nav(self, nav: msg.Nav) -> Optional[msg.Cmd]:
        import flight_sw

        if self.last_cmd is not None and nav.step == self.last_cmd.step:  # a resend: the same answer
            self.nav_duplicates += 1
            return self.last_cmd
        if nav.flags & 1:
            self.guidance.reset()
            self.overruns = 0
            self.last_cmd = None
        elif self.last_cmd is not None and nav.step < self.last_cmd.step:
            return None
        phase_before = min(int(self.guidance.phase), 3) - 1
        ts = self.params.phase(self.guidance.phase).Ts_s
        budget_us = self.deadline_fraction * ts * 1e6
        nav_in = flight_sw.NavInput(nav.step, nav.t_s, [*nav.position_lvlh_m, *nav.velocity_lvlh_mps],
                                    list(nav.q_lvlh_body), list(nav.omega_body_rad_s))
        c = self.guidance.step(nav_in, budget_us)
        status = c.solver_status
        overrun = status == "time_limit" or c.step_time_us > budget_us
        self.overruns += int(overrun)
        if c.solved:
            lg = self._log
            lg["steps"][phase_before] += 1
            lg["sum"][phase_before] += c.solve_time_us
            if lg["steps"][phase_before] == 1 or c.solve_time_us > lg["max"][phase_before]:
                lg["max"][phase_before] = c.solve_time_us
                lg["max_step"][phase_before] = nav.step
            lg["overruns"][phase_before] += int(overrun)
        code = _SOLVER_CODE[status] if (status == "time_limit" or c.solved) else NOT_RUN
        cmd = msg.Cmd(
            step=nav.step, phase=int(c.phase), guidance_status=int(c.status), solver_status=code,
            overrun=int(overrun), period_s=c.period_s,
            dv_cmd_lvlh_mps=tuple(_finite_or(v, 0.0) for v in c.dv_cmd_mps),
            dv_alloc_lvlh_mps=tuple(_finite_or(v, 0.0) for v in c.dv_alloc_mps),
            pulse_s=tuple(_finite_or(v, 0.0) for v in c.pulse_s),
            solve_time_us=_finite_or(c.solve_time_us, 0.0) if c.solved else 0.0,
            step_time_us=_finite_or(c.step_time_us, 0.0), instructions=0,
            iterations=int(c.iterations) if c.solved else 0, overruns=self.overruns,
            primal_residual=_finite_or(c.primal_residual) if c.solved else -1.0,
            dual_residual=_finite_or(c.dual_residual) if c.solved else -1.0,
            objective=_finite_or(c.objective, 0.0) if c.solved else 0.0)
        self.last_cmd = cmd
        return cmd


class InProcessLink:
    """What PilServer needs of its link (open/put/get/close, inbox, rejected, session), served by an
    InProcessFlight instead of a Zenoh session."""

    def __init__(self, flight: InProcessFlight):
        self.flight = flight
        self.inbox: "queue.Queue[tuple[float, object]]" = queue.Queue()
        self.rejected: list[tuple[str, str]] = []
        self.session = None

    def open(self) -> None:
        self.session = "in-process"
        self._arrive(self.flight.hello())

    def _arrive(self, message) -> None:
        self.inbox.put((time.monotonic(), message))

    def put(self, kind: str, message) -> None:
        if kind == "nav":
            cmd = self.flight.handle_nav(message)
            if cmd is not None:
                self._arrive(cmd)
                self.flight.answered += 1
                if self.flight.answered % TELEMETRY_EVERY == 0:
                    self._arrive(self.flight.telemetry())
        elif kind == "bye":  # the flight software answers bye with its final telemetry and its own bye
            self._arrive(self.flight.telemetry())
            last = self.flight.last_cmd.step if self.flight.last_cmd is not None else 0
            self._arrive(msg.Bye(reason=0, last_step=last, text="flight_sw exit: bye from the host"))

    def get(self, timeout_s: float):
        try:
            return self.inbox.get(timeout=max(timeout_s, 0.0))[1]
        except queue.Empty:
            return None

    def close(self) -> None:
        self.session = None


def run_in_process(scenario: Scenario, settings: GuidanceSettings, *, seed: int = 0, truth: str = "cw",
                   sensor_noise: bool = True, thrust_noise: bool = True, impulsive: bool = False,
                   sim_options: Optional[dict] = None, config: Optional[ServerConfig] = None,
                   run_dir: Path | str, meta: Optional[dict] = None) -> tuple[RunSummary, Path]:
    """One run with the in-process guidance; the record has run_pil's layout and metadata."""
    sim = Simulator(scenario, truth=truth, seed=seed, sensor_noise=sensor_noise, thrust_noise=thrust_noise,
                    impulsive=impulsive, **(sim_options or {}))
    cfg = config or ServerConfig()
    cfg.run_id = cfg.run_id if cfg.run_id != "run" else uuid.uuid4().hex[:12]
    flight = InProcessFlight(settings)
    record_meta = dict(sim.record_meta())
    record_meta.update(run_id=cfg.run_id, flight_command=["in-process", *settings.flight_args()], truth=truth,
                       lockstep=cfg.lockstep, delay_model=cfg.delay_model, zenoh_mode="in-process")
    record_meta.update(meta or {})
    run_dir = Path(run_dir)
    # the per-step columns the server fills (flight telemetry; a safety monitor's margins where it has one)
    columns = FLIGHT_COLUMNS + tuple(getattr(server_module, "SAFETY_COLUMNS", ()))
    recorder = RunRecorder(run_dir, meta=record_meta, extra_columns=columns)
    server = PilServer(sim, cfg, record=recorder)
    server.link = InProcessLink(flight)
    status = "failed"
    try:
        summary = server.run()
        status = "finished"
    finally:
        s = server.summary
        hello = s.hello
        recorder.close(
            status,
            end=s.end, docked=s.docked, steps=s.steps, t_end_s=s.t_s, dv_total_mps=s.dv_total_mps, dv_l1_mps=s.dv_l1_mps,
            dv_per_phase_mps=s.dv_per_phase_mps, time_per_phase_s=s.time_per_phase_s,
            final_range_to_port_m=s.final_range_to_port_m, nav_resends=s.nav_resends,
            late_commands=s.late_commands, rejected_messages=s.rejected_messages,
            flight_exit_code=0 if status == "finished" else None,
            flight_hello=None if hello is None else {k: getattr(hello, k) for k in
                                                      ("arch", "cpu_model", "compiler", "build", "horizon", "deadline_fraction",
                                                       "period_s", "solver_mode", "solver_max_iter", "session")},
            flight_telemetry=None if s.telemetry is None else vars(s.telemetry),
            **({"safety": s.safety} if hasattr(s, "safety") else {}),
        )
    return summary, run_dir
