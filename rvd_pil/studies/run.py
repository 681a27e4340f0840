"""One run of a study, on whichever worker computes it.

`execute(task, exe_data, plugin_data)` runs the point in a private temporary folder (in-process
guidance, the native flight executable over Zenoh, or the cross-built one under QEMU user mode
with the instruction-counting plugin), computes its metrics, and returns the whole record as
bytes: the client writes it into its own output folder, so workers need no shared filesystem.
An exception means the run could not be computed (the client counts it as failed and does not
store it); a flight software that crashed or never docked is a finished run with that outcome.
"""
from __future__ import annotations

import hashlib
import json
import os
import resource
import shutil
import socket
import tempfile
import time
from pathlib import Path

from rvd_pil.host_sim import scenario as scenarios
from rvd_pil.host_sim.server import ServerConfig

from . import engine as engines
from .metrics import METRICS_VERSION, run_metrics

_checked: set = set()


def _cpu_s() -> float:
    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime


def content_id(point) -> str:
    """The point's content alone (without the engine): finds stored runs again for a report."""
    from .grid import canonical

    return hashlib.sha256(canonical(point.content()).encode()).hexdigest()[:24]


def record_meta(task: dict) -> dict:
    p, eng = task["point"], task["engine"]
    t = eng.target
    meta = {"study_run": {"key": task["key"], "content": content_id(p), "study": task["study"],
                          "label": p.scenario_label, "seed": p.seed,
                          "repeat": p.repeat, "mode": p.mode, "target": p.target, "cpu": p.cpu,
                          "guidance": p.guidance.to_dict(), "model": dict(p.model), "engine": eng.identity},
            "scenario_label": p.scenario_label, "mode": p.mode, "kind": "study", "horizons": list(p.guidance.horizon),
            "target": p.target if t is None else t.name, "build": p.target if t is None else t.build_name,
            "cpu": p.cpu if t is None else t.cpu}
    if t is not None:
        meta.update(arch=t.arch, clock_hz=t.clock_hz,
                    cpi={"nominal": t.cpi.nominal, "low": t.cpi.low, "high": t.cpi.high,
                         "calibrated": t.cpi.calibrated})
    return meta


def compute(task: dict, run_dir: Path, exe_data: bytes | None = None, plugin_data: bytes | None = None):
    """Runs the task's point into `run_dir` (which must not exist yet)."""
    p, eng = task["point"], task["engine"]
    model = dict(p.model)
    scen = scenarios.from_dict(json.loads(p.scenario), source=p.scenario_label)
    kw = dict(seed=p.seed, truth=model["truth"], sensor_noise=model["sensor_noise"],
              thrust_noise=model["thrust_noise"], impulsive=model["impulsive"],
              sim_options={"j2": model["j2"], "drag": model["drag"]})
    cfg = ServerConfig(delay_model=model["delay"], cmd_timeout_s=p.cmd_timeout_s)
    meta = record_meta(task)
    if p.mode == "in-process":
        from .inprocess import run_in_process

        return run_in_process(scen, p.guidance, config=cfg, run_dir=run_dir, meta=meta, **kw)
    from rvd_pil.host_sim.pil import run_pil

    exe = engines.materialize(eng.exe, exe_data)
    if p.mode == "native":
        return run_pil(scen, flight_exe=str(exe), flight_args=p.guidance.flight_args(), config=cfg, run_dir=run_dir,
                       meta=meta, **kw)
    from rvd_pil.qemu import plugin, user

    t = eng.target
    lib = engines.materialize(eng.plugin, plugin_data)
    cfg.cpi, cfg.clock_hz, cfg.hello_timeout_s = t.cpi.nominal, t.clock_hz, 180.0
    counter = plugin.InsnCounter(log=run_dir / "plugin_insns.log", library=lib)
    return run_pil(scen, flight_command=lambda args: user.command(t, exe, args, plugin=counter),
                   flight_args=p.guidance.flight_args(), config=cfg, run_dir=run_dir, meta=meta, **kw)


def execute(task: dict, exe_data: bytes | None = None, plugin_data: bytes | None = None) -> dict:
    t0, c0 = time.monotonic(), _cpu_s()
    ident = task["engine"].identity
    token = json.dumps(ident, sort_keys=True)
    if token not in _checked:
        engines.check_worker(ident)
        _checked.add(token)
    work = Path(tempfile.mkdtemp(prefix="rvd-run-"))
    try:
        run_dir = work / task["key"]
        compute(task, run_dir, exe_data, plugin_data)
        metrics = run_metrics(run_dir)
        files = {p.name: p.read_bytes() for p in sorted(run_dir.iterdir()) if p.is_file()}
    finally:
        shutil.rmtree(work, ignore_errors=True)
    files["metrics.json"] = json.dumps({"version": METRICS_VERSION, "metrics": metrics}, allow_nan=True).encode()
    return {"key": task["key"], "files": files, "wall_s": time.monotonic() - t0, "cpu_s": _cpu_s() - c0,
            "worker": f"{socket.gethostname()}:{os.getpid()}"}
