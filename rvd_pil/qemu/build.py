"""Cross builds with the toolchain files in cross/: one CMake build directory per target (and CPU),
static executables, tests runnable under QEMU user mode through ctest.

    >>> exe = cross_build(load("q7s"))           # build/cross/q7s, the flight executable
    >>> exe.path, exe.size_bytes
"""
from __future__ import annotations

import fcntl
import os
import subprocess
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from rvd_pil import paths

from .targets import Target

FLIGHT_EXE = "rvd_flight_sw"


@dataclass(frozen=True)
class Executable:
    path: Path
    size_bytes: int


def build_dir(target: Target, root: Path | None = None) -> Path:
    return (root or paths.build_root() / "cross") / target.build_name


@contextmanager
def _locked(directory: Path):
    """One builder per build directory at a time (a campaign and a test may share one)."""
    directory.mkdir(parents=True, exist_ok=True)
    with open(directory / ".rvd-build.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield


def _cmake_args(target: Target, build_type: str) -> list[str]:
    args = [f"-DCMAKE_BUILD_TYPE={build_type}", "-DRVD_BUILD_PYTHON=OFF",
            f"-DRVD_BUILD_TESTS={'ON' if paths.cpp_tests() else 'OFF'}", "-DRVD_BUILD_APP=ON"]
    if target.emulated:
        args += [f"-DCMAKE_TOOLCHAIN_FILE={target.toolchain_file}", f"-DRVD_CPU={target.cpu}",
                 f"-DRVD_QEMU_CPU={target.qemu_cpu}", "-DRVD_STATIC=ON"]
        if target.arch == "armhf":
            args.append(f"-DRVD_FPU={target.mfpu}")
    return args


def configure(target: Target, *, build_type: str = "Release", root: Path | None = None) -> Path:
    """Configures (or re-configures: new sources are globbed at configure time) the build
    directory of `target`."""
    bdir = build_dir(target, root)
    with _locked(bdir):
        _run(["cmake", "-S", str(paths.source_root()), "-B", str(bdir), *_cmake_args(target, build_type)],
             f"configure {target.build_name}")
    return bdir


def build(bdir: Path, programs: list[str] | tuple[str, ...] | None = None, *,
          jobs: int = 2) -> dict[str, Executable]:
    """Builds the given CMake targets in `bdir` (None: everything, C++ tests included); returns
    each named program's path and size."""
    with _locked(bdir):
        _run(["cmake", "--build", str(bdir), f"-j{jobs}", *(["--target", *programs] if programs else [])],
             f"build {', '.join(programs or ['all'])}")
    return {p: find_executable(bdir, p) for p in programs or ()}


def cross_build(target: Target, program: str = FLIGHT_EXE, *, jobs: int = 2, build_type: str = "Release",
                root: Path | None = None) -> Executable:
    """Configures and builds `program` (by default the flight executable) for `target`."""
    bdir = configure(target, build_type=build_type, root=root)
    return build(bdir, [program], jobs=jobs)[program]


def find_executable(bdir: Path, program: str) -> Executable:
    hits = [p for p in bdir.rglob(program) if p.is_file() and os.access(p, os.X_OK) and "CMakeFiles" not in p.parts]
    if len(hits) != 1:
        raise FileNotFoundError(f"expected one executable {program!r} under {bdir}, found {len(hits)}")
    return Executable(path=hits[0], size_bytes=hits[0].stat().st_size)


def ctest(bdir: Path, *, regex: str | None = None, jobs: int = 2, timeout_s: float = 600) -> subprocess.CompletedProcess:
    """Runs the C++ tests of `bdir` (under QEMU for cross builds); never raises on test failure."""
    cmd = ["ctest", "--output-on-failure", "-j", str(jobs), "--timeout", str(int(timeout_s))]
    if regex:
        cmd += ["-R", regex]
    return subprocess.run(cmd, cwd=bdir, capture_output=True, text=True, timeout=timeout_s + 60)


def _run(cmd: list[str], what: str) -> None:
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        tail = "\n".join((proc.stdout + proc.stderr).splitlines()[-40:])
        raise RuntimeError(f"{what} failed ({' '.join(cmd[:3])} ...):\n{tail}")
