"""Where rvd-pil finds what it needs and where it writes, from a checkout or from an installed wheel.
The one module that knows the difference; everything else asks it.

- From a checkout (this package inside the repository, as `make build`'s editable install has it):
  the C++ sources and cross toolchain files are the checkout's, builds and downloads go to
  <checkout>/build, reports to <checkout>/reports.
- From a wheel: the flight executable is the one the wheel bundles (rvd_pil/bin), the C++ sources
  and toolchain files for cross builds and plug-in guidance laws are the copy the wheel ships
  (rvd_pil/cpp); builds and downloads go to $RVD_CACHE_DIR, else ~/.cache/rvd-pil/<installation>
  (one folder per installation: a CMake build folder belongs to one source tree), reports to the
  current folder.

Package data that needs no build (scenarios, study files, the target registry, cycle models, the
QEMU plugins' C sources) sits beside the modules that read it.
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent
SHIPPED_SOURCES = PACKAGE / "cpp"   # what a wheel ships of the C++ tree (CMakeLists.txt, flight_sw/, cross/)
BUNDLED_BIN = PACKAGE / "bin"       # the flight executable a wheel bundles


def checkout() -> Path | None:
    """The repository this package is running from, None for an installed wheel."""
    root = PACKAGE.parent
    return root if (root / "CMakeLists.txt").is_file() and (root / "flight_sw").is_dir() else None


class CheckoutNeeded(RuntimeError):
    """What was asked needs the repository (C++ test tools, the test suite's support code, git)."""


def require_checkout(what: str) -> Path:
    """The checkout, or a one-line error saying that `what` needs one."""
    root = checkout()
    if root is None:
        raise CheckoutNeeded(f"{what} needs a checkout of rvd-pil (it is not part of the installed package)")
    return root


def source_root() -> Path:
    """The CMake source tree of the flight software: the checkout, or the wheel's copy."""
    root = checkout() or SHIPPED_SOURCES
    if not (root / "CMakeLists.txt").is_file():
        raise FileNotFoundError(f"no flight software sources at {root} (this installation ships none): "
                                "cross builds and plug-in guidance laws need a checkout of rvd-pil")
    return root


def cpp_tests() -> bool:
    """Whether the source tree has the C++ tests (a checkout does; a wheel ships without them)."""
    return (source_root() / "tests" / "cpp" / "CMakeLists.txt").is_file()


def build_root() -> Path:
    """Where builds, downloads (Debian packages, kernels, the plugin header) and caches go."""
    root = checkout()
    if root is not None:
        return root / "build"
    if os.environ.get("RVD_CACHE_DIR"):
        return Path(os.environ["RVD_CACHE_DIR"])
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return cache / "rvd-pil" / f"build-{hashlib.sha256(str(PACKAGE).encode()).hexdigest()[:12]}"


def reports_root() -> Path:
    """The default parent of campaign and benchmark reports."""
    return (checkout() or Path.cwd()) / "reports"
