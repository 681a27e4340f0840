"""Debian packages for emulation (ARM kernels, busybox-static, the qemu source package) fetched with
apt-get into a private apt state under build/apt.

A private state leaves the machine's apt configuration alone (no `dpkg --add-architecture`, no
deb-src entry in /etc/apt), does not contend for the system's apt locks, and lists only the
architectures we need. Downloads are cached by file name, which carries the package version.
Tolerated apt pitfalls: a foreign-architecture security index that fails
("File has unexpected size") and the "_apt couldn't access" warning when downloading as root.
"""
from __future__ import annotations

import fcntl
import os
import re
import subprocess
import time
from contextlib import contextmanager
from pathlib import Path

from rvd_pil import paths

APT_ROOT = paths.build_root() / "apt"
MIRROR = os.environ.get("RVD_DEBIAN_MIRROR", "http://deb.debian.org/debian")
SECURITY_MIRROR = os.environ.get("RVD_DEBIAN_SECURITY_MIRROR", "http://deb.debian.org/debian-security")
KEYRING = "/usr/share/keyrings/debian-archive-keyring.gpg"
FOREIGN_ARCHES = ("arm64", "armhf")
LISTS_MAX_AGE_S = 7 * 24 * 3600


class AptError(RuntimeError):
    pass


def _codename() -> str:
    text = Path("/etc/os-release").read_text()
    m = re.search(r"^VERSION_CODENAME=(\w+)", text, re.M)
    if not m:
        raise AptError("cannot tell the Debian release from /etc/os-release")
    return m.group(1)


def _options() -> list[str]:
    root = APT_ROOT
    return ["-o", f"Dir::Etc::sourcelist={root / 'sources.list'}",
            "-o", f"Dir::Etc::sourceparts={root / 'sources.list.d'}",
            "-o", f"Dir::Etc::preferencesparts={root / 'preferences.d'}",
            "-o", f"Dir::State::Lists={root / 'lists'}",
            "-o", f"Dir::Cache={root / 'cache'}",
            # Binary caches of the indexes make each apt-cache call ~20 ms instead of ~1.5 s
            # (container images often switch them off in /etc/apt/apt.conf.d).
            "-o", f"Dir::Cache::pkgcache={root / 'cache' / 'pkgcache.bin'}",
            "-o", f"Dir::Cache::srcpkgcache={root / 'cache' / 'srcpkgcache.bin'}",
            "-o", "APT::Architectures::=" + FOREIGN_ARCHES[0],
            *[x for a in FOREIGN_ARCHES[1:] for x in ("-o", f"APT::Architectures::={a}")], "-q"]


def _write_config() -> None:
    for d in ("sources.list.d", "preferences.d", "lists/partial", "cache/archives/partial", "debs", "src"):
        (APT_ROOT / d).mkdir(parents=True, exist_ok=True)
    rel = _codename()
    arch = ",".join(FOREIGN_ARCHES)
    lines = []
    for kind, opts in (("deb", f"arch={arch} signed-by={KEYRING}"), ("deb-src", f"signed-by={KEYRING}")):
        lines += [f"{kind} [{opts}] {MIRROR} {rel} main",
                  f"{kind} [{opts}] {MIRROR} {rel}-updates main",
                  f"{kind} [{opts}] {SECURITY_MIRROR} {rel}-security main"]
    text = "\n".join(lines) + "\n"
    path = APT_ROOT / "sources.list"
    if not path.exists() or path.read_text() != text:
        path.write_text(text)


@contextmanager
def _locked():
    APT_ROOT.mkdir(parents=True, exist_ok=True)
    with open(APT_ROOT / ".rvd-apt.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield


def _apt(tool: str, *args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([tool, *_options(), *args], cwd=cwd, capture_output=True, text=True)


def _have_lists() -> bool:
    lists = APT_ROOT / "lists"
    return any(lists.glob("*_main_binary-arm64_Packages*")) and any(lists.glob("*_main_source_Sources*"))


class NotCached(AptError):
    """Raised with fetch=False when something would have to be downloaded."""


def update(force: bool = False, fetch: bool = True) -> None:
    """Refreshes the private package lists when missing, older than a week, or forced. With
    fetch=False, uses whatever lists exist (raises NotCached when there are none)."""
    with _locked():
        _write_config()
        stamp = APT_ROOT / "lists" / ".rvd-updated"
        fresh = stamp.exists() and time.time() - stamp.stat().st_mtime < LISTS_MAX_AGE_S
        if _have_lists() and ((fresh and not force) or not fetch):
            return
        if not fetch:
            raise NotCached("no package lists yet (python -m rvd_pil.qemu prepare)")
        proc = _apt("apt-get", "update")
        # apt-get update exits 100 when any one index fails, e.g. the armhf security index
        # ("File has unexpected size"); the main indexes are what we need.
        if not _have_lists():
            raise AptError(f"apt-get update got no usable index:\n{proc.stdout[-2000:]}{proc.stderr[-2000:]}")
        stamp.touch()


def depends(package: str, fetch: bool = True) -> list[str]:
    """Direct dependencies of `package` (e.g. a kernel meta package -> the ABI-versioned image)."""
    update(fetch=fetch)
    proc = _apt("apt-cache", "depends", package)
    if proc.returncode != 0:
        raise AptError(f"apt-cache depends {package}: {proc.stderr.strip()}")
    return [m.group(1) for m in re.finditer(r"^\s+Depends: (\S+)", proc.stdout, re.M)]


def candidate_version(package: str, fetch: bool = True) -> str:
    update(fetch=fetch)
    proc = _apt("apt-cache", "policy", package)
    m = re.search(r"Candidate: (\S+)", proc.stdout)
    if proc.returncode != 0 or not m or m.group(1) == "(none)":
        raise AptError(f"no candidate version for {package} in the {_codename()} indexes")
    return m.group(1)


def download(package: str, arch: str, fetch: bool = True) -> Path:
    """The .deb of `package` for `arch` at its candidate version (downloaded once, then cached;
    with fetch=False raises NotCached instead of downloading)."""
    spec = f"{package}:{arch}"
    version = candidate_version(spec, fetch)
    name = f"{package}_{version.replace(':', '%3a')}_{arch}.deb"
    dest = APT_ROOT / "debs"
    if (dest / name).exists():
        return dest / name
    if not fetch:
        raise NotCached(f"{name} not downloaded yet (python -m rvd_pil.qemu prepare)")
    with _locked():
        proc = _apt("apt-get", "download", f"{spec}={version}", cwd=dest)
    if not (dest / name).exists():
        raise AptError(f"apt-get download {spec}={version} failed:\n{proc.stderr[-2000:]}")
    return dest / name


def source(package: str, version: str) -> Path:
    """Downloads (without unpacking) the source package `package`=`version`; returns its folder."""
    dest = APT_ROOT / "src" / f"{package}_{version.replace(':', '%3a')}"
    dsc = f"{package}_{version.split(':', 1)[-1]}.dsc"
    if (dest / dsc).exists():
        return dest
    dest.mkdir(parents=True, exist_ok=True)
    update()
    with _locked():
        proc = _apt("apt-get", "source", "--download-only", f"{package}={version}", cwd=dest)
    if not (dest / dsc).exists():
        raise AptError(f"apt-get source {package}={version} failed:\n{proc.stderr[-2000:]}")
    return dest


def installed_source_version(package: str) -> str:
    """Source version of an installed binary package (binNMU suffix dropped), e.g. 1:7.2+dfsg-7+deb12u18."""
    proc = subprocess.run(["dpkg-query", "-W", "-f=${source:Version}", package], capture_output=True, text=True)
    if proc.returncode != 0 or not proc.stdout.strip():
        raise AptError(f"{package} is not installed (tools/install-deps pil)")
    return proc.stdout.strip()
