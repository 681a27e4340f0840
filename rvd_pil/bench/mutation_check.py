"""Mutation check of the test suite's teeth: deliberate defects, one at a time, in a copy of the tree;
each must make the tests fail. A benchmark (minutes per defect), not part of `make test`.

    python -m rvd_pil.bench.mutation_check                  # every mutation, the relevant tests of each
    python -m rvd_pil.bench.mutation_check --only cw_sign   # one (comma-separated names)
    python -m rvd_pil.bench.mutation_check --full           # the whole suite (ctest + pytest) per mutation
    python -m rvd_pil.bench.mutation_check --list           # the mutations and what each runs

The copy (tracked and untracked, not ignored, files of this checkout) gets its own CMake build with
the flight executable, the C++ tests and the `rvd_pil.flight_sw` Python module; the tests run against that
copy only (the checkout's editable install is taken out of the import path). Each mutation is a
textual edit that must apply exactly once; after it the copy is rebuilt incrementally, the tests
run, and the edit is undone. Printed per mutation: the tests that failed ("caught by"), or SURVIVED.
Exit status 1 when a mutation survives or does not apply.

Measured (2 cores shared with other jobs; the copy's first build 26 min, each mutation 2-6 min): all six
caught. cw_sign: test_guidance_cw, test_guidance_closed_loop (C++), and in Python the STM against expm,
the phase QP dynamics, the log against the CW plant, the phase figures and the dissertation totals;
dropped_overshoot_row: test_guidance_phase_qp, test_guidance_safety, the recovery QP against Clarabel (again with the
edit following the row's `&& !holding` condition: `--only dropped_overshoot_row`, 39 s of tests);
horizon_off_by_one: test_guidance_phase_qp, test_guidance_safety (the closed loop still docks with N - 1);
thrust_unit: test_guidance_allocation, test_guidance_closed_loop, test_guidance_noalloc and five Python
closed-loop tests; mib_unit: test_guidance_allocation only, so the closed-loop allocation check was made two-sided:
with it, tests/test_guidance_closed_loop.py::test_thrust_and_docking_limits (3 cases) fails too (checked on a
module built with the mutation); skipped_tag_check: test_link_messages and three forgery tests
of tests/test_pil_integrity.py.
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from rvd_pil import paths



@dataclass
class Mutation:
    name: str
    what: str
    path: str
    old: str
    new: str
    ctest: str = ""                      # ctest -R regex ('' = none)
    pytest: list[str] = field(default_factory=list)
    regenerate: bool = False             # run schema/generate.py after the edit (a generator template)


MUTATIONS = [
    Mutation("cw_sign", "a sign in the CW matrix: the Coriolis term of the radial velocity, +2 sin(nt) -> -2 sin(nt)",
             "flight_sw/guidance/cw.cpp", "P(3, 4) = 2.0 * s;", "P(3, 4) = -2.0 * s;",
             ctest="test_guidance_", pytest=["tests/test_guidance_cw.py", "tests/test_guidance_closed_loop.py"]),
    Mutation("dropped_overshoot_row", "a dropped constraint row: the approach phase's overshoot plane is never filled in",
             "flight_sw/guidance/phase_qp.cpp", "    if (L.keepout_row >= 0 && !holding) {  // overshoot plane",
             "    if (L.keepout_row >= 0 && !holding && false) {  // overshoot plane",
             ctest="test_guidance_", pytest=["tests/test_guidance_qp.py", "tests/test_guidance_closed_loop.py"]),
    Mutation("horizon_off_by_one", "an off-by-one in the horizon: every phase QP is built with N - 1 stages",
             "flight_sw/guidance/phase_qp.cpp", "  N_ = pp.N;", "  N_ = pp.N - 1;",
             ctest="test_guidance_", pytest=["tests/test_guidance_qp.py", "tests/test_guidance_closed_loop.py"]),
    Mutation("thrust_unit", "a wrong unit in the thruster model: the pulse width computed with the thrust in mN where the formula wants N",
             "flight_sw/guidance/allocation.cpp", "double t = thr.mass_kg * std::abs(v) / (s * thr.thrust_N);",
             "double t = thr.mass_kg * std::abs(v) / (s * thr.thrust_N * 1e3);",
             ctest="test_guidance_", pytest=["tests/test_guidance_closed_loop.py", "tests/test_guidance_qp.py"]),
    Mutation("mib_unit", "a wrong unit in the thruster model: the minimum impulse bit compared in ms against a pulse in s",
             "flight_sw/guidance/allocation.cpp", "if (t < thr.min_impulse_bit_s) continue;",
             "if (t * 1e3 < thr.min_impulse_bit_s) continue;",
             ctest="test_guidance_", pytest=["tests/test_guidance_closed_loop.py"]),
    Mutation("skipped_tag_check", "a skipped tag check in link authentication: the flight side opens a message "
             "without comparing its tag (generator template, codecs regenerated)",
             "schema/generate.py",
             "    if (!link::equal_constant_time(tag, m + n - kTagSize, kTagSize)) return Error::BadTag;\n",
             "", regenerate=True,
             ctest="test_link_", pytest=["tests/test_link_messages.py", "tests/test_pil_integrity.py"]),
]


def run(cmd, cwd, env=None, log=None) -> tuple[int, str]:
    out = subprocess.run(cmd, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if log is not None:
        log.write(f"$ {' '.join(map(str, cmd))}\n{out.stdout}\n")
    return out.returncode, out.stdout


def copy_tree(dst: Path) -> None:
    repo = paths.require_checkout("the mutation check")
    files = subprocess.run(["git", "ls-files", "-z", "-co", "--exclude-standard"], cwd=repo, check=True,
                           stdout=subprocess.PIPE).stdout.decode().split("\0")
    for f in filter(None, files):
        src = repo / f
        if src.is_file():
            (dst / f).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dst / f)


# pytest in the copy, with the checkout's editable install (a meta-path finder that maps rvd_pil and
# rvd_pil.flight_sw to the checkout) removed, so the copy's sources and module are imported.
BOOT = ("import os, sys; sys.meta_path[:] = [f for f in sys.meta_path if 'editable' not in type(f).__module__.lower() "
        "and 'editable' not in type(f).__name__.lower()]; from rvd_pil import flight_sw, host_sim; "
        "bad = [m.__name__ for m in (flight_sw, host_sim) if not m.__file__.startswith(os.getcwd())]; "
        "bad and sys.exit('not the copy: ' + ', '.join(bad)); import pytest; sys.exit(pytest.main(sys.argv[1:]))")


class Copy:
    def __init__(self, root: Path, jobs: int, log):
        self.root, self.jobs, self.log = root, jobs, log
        self.build = root / "build" / "native"
        self.env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
                        PYTHONPATH=str(root),
                        RVD_FLIGHT_SW=str(self.build / "flight_sw" / "rvd_flight_sw"),
                        RVD_ZENOH_PROBE=str(self.build / "tests" / "cpp" / "zenoh_probe"))

    def configure(self) -> None:
        rc, out = run(["cmake", "-S", ".", "-B", str(self.build), "-DCMAKE_BUILD_TYPE=Release", "-DRVD_BUILD_TESTS=ON",
                       "-DRVD_BUILD_PYTHON=ON", f"-DPython_EXECUTABLE={sys.executable}"], self.root, log=self.log)
        if rc:
            raise SystemExit(f"cmake configure of the copy failed:\n{out[-3000:]}")
        # the copy's module, where `from rvd_pil import flight_sw` finds it (rebuilt in place)
        module = "flight_sw" + sysconfig.get_config_var("EXT_SUFFIX")
        (self.root / "rvd_pil" / module).symlink_to(self.build / "flight_sw" / module)

    def rebuild(self) -> tuple[bool, str]:
        rc, out = run(["nice", "-n", "10", "cmake", "--build", str(self.build), "-j", str(self.jobs)], self.root,
                      log=self.log)
        return rc == 0, out

    def ctest(self, regex: str | None) -> list[str]:
        cmd = ["ctest", "--output-on-failure", "-j", str(self.jobs)] + (["-R", regex] if regex else [])
        rc, out = run(cmd, self.build, env=self.env, log=self.log)
        failed = re.findall(r"^\s*\d+ - (\S+) \(", out, flags=re.M)
        return failed or ([f"ctest exit {rc}"] if rc else [])

    def pytest(self, paths: list[str]) -> list[str]:
        cmd = [sys.executable, "-c", BOOT, "-q", "-p", "no:cacheprovider", "-rf", *paths]
        rc, out = run(cmd, self.root, env=self.env, log=self.log)
        failed = sorted(set(re.findall(r"^(?:FAILED|ERROR) (\S+?)(?: - |$)", out, flags=re.M)))
        return failed or ([f"pytest exit {rc}"] if rc not in (0, 5) else [])


def summarize(failed: list[str]) -> str:
    """Failed tests, parametrizations of one test function counted together: 'file::test (3 cases)'."""
    groups: dict[str, int] = {}
    for f in failed:
        key = f.split("[", 1)[0]
        groups[key] = groups.get(key, 0) + 1
    return ", ".join(k + (f" ({n} cases)" if n > 1 else "") for k, n in groups.items())


def apply(root: Path, m: Mutation) -> str:
    path = root / m.path
    text = path.read_text()
    if text.count(m.old) != 1:
        raise ValueError(f"{m.name}: the text to mutate occurs {text.count(m.old)} times in {m.path}")
    path.write_text(text.replace(m.old, m.new))
    if m.regenerate:
        subprocess.run([sys.executable, "schema/generate.py"], cwd=root, check=True, stdout=subprocess.DEVNULL)
    return text


def undo(root: Path, m: Mutation, original: str) -> None:
    (root / m.path).write_text(original)
    if m.regenerate:
        subprocess.run([sys.executable, "schema/generate.py"], cwd=root, check=True, stdout=subprocess.DEVNULL)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", help="comma-separated mutation names")
    ap.add_argument("--full", action="store_true", help="run the whole suite (every ctest, every pytest file) per mutation")
    ap.add_argument("--list", action="store_true", help="list the mutations and exit")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--keep", action="store_true", help="keep the copy (its path is printed) and the log")
    a = ap.parse_args(argv)
    chosen = MUTATIONS
    if a.only:
        names = a.only.split(",")
        unknown = [n for n in names if n not in {m.name for m in MUTATIONS}]
        if unknown:
            print(f"mutation_check: unknown mutation(s) {', '.join(unknown)}; --list shows them", file=sys.stderr)
            return 2
        chosen = [m for m in MUTATIONS if m.name in names]
    if a.list:
        for m in chosen:
            print(f"{m.name:<22} {m.path}: {m.what}\n{'':<22} runs: ctest -R '{m.ctest}', pytest {' '.join(m.pytest)}")
        return 0

    root = Path(tempfile.mkdtemp(prefix="rvd-mutants-"))
    log = open(root / "mutation_check.log", "w")
    print(f"copy of the checkout: {root} (log: mutation_check.log there)")
    try:
        copy_tree(root)
        c = Copy(root, a.jobs, log)
        t0 = time.monotonic()
        c.configure()
        ok, out = c.rebuild()
        if not ok:
            print(f"the unmutated copy does not build:\n{out[-3000:]}", file=sys.stderr)
            return 1
        print(f"unmutated copy built in {time.monotonic() - t0:.0f} s")
        # The baseline: the unmutated copy passes what the mutations will run, so a failure is the mutation's.
        base_ct = sorted({m.ctest for m in chosen if m.ctest})
        base_py = sorted({p for m in chosen for p in m.pytest})
        base_fail = (c.ctest(None) + c.pytest(["tests"])) if a.full else \
            ([f for r in base_ct for f in c.ctest(r)] + c.pytest(base_py))
        if base_fail:
            print(f"the unmutated copy fails already: {', '.join(base_fail)}", file=sys.stderr)
            return 1
        print("unmutated copy: the selected tests pass\n")
        survived = 0
        rows = []
        for m in chosen:
            t0 = time.monotonic()
            try:
                original = apply(root, m)
            except (ValueError, subprocess.CalledProcessError) as e:
                print(f"{m.name}: DOES NOT APPLY ({e})")
                survived += 1
                continue
            try:
                ok, out = c.rebuild()
                if not ok:
                    caught = ["(does not compile)"]
                else:
                    caught = (c.ctest(None) + c.pytest(["tests"])) if a.full else \
                        ((c.ctest(m.ctest) if m.ctest else []) + (c.pytest(m.pytest) if m.pytest else []))
            finally:
                undo(root, m, original)
            survived += not caught
            rows.append((m, caught, time.monotonic() - t0))
            print(f"{m.name}: {m.what}")
            print(f"  {m.path}: {m.old.strip()!r} -> {m.new.strip()!r}")
            print(f"  {'caught by ' + summarize(caught) if caught else 'SURVIVED'}  ({time.monotonic() - t0:.0f} s)\n",
                  flush=True)
        if a.keep:
            c.rebuild()  # leave the kept copy built as it was
        print(f"{sum(1 for _, c, _ in rows if c)} of {len(chosen)} mutations caught"
              + (f"; {survived} survived or did not apply" if survived else ""))
        return 1 if survived else 0
    finally:
        log.close()
        if not a.keep:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
