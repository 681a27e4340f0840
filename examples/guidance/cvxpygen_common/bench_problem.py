"""One generated problem (generate.py's output for one phase and horizon) outside the flight software:
built with solve_driver.c for a target, and solved on fixed data, natively or under qemu-user with the
instruction counter. For studies of the generated solver: its settings, and what the generator's cut
functions (--split-lines) cost.

    python generate.py --out build/gen --solver QOCOGEN --horizons 15/5/5 [--split-lines 0]
    python bench_problem.py build/gen/<key>/a5 --target q7s --repeat 3 [--params FILE] [iter_ref_iters=5 ...]

FOLDER is one problem's folder of a generation (its rvd_*.c wrappers and rvd_glue.c). The parameters
are those of our QP builder (flight_sw.PhaseQp, default guidance parameters, as codegen_law.cpp copies
them) for a state of Case 1 (rendezvous: its initial state; approach and docking: a state on the V-bar
near the port), unless --params gives a file in solve_driver.c's format. Every source is compiled on
its own, in turn, with the flight software's C flags (CMake Release: -O3 -DNDEBUG, plus the target's
-mcpu/-mfpu; static for emulated targets); the CPU time of each compile is printed. Then REPEAT solves
of the same data: status, iterations and, under QEMU, instructions per solve (plugin log).
"""
from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
NAMES = ("x0", "A", "B", "q", "ubox", "keepout_C", "keepout_d", "cone_C", "cone_d", "speed_C", "speed_d", "vel_d")
PHASES = {"r": "rendezvous", "a": "approach", "d": "docking"}


def problem_sizes(folder: Path) -> tuple[str, int, dict[str, int]]:
    """The prefix, horizon and parameter sizes of a generated problem (from its rvd_glue.c)."""
    text = (folder / "rvd_glue.c").read_text()
    m = re.search(r"const rvd_cpg_problem (\w+)_rvd_problem = \{\s*(\d+), (\d+), \"\w+\", \{([\d, ]+)\}", text)
    if not m:
        raise SystemExit(f"{folder}: no rvd_glue.c with a problem table")
    sizes = [int(v) for v in m.group(4).split(",")]
    return m.group(1), int(m.group(3)), dict(zip(NAMES, sizes))


def builder_params(prefix: str, N: int, sizes: dict[str, int]) -> dict[str, np.ndarray]:
    """The generated problem's parameters for our builder's QP at a fixed state (codegen_law.cpp load())."""
    from rvd_pil import flight_sw

    phase = PHASES[prefix[0]]
    p = flight_sw.GuidanceParams()
    getattr(p, phase).N = N
    case = flight_sw.dissertation_case(1)
    x = np.asarray(case["x0"], float) if phase == "rendezvous" else np.array([0.2, 40.0, 0.1, 0.0, -0.05, 0.0])
    b = flight_sw.PhaseQp({"rendezvous": flight_sw.Phase.Rendezvous, "approach": flight_sw.Phase.Approach,
                           "docking": flight_sw.Phase.Docking}[phase], p)
    qp = b.build(x, np.asarray(case["q_lvlh_body"], float), np.asarray(case["omega_body_rad_s"], float))
    v = {name: [] for name in NAMES}
    v["x0"] = list(x)
    A, B = np.asarray(qp["A"][0]), np.asarray(qp["B"][0])
    v["A"], v["B"] = list(A.ravel()), list(B[:, :3].ravel())
    for i in range(N + 1):
        v["q"] += list(np.asarray(qp["q"][i]))
        C, d = np.asarray(qp["C"][i]).reshape(-1, 6), np.asarray(qp["d"][i])
        if i < N:
            v["ubox"] += list(d[:6])  # the box is a stage's first 6 rows (phase_qp.cpp StageLayout)
        if i == 0:
            continue
        k = b.keepout_row(i)
        if k >= 0 and sizes["keepout_d"]:
            v["keepout_C"] += list(C[k, :3])
            v["keepout_d"].append(d[k])
        if sizes["speed_d"]:  # approach: the closing-speed row follows the overshoot plane when there is one
            c = b.cone_row(i)
            has = k >= 0 and k + 1 < len(d) and k + 1 != c and b.velocity_row(i) != k + 1
            v["speed_C"] += list(C[k + 1, 3:]) if has else [0.0, 0.0, 0.0]
            v["speed_d"].append(d[k + 1] if has else 1.0)
        c = b.cone_row(i)
        if c >= 0 and sizes["cone_d"]:
            for r in range(4):
                v["cone_C"] += list(C[c + r, :3])
                v["cone_d"].append(d[c + r])
        vr = b.velocity_row(i)
        if vr >= 0 and sizes["vel_d"]:
            v["vel_d"] += list(d[vr:vr + 6])
    ref = flight_sw.solve_ocp_qp(**qp)
    print(f"{prefix}: our Fast MPC on the same QP: {ref.status}, u0 " + " ".join(f"{u:.17g}" for u in np.asarray(ref.u[0])[:3]))
    out = {}
    for name in NAMES:
        if sizes[name]:
            if len(v[name]) != sizes[name]:
                raise SystemExit(f"{prefix}: {name} has {len(v[name])} values, the generated problem {sizes[name]}")
            out[name] = np.asarray(v[name], float)
    return out


def write_params(path: Path, params: dict[str, np.ndarray]) -> None:
    path.write_text("".join(f"{NAMES.index(k)} {len(v)} " + " ".join(repr(float(x)) for x in v) + "\n"
                            for k, v in params.items()))


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def build(folder: Path, prefix: str, target, out: Path) -> tuple[Path, list[tuple[str, float]]]:
    """The driver and the problem's sources compiled one by one (CPU seconds each) and linked."""
    cc = target.compiler.replace("g++", "gcc") if target.emulated else os.environ.get("CC", "cc")
    flags = ["-O3", "-DNDEBUG", *target.compile_flags, "-w", f"-I{folder}", f"-I{HERE}"]
    sources = sorted(folder.glob("rvd_*.c")) + [HERE / "solve_driver.c"]
    out.mkdir(parents=True, exist_ok=True)
    objs, times = [], []
    for src in sources:
        obj = out / (src.stem + ".o")
        extra = [f"-DRVD_PREFIX={prefix}", "-DRVD_QOCOGEN"] if src.name == "solve_driver.c" else []
        t0 = _cpu_s()
        subprocess.run([cc, *flags, *extra, "-c", str(src), "-o", str(obj)], check=True)
        times.append((src.name, _cpu_s() - t0))
        objs.append(obj)
    exe = out / f"solve_{prefix}"
    subprocess.run([cc, *(["-static"] if target.emulated else []), *target.compile_flags, *map(str, objs), "-lm", "-o",
                    str(exe)], check=True)
    return exe, times


def run(exe: Path, target, params: Path, repeat: int, settings: list[str]) -> tuple[str, list[int]]:
    """The driver's output, and the instructions of each solve (empty natively)."""
    from rvd_pil.qemu import user
    from rvd_pil.qemu.plugin import InsnCounter

    args = [str(params), str(repeat), *settings]
    if not target.emulated:
        return subprocess.run([str(exe), *args], check=True, capture_output=True, text=True).stdout, []
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "insns.log"
        r = user.run(target, exe, args, plugin=InsnCounter(log=log), check=True)
        counts = [int(ln.split()[1]) for ln in log.read_text().splitlines() if ln.strip() and ln.split()[0].isdigit()]
    return r.stdout, counts


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", type=Path, help="one generated problem's folder (generate.py's OUT/<key>/<prefix>)")
    ap.add_argument("--target", default="host", help="host (native) or an emulated target of rvd_pil/qemu/targets.toml")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--params", type=Path, help="parameters in solve_driver.c's format (default: our builder's QP)")
    ap.add_argument("--out", type=Path, help="build folder (default: FOLDER/bench-<target>)")
    ap.add_argument("settings", nargs="*", help="QOCOGEN settings after the law's, NAME=VALUE")
    a = ap.parse_intermixed_args(argv)
    from rvd_pil.qemu import targets

    target = targets.load(a.target)
    folder = a.folder.resolve()
    prefix, N, sizes = problem_sizes(folder)
    out = (a.out or folder / f"bench-{a.target}").resolve()
    params = a.params
    if params is None:
        params = out / "params.txt"
        out.mkdir(parents=True, exist_ok=True)
        write_params(params, builder_params(prefix, N, sizes))
    t0 = time.time()
    exe, times = build(folder, prefix, target, out)
    print(f"{prefix} for {a.target}: compile CPU {sum(t for _, t in times):.1f} s ({time.time() - t0:.0f} s wall): " +
          ", ".join(f"{n} {t:.1f}" for n, t in times), flush=True)
    stdout, counts = run(exe, target, params, a.repeat, a.settings)
    print(stdout, end="")
    if counts:
        print(f"{prefix} instructions per solve: " + " ".join(map(str, counts)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
