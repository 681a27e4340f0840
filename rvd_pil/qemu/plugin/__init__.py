"""The TCG plugins beside this file, built against the qemu-plugin.h of the installed QEMU:
insn_count.c (instructions per solve, written back into the guest) and block_profile.c (executions
per translation block per solve, and a cache model; read by rvd_pil/qemu/cycles.py).

No Debian binary package ships qemu-plugin.h, so build() fetches the qemu source package of
exactly the installed version (apt-get source into build/apt), takes only
include/qemu/qemu-plugin.h out of it into build/qemu-plugin/<version>/ (third-party: never
committed), refuses if a Debian patch changes that header, and compiles the plugin there. Every
step is cached; a new QEMU version gets a new folder.

    python -m rvd_pil.qemu.plugin          # fetch + build, prints the plugin path
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
import tarfile
from dataclasses import dataclass
from pathlib import Path

from rvd_pil import paths

from .. import debian

SOURCE = Path(__file__).with_name("insn_count.c")
PROFILE_SOURCE = Path(__file__).with_name("block_profile.c")
CACHE = paths.build_root() / "qemu-plugin"
HEADER_MEMBER = "include/qemu/qemu-plugin.h"
QEMU_PACKAGE = "qemu-user"  # the dynamic qemu-arm / qemu-aarch64 (plugins do not load in -static)


@dataclass(frozen=True)
class InsnCounter:
    """Plugin settings for one QEMU user-mode run."""

    log: Path                # the plugin writes "step insns" lines here (cross-check of the slots)
    count: str = "inline"    # "inline" (one counter, +1-2 %) or "vcpu" (per thread, exact with threads)
    library: Path | None = None  # default: build()

    def qemu_args(self) -> list[str]:
        if self.count not in ("inline", "vcpu"):
            raise ValueError(f"count must be 'inline' or 'vcpu', not {self.count!r}")
        if "," in str(self.log):
            raise ValueError(f"plugin log path must not contain ',': {self.log}")
        lib = self.library or build()
        if lib is None:
            raise RuntimeError("instruction-counting plugin not built: run `python -m rvd_pil.qemu.plugin`")
        return ["-plugin", f"{lib},log={self.log},count={self.count}"]


def _version_dir() -> Path:
    version = debian.installed_source_version(QEMU_PACKAGE)
    return CACHE / version.replace(":", "%3a")


def header(download: bool = True) -> Path | None:
    """qemu-plugin.h matching the installed QEMU; None if not cached and download is False."""
    vdir = _version_dir()
    dest = vdir / "include" / "qemu-plugin.h"
    if dest.exists():
        return dest
    if not download:
        return None
    version = debian.installed_source_version(QEMU_PACKAGE)
    src = debian.source("qemu", version)
    orig = next(src.glob("qemu_*.orig.tar.*"), None)
    deb = next(src.glob("qemu_*.debian.tar.*"), None)
    if orig is None or deb is None:
        raise debian.AptError(f"qemu source package in {src} lacks its orig or debian tarball")
    _refuse_patched_header(deb)
    with tarfile.open(orig) as tar:
        member = next((m for m in tar if m.name.endswith("/" + HEADER_MEMBER)), None)
        if member is None:
            raise debian.AptError(f"{orig.name} has no {HEADER_MEMBER}")
        data = tar.extractfile(member).read()
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = dest.with_suffix(".tmp")
    tmp.write_bytes(data)
    tmp.rename(dest)
    return dest


def _refuse_patched_header(debian_tar: Path) -> None:
    """Debian applies upstream point releases as patches: the header must be untouched by them."""
    with tarfile.open(debian_tar) as tar:
        for m in tar:
            if m.isfile() and "/patches/" in m.name and HEADER_MEMBER.encode() in tar.extractfile(m).read():
                raise debian.AptError(f"Debian patch {m.name} changes {HEADER_MEMBER}: the orig header "
                                      "does not match the installed QEMU; apply the patch by hand")


def api_version(header_path: Path) -> int:
    m = re.search(r"^#define QEMU_PLUGIN_VERSION (\d+)", header_path.read_text(), re.M)
    if not m:
        raise ValueError(f"{header_path}: no QEMU_PLUGIN_VERSION")
    return int(m.group(1))


def build(download: bool = True, source: Path = SOURCE) -> Path | None:
    """Path of the compiled plugin `source` (built if missing or older than its source); None
    when the header is not cached and download is False."""
    hdr = header(download)
    if hdr is None:
        return None
    lib = hdr.parent.parent / f"librvd_{source.stem}.so"
    if lib.exists() and lib.stat().st_mtime >= source.stat().st_mtime:
        return lib
    tmp = lib.with_suffix(f".{os.getpid()}.tmp.so")
    cmd = ["gcc", "-std=c11", "-O2", "-Wall", "-Wextra", "-fPIC", "-shared",
           f"-I{hdr.parent}", str(source), "-o", str(tmp), "-lpthread"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"plugin build failed:\n{proc.stderr}")
    tmp.rename(lib)
    return lib


def build_profile(download: bool = True) -> Path | None:
    """The block-profile plugin (block_profile.c), built like build()."""
    return build(download, PROFILE_SOURCE)


@dataclass(frozen=True)
class BlockProfiler:
    """Settings of the block-profile plugin for one QEMU user-mode run (beside InsnCounter)."""

    out: Path                          # the plugin's output (rvd_pil/qemu/cycles.py reads it)
    cache: "tuple[tuple[int, int, int], tuple[int, int, int], tuple[int, int, int]] | None" = None
    #                                    (l1d, l1i, l2) as (size bytes, ways, line bytes); None: off
    library: Path | None = None        # default: build_profile()
    # "solves": the cache model sees the solve regions only (each starts from the state the previous
    # one left: repeatable); "process": every access (a board calibration compares the whole process)
    cache_scope: str = "solves"

    def qemu_args(self) -> list[str]:
        if "," in str(self.out):
            raise ValueError(f"profile path must not contain ',': {self.out}")
        if self.cache_scope not in ("solves", "process"):
            raise ValueError(f"cache_scope must be 'solves' or 'process', not {self.cache_scope!r}")
        lib = self.library or build_profile()
        if lib is None:
            raise RuntimeError("block-profile plugin not built: run `python -m rvd_pil.qemu.plugin`")
        args = f"{lib},out={self.out}"
        if self.cache is not None:
            l1d, l1i, l2 = self.cache
            args += ",cache=on" if self.cache_scope == "solves" else ",cache=process"
            args += "".join(f",{name}={g[0]}:{g[1]}:{g[2]}" for name, g in (("l1d", l1d), ("l1i", l1i), ("l2", l2)))
        return ["-plugin", args]


def read_log(path: Path) -> list[tuple[int, int]]:
    """(step, instructions) pairs from a plugin log; comment lines (#) are skipped."""
    pairs = []
    for line in Path(path).read_text().splitlines():
        if line and not line.startswith("#"):
            step, insns = line.split()
            pairs.append((int(step), int(insns)))
    return pairs


def main() -> int:
    lib = build(download=True)
    profile = build_profile(download=False)
    hdr = header(download=False)
    print(f"{lib}\n{profile}  (qemu-plugin.h API version {api_version(hdr)}, "
          f"QEMU {debian.installed_source_version(QEMU_PACKAGE)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
