"""QEMU user mode: run one static guest executable as a host process.

    >>> t = load("rpi3")
    >>> command(t, exe, ["--run", "r1"])
    ['qemu-aarch64', '-cpu', 'cortex-a53', '/.../rvd_flight_sw', '--run', 'r1']
    >>> command(t, exe, args, plugin=InsnCounter(log=Path("counts.txt")))   # + instruction counts

Always the dynamic qemu-arm / qemu-aarch64 (TCG plugins do not load in the -static ones), always
an explicit -cpu (QEMU's default `max` would accept instructions the real CPU lacks). The guest
reaches host TCP services at 127.0.0.1 directly. Times measured inside the guest on its clock are
host wall time, not target time: the flight software takes its deadlines and step times on target
time instead when given target_clock_args() and run with the instruction counter (InsnCounter),
which answers its clock reads.
"""
from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Sequence

from .plugin import BlockProfiler, InsnCounter
from .targets import Target


def command(target: Target, exe: Path | str, args: Sequence[str] = (), *,
            plugin: InsnCounter | BlockProfiler | Sequence[InsnCounter | BlockProfiler] | None = None) -> list[str]:
    """The command line that runs `exe` for `target` (natively for the host target). `plugin`:
    one plugin's settings or several (e.g. the instruction counter and the block profiler)."""
    plugins = [] if plugin is None else list(plugin) if isinstance(plugin, (list, tuple)) else [plugin]
    if not target.emulated:
        if plugins:
            raise ValueError("instruction counting needs QEMU: the host target runs natively")
        return [str(exe), *map(str, args)]
    cmd = [target.qemu_user, "-cpu", target.qemu_cpu]
    for p in plugins:
        cmd += p.qemu_args()
    return [*cmd, str(exe), *map(str, args)]


def run(target: Target, exe: Path | str, args: Sequence[str] = (), *, plugin=None,
        timeout_s: float | None = 600, **kwargs) -> subprocess.CompletedProcess:
    """Runs `exe` to completion and captures its output (text)."""
    return subprocess.run(command(target, exe, args, plugin=plugin), capture_output=True, text=True,
                          timeout=timeout_s, **kwargs)


def target_clock_args(cpi: float, clock_hz: float) -> list[str]:
    """The flight software's options for its flight clock on target time: instructions (read from
    the InsnCounter plugin) x `cpi` / `clock_hz`. Pass the CPI the run's estimated control delay uses,
    so that the flight's budget and the host's delay price an instruction alike."""
    return ["--target-clock", f"{float(cpi)!r},{float(clock_hz)!r}"]
