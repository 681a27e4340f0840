"""Run one scenario processor-in-the-loop: host simulator + flight software process, over Zenoh.

    summary, run_dir = run_pil("case1_vbar", truth="cw", sensor_noise=False, thrust_noise=False)

starts the host's Zenoh session on a free loopback port, launches the flight executable (native, or
behind a runner prefix such as ``qemu-arm -cpu cortex-a9``) pointed at it, serves the run in lockstep,
writes the run record and stops the flight process. Used by the `rvd-run` command, the tests and the
campaigns in rvd_pil/bench/.

The run's link key (a fresh random one unless the config names one) reaches the flight process in
its environment ($RVD_LINK_KEY), which only its own user can read, never on its command line,
which every local user can; a runner or wrapper passes the environment on (QEMU user mode does; the
semihosting bridge of QEMU system mode turns it into a 0600 file the guest reads). The key is not
written to the record.
"""
from __future__ import annotations

import dataclasses
import datetime as _dt
import os
import secrets
import shlex
import shutil
import signal
import subprocess
import time
import uuid
from pathlib import Path
from typing import Callable, Optional, Sequence

from rvd_pil import paths
from rvd_pil.host_sim import messages as msg
from rvd_pil.host_sim.record import RunRecorder
from rvd_pil.host_sim.scenario import Scenario, load
from rvd_pil.host_sim.server import (FLIGHT_COLUMNS, PLANAR_COLUMNS, SAFETY_COLUMNS, PilServer, RunSummary,
                                     ServerConfig, free_tcp_port)
from rvd_pil.host_sim.simulator import Simulator

# The whole environment of a flight process under QEMU user mode (besides the link key).
EMULATED_FLIGHT_ENV = {"PATH": "/usr/local/bin:/usr/bin:/bin", "LC_ALL": "C"}
FLIGHT_EXE_NAME = "rvd_flight_sw"


class FlightLaunchError(ValueError):
    """The flight executable cannot run as asked (missing, not executable, built for another CPU)."""


# ELF e_machine values of the architectures the flight software is built for
ELF_MACHINES = {0x03: "x86 (32-bit)", 0x28: "ARM (32-bit)", 0x3E: "x86-64", 0xB7: "AArch64"}
HOST_ELF_MACHINE = {"x86_64": 0x3E, "amd64": 0x3E, "aarch64": 0xB7, "arm64": 0xB7, "armv7l": 0x28, "i686": 0x03}


RUNNER_EXAMPLE = {0x28: "qemu-arm -cpu cortex-a9", 0xB7: "qemu-aarch64 -cpu cortex-a53"}


def elf_machine(path: Path | str) -> int | None:
    """The ELF header's e_machine of `path`, None when it is not an ELF file (e.g. a script)."""
    try:
        with open(path, "rb") as f:
            head = f.read(20)
    except OSError:
        return None
    if len(head) < 20 or head[:4] != b"\x7fELF":
        return None
    return int.from_bytes(head[18:20], "little" if head[5] == 1 else "big")


def check_runs_here(exe: Path | str) -> None:
    """Refuse, with the cause, an executable built for another CPU than this host's (it needs a
    runner such as qemu-arm, which `rvd-run --target` sets up)."""
    import platform

    machine = elf_machine(exe)
    host = HOST_ELF_MACHINE.get(platform.machine().lower())
    if machine is not None and host is not None and machine != host:
        raise FlightLaunchError(
            f"{exe} is an {ELF_MACHINES.get(machine, f'ELF machine {machine:#x}')} executable and this host is "
            f"{ELF_MACHINES.get(host, platform.machine())}: run it under QEMU (rvd-run --target <name>, or "
            f"--runner \"{RUNNER_EXAMPLE.get(machine, 'qemu-<arch> -cpu <model>')}\")")


def find_flight_executable(explicit: Optional[str] = None, name: str = FLIGHT_EXE_NAME) -> Path:
    """The native flight executable: `explicit` (which must exist: never replaced by another),
    $RVD_FLIGHT_SW, the checkout's build/native, the one an installed wheel bundles (rvd_pil/bin),
    or PATH."""
    if explicit:
        path = Path(explicit)
        if not path.is_file():
            raise FlightLaunchError(f"flight executable {explicit}: no such file")
        if not os.access(path, os.X_OK):
            raise FlightLaunchError(f"flight executable {explicit}: not executable")
        return path
    checkout = paths.checkout()
    native = checkout / "build" / "native" / "flight_sw" if checkout else None
    candidates = [os.environ.get("RVD_FLIGHT_SW") if name == FLIGHT_EXE_NAME else None,
                  str(native / name) if native else None, str(paths.BUNDLED_BIN / name), shutil.which(name)]
    for c in candidates:
        if c and Path(c).is_file() and os.access(c, os.X_OK):
            return Path(c)
    looked = ", ".join(["$RVD_FLIGHT_SW", *([str(native)] if native else []), str(paths.BUNDLED_BIN), "PATH"])
    raise FileNotFoundError(f"no flight executable found (looked at {looked}); "
                            + ("build it with `make build`" if checkout else "reinstall rvd-pil"))


def error_model_args(sim: Simulator) -> list[str]:
    """Flight options telling the flight software the disturbances of this run: the sensor noise
    (its navigation filter's measurement model), the thrust amplitude error's steady-state sigma and
    whether burns are finite (its robustness margins). A switched-off model is reported as zero."""
    sc = sim.scenario
    sp, sv = (sc.sensors.sigma_position_m, sc.sensors.sigma_velocity_mps) if sim.sensor_noise else (0.0, 0.0)
    sw = (sc.thrust_error.steady_state_covariance()[0, 0] ** 0.5 / 100.0) if sim.thrust_noise else 0.0
    return ["--nav-sigma", f"{sp!r},{sv!r}", "--thrust-error-sigma", repr(float(sw)),
            "--finite-burns", "off" if sim.impulsive else "on"]


def truth_args(sim: Simulator) -> list[str]:
    """Flight options for what the truth fixes beyond the vehicle the config message carries: where on
    the target the port is (the scenario's, in every scenario: a flight software aiming at its own
    default port would dock somewhere else), and on an air-bearing table (the planar truth) no orbit
    and the chaser's inertia and torque limit. On the command line, before any options of the run's
    own, so they are pinned (a scenario cannot contradict its own truth; a study that wants the flight
    to believe another port says so after them) and take none of the config message's 512 bytes of
    settings."""
    sc = sim.scenario
    port = sc.target.docking_port_body_m
    args = [a for axis, v in zip("xyz", port) for a in ("--set", f"port_body_{axis}_m={float(v)!r}")]
    if not sc.is_planar:
        return args
    return ["--set", "relative_motion=double_integrator", "--set", f"attitude.inertia_kgm2={sc.planar.chaser_inertia_kgm2!r}",
            "--set", f"attitude.torque_max_nm={sc.planar.torque_max_nm!r}", *args]


def write_law_values(run_dir: Path, values: list) -> None:
    """The guidance law's named values per step (rvd_guidance.h, rvd_guidance_output.named) as
    law_values.csv: step, name, value; nothing when the law logged none."""
    if not values:
        return
    with open(Path(run_dir) / "law_values.csv", "w", encoding="utf-8") as f:
        f.write("step,name,value\n")
        for step, named in values:
            for name, v in named.items():
                f.write(f"{step},{name},{v!r}\n")


def default_run_dir(scenario_name: str, root: Path | str = "runs") -> Path:
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    return Path(root) / f"{stamp}-{scenario_name}-{uuid.uuid4().hex[:6]}"


def stop_process(proc: subprocess.Popen, grace_s: float = 5.0) -> int:
    """Wait for a process to leave on its own, then SIGTERM, then SIGKILL. Returns its exit code."""
    for sig, wait in ((None, grace_s), (signal.SIGTERM, 3.0), (signal.SIGKILL, 3.0)):
        if sig is not None and proc.poll() is None:
            proc.send_signal(sig)
        try:
            return proc.wait(timeout=wait)
        except subprocess.TimeoutExpired:
            continue
    return proc.wait()



HELLO_FIELDS = ("arch", "cpu_model", "compiler", "build", "horizon", "deadline_fraction", "step_clock", "period_s",
                "max_pulse_s", "solver_mode", "solver_max_iter", "session")


def end_of_run_meta(s, cfg, flight_exit_code) -> dict:
    """What a run's record says when it ends: the server's summary `s` (RunSummary), the flight software's
    hello, telemetry and configuration; the same for a PIL run and the in-process path."""
    hello = s.hello
    return dict(
        end=s.end, docked=s.docked, held=s.held, steps=s.steps, t_end_s=s.t_s, dv_total_mps=s.dv_total_mps, dv_l1_mps=s.dv_l1_mps,
        dv_per_phase_mps=s.dv_per_phase_mps, time_per_phase_s=s.time_per_phase_s,
        final_range_to_port_m=s.final_range_to_port_m, nav_resends=s.nav_resends,
        late_commands=s.late_commands, rejected_messages=s.rejected_messages,
        stale_commands=s.stale_commands, duplicate_commands=s.duplicate_commands,
        future_commands=s.future_commands, invalid_commands=s.invalid_commands,
        host_discarded=s.discarded, flight_discarded=s.flight_discarded,
        host_speed_dependent=s.host_speed_dependent or cfg.host_speed_dependent(hello),
        flight_exit_code=flight_exit_code,
        flight_hello=None if hello is None else {k: getattr(hello, k) for k in HELLO_FIELDS},
        flight_telemetry=None if s.telemetry is None else vars(s.telemetry),
        safety=s.safety, flight_config=s.flight_config, law_faults=s.law_faults,
    )

def flight_environment(cmd: list[str], link_key: bytes) -> dict[str, str]:
    """The flight process's environment: this process's plus the link key; under QEMU user mode only
    EMULATED_FLIGHT_ENV and the key. QEMU user mode hands its own environment to the guest, whose
    size moves the guest's initial stack and so the cache model's figures: the same few variables in
    every checkout and shell make the estimate independent of them."""
    name = Path(cmd[0]).name
    base = EMULATED_FLIGHT_ENV if name.startswith("qemu-") and not name.startswith("qemu-system") else os.environ
    return {**base, msg.KEY_ENV: link_key.hex()}


def run_pil(
    scenario: Scenario | str,
    *,
    seed: int = 0,
    truth: str = "cw",
    sensor_noise: bool = True,
    thrust_noise: bool = True,
    impulsive: bool = False,
    sim_options: Optional[dict] = None,
    flight_exe: Optional[str] = None,
    flight_args: Sequence[str] = (),
    runner: Sequence[str] | str = (),
    flight_command: Optional[Callable[[list[str]], list[str]]] = None,
    host_address: str = "127.0.0.1",
    flight_endpoint: Optional[str] = None,
    config: Optional[ServerConfig] = None,
    run_dir: Optional[Path | str] = None,
    meta: Optional[dict] = None,
    on_step: Optional[Callable] = None,
    on_started: Optional[Callable[[PilServer, subprocess.Popen], None]] = None,
) -> tuple[RunSummary, Path]:
    """Run `scenario` against the flight software and return (summary, run directory).

    runner: a command prefix for the flight executable (e.g. "qemu-arm -cpu cortex-a9");
    flight_command: instead of exe and runner, a function from the flight software's arguments to the
    whole command (QEMU system mode puts them on the kernel command line). The flight software
    connects to `flight_endpoint` (default: the host's listening endpoint; QEMU system mode passes
    tcp/10.0.2.2:PORT). config: server settings (the endpoint and run id are filled in here).
    """
    scen = load(scenario) if isinstance(scenario, str) else scenario
    sim = Simulator(scen, truth=truth, seed=seed, sensor_noise=sensor_noise, thrust_noise=thrust_noise,
                    impulsive=impulsive, **(sim_options or {}))
    cfg = config or ServerConfig()
    port = free_tcp_port(host_address)
    cfg.endpoint = f"tcp/{host_address}:{port}"
    cfg.run_id = msg.check_run_id(cfg.run_id if cfg.run_id != "run" else uuid.uuid4().hex[:12])
    link_key = cfg.link_key or secrets.token_bytes(msg.KEY_SIZE)  # fresh for every run unless given
    # --verbose: the flight software notes its events (connects, rejected input, exit) in flight_sw.log.
    # The error model the flight software's navigation filter and margins assume is the scenario's.
    args = ["--connect", flight_endpoint or cfg.endpoint, "--run", cfg.run_id, "--verbose",
            *error_model_args(sim), *(["--obstacles", "on"] if sim.scenario.obstacles else []), *truth_args(sim),
            *flight_args]
    if flight_command is not None:
        cmd = list(flight_command(args))
    else:
        prefix = shlex.split(runner) if isinstance(runner, str) else list(runner)
        exe = find_flight_executable(flight_exe)
        if not prefix:
            check_runs_here(exe)
        elif shutil.which(prefix[0]) is None:
            raise FlightLaunchError(f"runner {prefix[0]!r}: not found on PATH")
        cmd = prefix + [str(exe), *args]
    flight_env = flight_environment(cmd, link_key)

    run_dir = Path(run_dir) if run_dir else default_run_dir(scen.name)
    record_meta = dict(sim.record_meta())
    record_meta.update(run_id=cfg.run_id, flight_command=cmd, truth=sim.truth, lockstep=cfg.lockstep,
                       delay_model=cfg.delay_model, zenoh_mode=cfg.mode,
                       link_auth=f"HMAC-SHA-256 tag of {msg.TAG_SIZE} bytes on every message, per-run key "
                                 f"(handed over in ${msg.KEY_ENV}, not recorded)",
                       host_speed_dependent=cfg.host_speed_dependent())
    record_meta.update(meta or {})
    recorder = RunRecorder(run_dir, meta=record_meta, extra_columns=FLIGHT_COLUMNS + SAFETY_COLUMNS +
                           (PLANAR_COLUMNS if sim.scenario.is_planar else ()))
    proc = None

    def flight_exited():
        code = None if proc is None else proc.poll()
        return None if code is None else f"exit code {code}"

    server = PilServer(sim, dataclasses.replace(cfg, link_key=link_key), record=recorder, on_step=on_step,
                       flight_exited=flight_exited)
    status = "failed"
    try:
        server.link.open()
        with open(run_dir / "flight_sw.log", "wb") as log:
            proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=flight_env)
            recorder.update_meta(flight_pid=proc.pid)
            if on_started is not None:
                on_started(server, proc)
            summary = server.run()
            stop_process(proc)
        status = "finished"
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        recorder.close(status, **end_of_run_meta(server.summary, cfg, None if proc is None else proc.returncode))
        write_law_values(run_dir, server.summary.law_values)
    return summary, run_dir
