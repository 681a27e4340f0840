"""The target registry (rvd_pil/qemu/targets.toml): CPU, clock, compiler flags, QEMU binaries, system-mode
machine and CPI model of each emulated flight computer.

    >>> t = load("q7s")                      # Cortex-A9 at 766 MHz
    >>> t.qemu_user, t.qemu_cpu
    ('qemu-arm', 'cortex-a9')
    >>> t.target_time_s(1_000_000)           # (nominal, low, high) seconds on the real CPU
    >>> load("q7s", cpu="cortex-a8")         # same board, another CPU model (or QEMU_CPU=cortex-a8)
"""
from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass
from pathlib import Path

from rvd_pil import paths

REGISTRY = Path(__file__).with_name("targets.toml")
CPU_ENV = "QEMU_CPU"  # the variable QEMU user mode itself reads; we honour it the same way


@dataclass(frozen=True)
class CpiModel:
    """Cycles per instruction on the real CPU: nominal value and an honest range."""

    nominal: float
    low: float
    high: float
    calibrated: bool  # false: an estimate from documented pipeline facts, not a measurement
    basis: str        # where the figures come from


@dataclass(frozen=True)
class SystemMode:
    """How the target boots in QEMU system mode."""

    machine: str                      # -M
    machine_options: tuple[str, ...]  # appended to -M, e.g. dtb-randomness=off
    kernel_package: str               # Debian meta package of the kernel (resolved at build time)
    dtb: str | None                   # device tree in the kernel package; None: QEMU makes one
    console: str                      # kernel console device
    memory: str                       # -m
    extra_args: tuple[str, ...]
    icount_shift: int = 0             # -icount shift: one guest instruction = 2^shift ns of guest time


@dataclass(frozen=True)
class Target:
    name: str
    description: str
    arch: str                 # "armhf", "aarch64" or "host"
    cpu: str | None           # CPU model (-mcpu and QEMU -cpu); None for host
    clock_hz: float | None
    clock_source: str
    mfpu: str | None          # armhf only
    cpi: CpiModel | None
    system: SystemMode | None  # None: user mode only (or host)
    toolchain_file: Path | None
    compiler: str | None
    qemu_user: str | None
    qemu_system: str | None
    qemu_cpu: str | None
    debian_arch: str | None
    objdump: str | None
    cpu_overridden: bool = False
    system_note: str = ""      # why there is no system mode, when the registry has one

    @property
    def emulated(self) -> bool:
        return self.arch != "host"

    @property
    def compile_flags(self) -> list[str]:
        """The compiler flags that select this CPU (what the toolchain file adds)."""
        if not self.emulated:
            return []
        flags = [f"-mcpu={self.cpu}"]
        if self.arch == "armhf":
            flags += [f"-mfpu={self.mfpu}", "-mfloat-abi=hard"]
        return flags

    @property
    def build_name(self) -> str:
        """Build directory name: the target, plus the CPU when it was swapped."""
        return f"{self.name}-{self.cpu}" if self.cpu_overridden else self.name

    def target_time_s(self, instructions: float) -> tuple[float, float, float]:
        """Estimated time on the real CPU, seconds: (nominal, low, high) = insns x CPI / f_clk."""
        if self.cpi is None or not self.clock_hz:
            raise ValueError(f"target {self.name!r} has no CPI model (host: use measured wall time)")
        n = float(instructions)
        return (n * self.cpi.nominal / self.clock_hz, n * self.cpi.low / self.clock_hz,
                n * self.cpi.high / self.clock_hz)


def _toolchain(relative: str) -> Path | None:
    """The toolchain file (relative to the C++ source tree: the checkout or a wheel's copy); None
    when this installation ships no sources (the cross build then says a checkout is needed)."""
    try:
        return paths.source_root() / relative
    except FileNotFoundError:
        return None


def _registry() -> dict:
    with REGISTRY.open("rb") as f:
        return tomllib.load(f)


def names() -> list[str]:
    """Registered target names."""
    return list(_registry()["target"])


def cpus(arch: str | None = None) -> list[str]:
    """Known CPU models, optionally only those of one architecture."""
    return [c for c, v in _registry()["cpu"].items() if arch is None or v["arch"] == arch]


def load(name: str, cpu: str | None = None) -> Target:
    """The target `name`; `cpu` (else $QEMU_CPU, else the registry's) picks the CPU model."""
    reg = _registry()
    if name not in reg["target"]:
        raise ValueError(f"unknown target {name!r}; known: {', '.join(reg['target'])}")
    t = reg["target"][name]
    arch = t["arch"]
    if arch == "host":
        return Target(name=name, description=t["description"], arch="host", cpu=None, clock_hz=None,
                      clock_source="", mfpu=None, cpi=None, system=None, toolchain_file=None,
                      compiler=None, qemu_user=None, qemu_system=None, qemu_cpu=None,
                      debian_arch=None, objdump=None)

    requested = cpu or os.environ.get(CPU_ENV) or None
    cpu_name = requested or t["cpu"]
    if cpu_name not in reg["cpu"]:
        source = "cpu argument" if cpu else f"${CPU_ENV}"
        raise ValueError(f"unknown CPU {cpu_name!r} ({source}); known: {', '.join(reg['cpu'])}")
    c = reg["cpu"][cpu_name]
    if c["arch"] != arch:
        raise ValueError(f"CPU {cpu_name!r} is {c['arch']}, target {name!r} is {arch}; "
                         f"{arch} CPUs: {', '.join(cpus(arch))}")
    a = reg["arch"][arch]
    cpi = CpiModel(nominal=c["cpi"]["nominal"], low=c["cpi"]["low"], high=c["cpi"]["high"],
                   calibrated=c["cpi"]["calibrated"], basis=" ".join(c["cpi"]["basis"].split()))
    system, system_note = None, ""
    if "system" in t and cpu_name not in t["system"].get("cpus", [cpu_name]):
        system_note = (f"QEMU's {t['system']['machine']} machine takes only {', '.join(t['system']['cpus'])}, "
                       f"not {cpu_name}: user mode only")
    elif "system" in t:
        s = t["system"]
        system = SystemMode(machine=s["machine"], machine_options=tuple(s.get("machine_options", ())),
                            kernel_package=s["kernel_package"], dtb=s.get("dtb"),
                            console=s["console"], memory=s["memory"],
                            extra_args=tuple(s.get("extra_args", ())),
                            icount_shift=int(s.get("icount_shift", 0)))
    return Target(name=name, description=t["description"], arch=arch, cpu=cpu_name,
                  clock_hz=float(t["clock_hz"]), clock_source=t["clock_source"], mfpu=c.get("mfpu"),
                  cpi=cpi, system=system, toolchain_file=_toolchain(a["toolchain"]),
                  compiler=a["compiler"], qemu_user=a["qemu_user"], qemu_system=a["qemu_system"],
                  qemu_cpu=c["qemu_cpu"], debian_arch=a["debian_arch"], objdump=a["objdump"],
                  cpu_overridden=cpu_name != t["cpu"], system_note=system_note)
