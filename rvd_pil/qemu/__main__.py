"""python -m rvd_pil.qemu: the emulation set-up from the command line.

    python -m rvd_pil.qemu list                    targets, CPUs, clocks, CPI models
    python -m rvd_pil.qemu prepare [TARGET ...]    build the counting plugin and the system-mode images
                                           (downloads: qemu source package, ARM kernels, busybox)
    python -m rvd_pil.qemu build TARGET [PROGRAM]  cross-build PROGRAM (default: the flight executable)
"""
from __future__ import annotations

import argparse
import sys

from . import build, plugin, system, targets


def _list() -> int:
    for name in targets.names():
        t = targets.load(name)
        if not t.emulated:
            print(f"{name:11s} native build, no emulation")
            continue
        machine = t.system.machine if t.system else "user mode only"
        print(f"{name:11s} {t.arch:8s} {t.cpu:11s} {t.clock_hz / 1e6:6.0f} MHz  CPI {t.cpi.nominal} "
              f"[{t.cpi.low}-{t.cpi.high}]{'' if t.cpi.calibrated else ' (estimate)'}  system: {machine}")
    return 0


def _prepare(names: list[str]) -> int:
    print(f"plugin: {plugin.build(download=True)}")
    print(f"plugin: {plugin.build_profile(download=False)}")
    for name in names or targets.names():
        t = targets.load(name)
        if t.emulated and t.system:
            img = system.image(t)
            print(f"{name}: kernel {img.kernel_version}, {img.initrd}")
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m rvd_pil.qemu", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    sub.add_parser("list")
    pp = sub.add_parser("prepare")
    pp.add_argument("targets", nargs="*")
    pb = sub.add_parser("build")
    pb.add_argument("target")
    pb.add_argument("program", nargs="?", default=build.FLIGHT_EXE)
    pb.add_argument("--cpu")
    a = p.parse_args(argv)
    if a.cmd == "list":
        return _list()
    if a.cmd == "prepare":
        return _prepare(a.targets)
    exe = build.cross_build(targets.load(a.target, cpu=a.cpu), a.program)
    print(f"{exe.path} ({exe.size_bytes} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
