"""The in-process path: the flight application itself (flight_sw.FlightApp, the pybind11 binding of
flight_sw/app) in this process, served by the very same host_sim Simulator and PilServer as a PIL
run, without Zenoh or a flight process.

    summary, run_dir = run_in_process(scenario, settings, seed=3, truth="nonlinear", run_dir=...)

The FlightApp is built from the flight executable's own options (the same parser), so it flies
what the executable flies; `InProcessLink` takes the place of the server's ZenohLink: each nav
the server publishes is encoded, handed to FlightApp.handle_nav, and the encoded cmd that comes
back is decoded and queued as if it had arrived, with telemetry every 20 answers and the final
telemetry and bye when the host says bye, as the executable sends them. The server's loop, delay
model, docking check, stop conditions and record are the PIL run's own, so the record is the same
bit for bit except for what measures time (solve/step wall time, round trip) and the flight's
self-description (hello); tests/test_studies.py checks this against the native executable.
"""
from __future__ import annotations

import queue
import time
import uuid
from pathlib import Path
from typing import Callable, Optional

from rvd_pil.host_sim import messages as msg
from rvd_pil.host_sim import pil as pil_module
from rvd_pil.host_sim import server as server_module
from rvd_pil.host_sim.record import RunRecorder
from rvd_pil.host_sim.scenario import Scenario
from rvd_pil.host_sim.server import FLIGHT_COLUMNS, PilServer, RunSummary, ServerConfig
from rvd_pil.host_sim.simulator import Simulator

from .settings import GuidanceSettings

TELEMETRY_EVERY = 20  # the flight executable's default --telemetry-every


class InProcessLink:
    """What PilServer needs of its link (open/put/get/close, inbox, rejected, discarded, session), served
    by a flight_sw.FlightApp instead of a Zenoh session. Nothing travels, so nothing is sealed or can be
    forged: the counters of dropped messages stay zero."""

    def __init__(self, app, on_answer: Optional[Callable[[int, object], None]] = None):
        self.app = app
        self.on_answer = on_answer
        self.inbox: "queue.Queue[tuple[float, object]]" = queue.Queue()
        self.rejected: "queue.Queue[tuple[str, str, str]]" = queue.Queue()
        self.discarded = {k: 0 for k in server_module.DISCARD_KINDS}
        self.session = None
        self.answered = 0
        self.last_step = 0

    def open(self) -> None:
        self.session = "in-process"
        self._arrive(self.app.hello(1))

    def _arrive(self, data: bytes) -> None:
        self.inbox.put((time.monotonic(), msg.decode(data)))

    def put(self, kind: str, message) -> None:
        if kind == "obstacles":
            self.app.handle_obstacles(msg.encode(message))
        elif kind == "chaser_attitude":
            self.app.handle_chaser_attitude(msg.encode(message))
        elif kind == "nav":
            cmd = self.app.handle_nav(msg.encode(message))
            if cmd is not None:
                if (status := self.app.take_obstacle_status()) is not None:  # before the cmd, as on the link
                    self._arrive(status)
                if (torque := self.app.torque_for(message.step)) is not None:
                    self._arrive(torque)
                self._arrive(cmd)
                self.last_step = message.step
                if self.on_answer is not None:
                    self.on_answer(message.step, self.app)
                self.answered += 1
                if self.answered % TELEMETRY_EVERY == 0:
                    self._arrive(self.app.telemetry())
        elif kind == "config":  # the echo, then a hello with the limits the configuration implies
            self._arrive(self.app.apply_config(msg.encode(message)))
            self._arrive(self.app.hello(1))
        elif kind == "bye":  # the flight software answers bye with its final telemetry and its own bye
            self._arrive(self.app.telemetry())
            self.inbox.put((time.monotonic(), msg.Bye(reason=0, last_step=self.last_step,
                                                      text="flight_sw exit: bye from the host")))

    def get(self, timeout_s: float):
        try:
            return self.inbox.get(timeout=max(timeout_s, 0.0))[1]
        except queue.Empty:
            return None

    def close(self) -> None:
        self.session = None


def flight_options(sim: Simulator, settings: GuidanceSettings, run_id: str) -> list[str]:
    """The options run_pil gives the flight executable (but the link's): the run id, the error model
    of this run where the host passes one, then the study's guidance settings."""
    error_model = getattr(pil_module, "error_model_args", None)
    truth = getattr(pil_module, "truth_args", None)
    return ["--run", run_id, *(error_model(sim) if error_model else []),
            *(["--obstacles", "on"] if sim.scenario.obstacles else []), *(truth(sim) if truth else []),
            *settings.flight_args()]


def run_in_process(scenario: Scenario, settings: GuidanceSettings, *, seed: int = 0, truth: str = "cw",
                   sensor_noise: bool = True, thrust_noise: bool = True, impulsive: bool = False,
                   sim_options: Optional[dict] = None, config: Optional[ServerConfig] = None,
                   run_dir: Path | str, meta: Optional[dict] = None,
                   on_answer: Optional[Callable[[int, object], None]] = None) -> tuple[RunSummary, Path]:
    """One run with the in-process flight application; the record has run_pil's layout and metadata.
    on_answer(step, app), when given, runs after each step the flight answered, with the
    flight_sw.FlightApp: app.guidance is the built-in MPC's Guidance (None for a plug-in law), so
    app.guidance.last_qp(phase) is the QP that step solved (the QP sets of disturbed runs)."""
    from rvd_pil import flight_sw

    sim = Simulator(scenario, truth=truth, seed=seed, sensor_noise=sensor_noise, thrust_noise=thrust_noise,
                    impulsive=impulsive, **(sim_options or {}))
    cfg = config or ServerConfig()
    cfg.run_id = cfg.run_id if cfg.run_id != "run" else uuid.uuid4().hex[:12]
    options = flight_options(sim, settings, cfg.run_id)
    app = flight_sw.FlightApp(options)
    record_meta = dict(sim.record_meta())
    record_meta.update(run_id=cfg.run_id, flight_command=["in-process", *options], truth=sim.truth,
                       lockstep=cfg.lockstep, delay_model=cfg.delay_model, zenoh_mode="in-process")
    record_meta.update(meta or {})
    run_dir = Path(run_dir)
    # the per-step columns the server fills (flight telemetry; a safety monitor's margins where it has one)
    columns = FLIGHT_COLUMNS + tuple(getattr(server_module, "SAFETY_COLUMNS", ())) + (
        tuple(getattr(server_module, "PLANAR_COLUMNS", ())) if getattr(sim.scenario, "is_planar", False) else ())
    recorder = RunRecorder(run_dir, meta=record_meta, extra_columns=columns)
    server = PilServer(sim, cfg, record=recorder)
    server.link = InProcessLink(app, on_answer)
    status = "failed"
    try:
        summary = server.run()
        status = "finished"
    finally:
        recorder.close(status, **pil_module.end_of_run_meta(server.summary, cfg, 0 if status == "finished" else None))
    return summary, run_dir
