"""One import name for the project: everything Python is `rvd_pil.*`, so an installed wheel puts nothing
else at the top of site-packages. A file that still imports, runs (`python -m`) or lives under the old
top-level names (host_sim, bench, qemu, studies, flight_sw) works in a checkout by accident at most and
fails from an installed package; this finds it in the tracked files."""
from __future__ import annotations

import re
import subprocess
import tomllib
from pathlib import Path

from rvd_pil import paths

ROOT = Path(__file__).resolve().parents[1]
OLD = ("host_sim", "bench", "qemu", "studies", "flight_sw")
IMPORT = re.compile(r"(?:^\s*(?:>>> )?|`)(?:from|import)\s+(" + "|".join(OLD) + r")\b", re.M)  # code, doctest, `inline`
RUN = re.compile(r"-m(?:[\"'],)?\s+[\"']?(" + "|".join(OLD) + r")\b(?![-/])")  # python -m X, [..., "-m", "X"]


def tracked_text_files() -> list[Path]:
    names = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout.split(b"\0")
    files = [ROOT / n.decode() for n in names if n]
    return [f for f in files if f.suffix in (".py", ".md", ".toml", ".cfg", ".txt") or f.name in ("Makefile", "run")]


def test_nothing_imports_or_runs_the_old_top_level_names():
    offenders = []
    for f in tracked_text_files():
        if not f.is_file():
            continue
        text = f.read_text(encoding="utf-8", errors="replace")
        for m in (*IMPORT.finditer(text), *RUN.finditer(text)):
            line = text.count("\n", 0, m.start()) + 1
            offenders.append(f"{f.relative_to(ROOT)}:{line}: {text.splitlines()[line - 1].strip()}")
    assert not offenders, "use rvd_pil.<name>:\n" + "\n".join(offenders)


def test_the_wheel_holds_one_package_and_the_checkout_no_other():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert project["tool"]["scikit-build"]["wheel"]["packages"] == ["rvd_pil"]
    assert all(e.split("=")[1].strip().startswith("rvd_pil.") for e in
               (f"{k}={v}" for k, v in project["project"]["scripts"].items()))
    strays = [n for n in OLD if (ROOT / n).exists() and n != "flight_sw"]
    assert not strays, f"Python code outside rvd_pil/: {strays}"


def test_the_checkout_is_found_and_builds_go_into_it():
    assert paths.checkout() == ROOT
    assert paths.source_root() == ROOT and paths.cpp_tests()
    assert paths.build_root() == ROOT / "build"
