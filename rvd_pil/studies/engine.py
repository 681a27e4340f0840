"""What computes a run (its engine), on the client and on the workers.

The client resolves, per (mode, target, CPU): the flight executable (the native build, or the
static cross build for the target), the instruction-counting plugin for QEMU user mode, or the
in-process flight_sw module; each is an `Artifact` named by its SHA-256. Executables travel to
remote workers as bytes (through Dask) and are written once into a cache folder named by that hash,
so a worker needs no shared filesystem. The simulator (host_sim) and the in-process module are not
sent: a worker must have the same installed, and says so when it does not (`check_worker`).
"""
from __future__ import annotations

import functools
import hashlib
import os
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

from rvd_pil import host_sim


def sha256_file(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@functools.lru_cache(maxsize=1)
def simulator_identity() -> dict:
    """The host simulator's source (every host_sim file) and the numerical libraries it runs on."""
    import numpy
    import scipy

    root = Path(host_sim.__file__).resolve().parent
    h = hashlib.sha256()
    for p in sorted(root.rglob("*")):
        if p.is_file() and p.suffix in (".py", ".toml") and "__pycache__" not in p.parts:
            h.update(str(p.relative_to(root)).encode() + b"\0" + p.read_bytes() + b"\0")
    # and the code of this package that turns a point into a run (settings -> flight options or
    # GuidanceParams, the in-process flight logic, the run itself)
    here = Path(__file__).resolve().parent
    r = hashlib.sha256()
    for name in ("settings.py", "inprocess.py", "run.py"):
        r.update(name.encode() + b"\0" + (here / name).read_bytes() + b"\0")
    return {"host_sim_sha": h.hexdigest()[:20], "runner_sha": r.hexdigest()[:20], "numpy": numpy.__version__,
            "scipy": scipy.__version__}


@functools.lru_cache(maxsize=1)
def module_sha() -> str:
    from rvd_pil import flight_sw

    return sha256_file(flight_sw.__file__)[:20]


@dataclass(frozen=True)
class Artifact:
    name: str          # file name it gets on a worker
    sha: str           # full SHA-256 hex digest of its bytes
    path: str          # where it is on the client
    size_bytes: int

    @classmethod
    def of(cls, path: str | Path, name: str | None = None) -> "Artifact":
        p = Path(path).resolve()
        return cls(name=name or p.name, sha=sha256_file(p), path=str(p), size_bytes=p.stat().st_size)

    def read(self) -> bytes:
        data = Path(self.path).read_bytes()
        if hashlib.sha256(data).hexdigest() != self.sha:
            raise RuntimeError(f"{self.path} changed since the study started (hash mismatch)")
        return data


def cache_dir() -> Path:
    base = os.environ.get("RVD_STUDY_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "rvd-study")
    return Path(base)


def materialize(art: Artifact, data: bytes | None) -> Path:
    """The artifact as a local executable file: from `data` (sent by the client) into the cache,
    or, without data, the client's own path (a local worker on the client's machine)."""
    if data is None:
        return Path(art.path)
    dest = cache_dir() / art.sha[:32] / art.name
    if dest.is_file() and dest.stat().st_size == len(data):
        return dest
    if hashlib.sha256(data).hexdigest() != art.sha:
        raise RuntimeError(f"{art.name}: the bytes received do not match their hash")
    dest.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=dest.parent, prefix=".part-")
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.chmod(tmp, 0o755)
    os.replace(tmp, dest)
    return dest


@dataclass(frozen=True)
class Engine:
    """Identity (goes into every run key) and artifacts of one (mode, target, CPU)."""

    mode: str
    identity: dict
    exe: Artifact | None = None
    plugin: Artifact | None = None
    target: object = None      # rvd_pil.qemu.targets.Target for qemu-user (plain data: pickles to workers)


def _qemu_version(binary: str) -> str:
    try:
        out = subprocess.run([binary, "--version"], capture_output=True, text=True, timeout=10).stdout
        return out.splitlines()[0].strip() if out else "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def resolve(mode: str, target_name: str, cpu: str | None, say=print) -> Engine:
    """Builds or finds what computes runs of this kind (may cross-compile: minutes the first time)."""
    ident = {"mode": mode, **simulator_identity()}
    if mode == "in-process":
        return Engine(mode, {**ident, "flight_sw_module": module_sha()})
    if mode == "native":
        from rvd_pil.host_sim.pil import find_flight_executable

        exe = Artifact.of(find_flight_executable())
        return Engine(mode, {**ident, "exe": exe.sha[:20]}, exe=exe)
    from rvd_pil.qemu import build, plugin, targets

    t = targets.load(target_name, cpu=cpu)
    say(f"{t.build_name}: cross-building the flight executable ({t.arch}, {t.cpu})")
    exe = Artifact.of(build.cross_build(t).path, name=f"rvd_flight_sw-{t.build_name}")
    lib = plugin.build(download=True)
    plug = Artifact.of(lib, name="librvd_insn_count.so")
    ident.update(exe=exe.sha[:20], plugin=plug.sha[:20], qemu=_qemu_version(t.qemu_user), build=t.build_name,
                 cpu=t.cpu, clock_hz=t.clock_hz, cpi={"nominal": t.cpi.nominal, "low": t.cpi.low, "high": t.cpi.high})
    return Engine(mode, ident, exe=exe, plugin=plug, target=t)


def check_worker(identity: dict) -> None:
    """Refuses to compute on a worker whose simulator or in-process module differs from the client's."""
    mine = simulator_identity()
    for k, v in mine.items():
        if identity.get(k) != v:
            raise RuntimeError(f"this worker's {k} is {v}, the client's {identity.get(k)}: install the same "
                               "rvd-pil on every worker")
    if "flight_sw_module" in identity and identity["flight_sw_module"] != module_sha():
        raise RuntimeError(f"this worker's flight_sw module is {module_sha()}, the client's "
                           f"{identity['flight_sw_module']}: install the same build on every worker")
