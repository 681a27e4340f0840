"""flight_sw's solver against DAQP on the flight CPUs: both cross-built for each target, solving the
same QPs under QEMU user mode, every solve priced by the target's cycle model (instructions, modelled
cycles at the target clock). The host benchmark (`python -m rvd_pil.bench.solvers`) ranks the solvers
on this machine's x86 core; this one answers the product's question for the peer that is closest on
few inputs: on the flight computer, which solver is faster, and by how much.

    python -m rvd_pil.bench.target_solvers                                  # synthetic MPC QPs (make bench)
    python -m rvd_pil.bench.target_solvers --qp-set cl.npz                  # docking and approach cells
    python -m rvd_pil.bench.target_solvers --qp-set cl.npz --cells docking:5 --per-cell 40 --targets rpi3
    python -m rvd_pil.bench.target_solvers --qp-set cl.npz --cells all --out reports/target-solvers

What runs: flight_sw/tools/solve_qp_file.cpp (flight_sw's solver, the host benchmark's settings:
tol 1e-8, cold, the interior point in the rendezvous as the guidance flies it) and
rvd_pil/bench/peer_drivers/daqp_solve_file.c (DAQP's C sources, from the PyPI sdist of the daqp
version installed here, fetched once into build/; the host benchmark's settings and condensed QP).
Both are built as the flight executable is (the target's compiler, -O3, its -mcpu flags, static).
Each solver runs in its own process, one QP after another, each solve between two solve markers;
what runs before the marker is each solver's set-up as the host benchmark leaves it off its clock
(flight_sw: setup(), the condensing, with one QP and one solver object per shape filled and set up
again, as a guidance keeps them per phase; DAQP: its setup, the LDP form of the condensed QP). The
block profiler's cache model sees the solve regions only, each starting from the caches the last
one left: the solver's previous QP, as in a flight.

Every answer is checked on the host: the OCP objective of the returned inputs (states rolled out)
against the reference (ProxSuite at 1e-10, Clarabel where it fails), 1e-6 relative; a wrong or
failed answer is counted as bad and its time left in. A QP the reference finds infeasible must be
called infeasible by both, and is left out of the times, as in the host benchmark. Cells are picked by the QP set's phase labels
(the closed-loop set has them). `--cells all` adds the rendezvous (the interior point), where DAQP's
dense solves take QEMU minutes per cell.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import struct
import sys
import time
import urllib.request
from collections import defaultdict
from pathlib import Path

import numpy as np

from rvd_pil import paths

paths.require_checkout("the target peer benchmark (its QP forms are tests/support/qp_forms.py)")
from support.qp_forms import load_qp_set  # noqa: E402

from rvd_pil.bench import solvers as host_bench  # noqa: E402

WORK = paths.build_root() / "target_solvers"
FLIGHT_DRIVER = "rvd_solve_qp_file"
DAQP_DRIVER = Path(__file__).with_name("peer_drivers") / "daqp_solve_file.c"
ACTIVE_SET_CELLS = ("docking:5", "docking:12", "docking:30", "approach:5", "approach:15", "approach:30")


# ---- the QP files (formats: the drivers' headers) -----------------------------------------------
def write_ocp_file(path: Path, qps) -> None:
    """flight_sw's input: each QP stage-wise, matrices column-major (Eigen's order)."""
    def mat(m):
        return np.asarray(m, float).ravel(order="F").tobytes()

    out = [b"RVDOCP01", struct.pack("<I", len(qps))]
    for qp in qps:
        N, soft = qp.N, qp.idxs is not None and any(len(k) for k in qp.idxs)
        out.append(struct.pack("<3i", N, qp.nx, 1 if qp.phase == "rendezvous" else 0))
        for dims in (qp.nu, qp.nc, qp.ns if soft else [0] * (N + 1)):
            out.append(np.asarray(dims, "<i4").tobytes())
        for i in range(N):
            out += [mat(qp.A[i]), mat(qp.B[i]), mat(qp.b[i])]
        for i in range(N + 1):
            out += [mat(qp.Q[i]), mat(qp.R[i]), mat(qp.q[i]), mat(qp.r[i]), mat(qp.C[i]), mat(qp.D[i]), mat(qp.d[i])]
        if soft:
            for i in range(N + 1):
                out += [np.asarray(qp.idxs[i], "<i4").tobytes(), mat(qp.zs[i]), mat(qp.Zs[i])]
        out.append(mat(qp.x0))
    path.write_bytes(b"".join(out))


def write_condensed_file(path: Path, condensed) -> None:
    """DAQP's input: the condensed QPs as the host benchmark gives them (every row general)."""
    out = [b"RVDDNS01", struct.pack("<I", len(condensed))]
    for c in condensed:
        n, m = c.H.shape[0], len(c.h)
        out.append(struct.pack("<2i", n, m))
        for a in (c.H, c.g, c.G, c.h, np.full(m, -1e30)):
            out.append(np.ascontiguousarray(a, "<f8").tobytes())
    path.write_bytes(b"".join(out))


def parse_answers(stdout: str, key: str) -> dict[int, tuple[str, np.ndarray]]:
    """Driver output -> QP index: (status, the vector after `key`)."""
    answers = {}
    for line in stdout.splitlines():
        parts = line.split()
        if len(parts) < 4 or parts[0] != "qp" or key not in parts:
            continue
        at = parts.index(key)
        answers[int(parts[1])] = (parts[3], np.array([float(v) for v in parts[at + 1:]]))
    return answers


def in_condensed_layout(c, qp, u_flat: np.ndarray) -> np.ndarray | None:
    """flight_sw's inputs (stages 0..N concatenated) as a vector of the condensed QP `c` (whose soft
    rows' slacks, which CondensedQp.unstack skips, stay 0); None when the count is wrong."""
    if len(u_flat) != sum(qp.nu):
        return None
    U, off = np.zeros(c.H.shape[0]), 0
    for i, s in enumerate(c.u_idx):
        U[s.start:s.start + qp.nu[i]] = u_flat[off:off + qp.nu[i]]
        off += qp.nu[i]
    return U


# ---- builds ------------------------------------------------------------------------------------
def daqp_sources() -> Path:
    """DAQP's C sources (csrc/) of the daqp version installed here, from its PyPI sdist (checked
    against PyPI's sha256), unpacked once under build/target_solvers/."""
    import importlib.metadata
    import tarfile
    version = importlib.metadata.version("daqp")
    root = WORK / f"daqp-{version}"
    csrc = root / f"daqp-{version}" / "csrc"
    if (csrc / "src" / "daqp.c").is_file():
        return csrc
    root.mkdir(parents=True, exist_ok=True)
    # PyPI's simple index (PEP 691 JSON): every file of the project with its sha256
    req = urllib.request.Request("https://pypi.org/simple/daqp/", headers={"Accept": "application/vnd.pypi.simple.v1+json"})
    with urllib.request.urlopen(req, timeout=60) as r:
        files = json.load(r)["files"]
    sdists = [f for f in files if f["filename"] == f"daqp-{version}.tar.gz"]
    if not sdists:
        raise RuntimeError(f"PyPI lists no source distribution of daqp {version}")
    with urllib.request.urlopen(sdists[0]["url"], timeout=120) as r:
        blob = r.read()
    if hashlib.sha256(blob).hexdigest() != sdists[0]["hashes"]["sha256"]:
        raise RuntimeError(f"daqp {version} sdist: sha256 differs from PyPI's")
    import io
    import shutil
    import tempfile
    with tempfile.TemporaryDirectory(dir=root) as tmp:  # unpacked aside, then moved in whole
        with tarfile.open(fileobj=io.BytesIO(blob)) as tar:
            tar.extractall(tmp, filter="data")
        if not (Path(tmp) / f"daqp-{version}" / "csrc" / "src" / "daqp.c").is_file():
            raise RuntimeError(f"daqp {version} sdist has no csrc/src/daqp.c")
        if not csrc.parent.exists():
            shutil.move(str(Path(tmp) / f"daqp-{version}"), str(csrc.parent))
    return csrc


def build_daqp_driver(target) -> Path:
    import subprocess
    csrc = daqp_sources()
    exe = WORK / target.build_name / "daqp_solve_file"
    sources = sorted(str(p) for p in (csrc / "src").glob("*.c")) + [str(DAQP_DRIVER)]
    newest = max(Path(s).stat().st_mtime for s in sources)
    if exe.exists() and exe.stat().st_mtime >= newest:
        return exe
    exe.parent.mkdir(parents=True, exist_ok=True)
    partial = exe.with_name(f"{exe.name}.{os.getpid()}")
    cmd = [target.compiler.replace("g++", "gcc"), "-O3", "-DNDEBUG", *target.compile_flags, "-static",
           f"-I{csrc / 'include'}", *sources, "-lm", "-o", str(partial)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"building DAQP for {target.name} failed:\n{proc.stderr[-3000:]}")
    return partial.replace(exe)


# ---- one solver on one target ------------------------------------------------------------------
def run_priced(target, exe: Path, qp_file: Path, profile: Path, timeout_s: float) -> tuple[str, list[dict]]:
    """Runs `exe qp_file` under QEMU with the block profiler; returns its output and the priced regions."""
    from rvd_pil.qemu import cycles, plugin, user
    model = cycles.CycleModel(target)
    proc = user.run(target, exe, [str(qp_file)], timeout_s=timeout_s,
                    plugin=plugin.BlockProfiler(out=profile, cache=model.cache_geometry, cache_scope="solves"))
    if proc.returncode != 0:
        raise RuntimeError(f"{exe.name} on {target.name} exited {proc.returncode}: {proc.stderr[-2000:]}")
    rows = cycles.profile_summary(model, exe, cycles.read_profile(profile))
    return proc.stdout, rows


def select(qps, cells: list[str], per_cell: int):
    """The QPs of the asked cells (phase:N), at most per_cell each, in the set's order."""
    want = {(c.split(":")[0], int(c.split(":")[1])) for c in cells}
    taken = defaultdict(int)
    out = []
    for qp in qps:
        key = (qp.phase, qp.N)
        if key in want and taken[key] < per_cell:
            taken[key] += 1
            out.append(qp)
    return out


def measure(qps, targets: list[str], work: Path | None = None, timeout_s: float = 3600) -> dict:
    """Per target, solver and QP: instructions, modelled time (us, nominal / low / high) and whether
    the answer agrees with the reference. Returns {target: {solver: [row per QP]}}. The QP files and
    block profiles go to `work` (default: build/target_solvers/set-<digest of the QPs>)."""
    from rvd_pil.qemu import build, targets as registry
    refs = []  # the reference objective, or None where the reference found the QP infeasible
    condensed = []  # DAQP's form of each QP (the host benchmark's)
    for qp in qps:
        forms = host_bench.prepare(qp)
        ref, who = host_bench.reference(qp, forms)
        if ref.status != "solved" and "infeasible" not in ref.status.lower():
            raise RuntimeError(f"the reference ({who}) could not solve a {qp.phase} N = {qp.N} QP: {ref.status}")
        refs.append(ref.objective if ref.status == "solved" else None)
        condensed.append(forms["condensed"])
    ocp_file = (work or WORK) / "ocp.bin.tmp"
    ocp_file.parent.mkdir(parents=True, exist_ok=True)
    write_ocp_file(ocp_file, qps)
    if work is None:  # one folder per QP set
        work = WORK / f"set-{hashlib.sha256(ocp_file.read_bytes()).hexdigest()[:12]}"
    work.mkdir(parents=True, exist_ok=True)
    ocp_file = ocp_file.replace(work / "ocp.bin")
    dense_file = work / "condensed.bin"
    write_condensed_file(dense_file, condensed)

    result = {}
    for name in targets:
        t = registry.load(name)
        if not t.emulated:
            raise ValueError(f"{name}: the host runs natively; use python -m rvd_pil.bench.solvers")
        exes = {"flight_sw": (build.cross_build(t, FLIGHT_DRIVER).path, ocp_file, "u"),
                "daqp": (build_daqp_driver(t), dense_file, "x")}
        result[name] = {}
        for solver, (exe, qp_file, key) in exes.items():
            t0 = time.time()
            print(f"  {name} {solver}: {len(qps)} QPs under QEMU ...", file=sys.stderr, flush=True)
            out, priced = run_priced(t, exe, qp_file, work / f"{name}-{solver}.blocks", timeout_s)
            answers = parse_answers(out, key)
            by_step = {r["step"]: r for r in priced}
            rows = []
            for k, qp in enumerate(qps):
                status, vec = answers.get(k, ("missing", np.zeros(0)))
                solved = status == ("1" if solver == "daqp" else "solved")  # DAQP's exit flag 1: optimal
                if refs[k] is None:  # infeasible: the answer must say so (DAQP's exit flag -1)
                    ok = status == ("-1" if solver == "daqp" else "infeasible")
                else:
                    c = condensed[k]
                    U = vec if solver == "daqp" else in_condensed_layout(c, qp, vec)
                    ok = solved and U is not None and len(U) == c.H.shape[0] and \
                        host_bench.agrees(qp.objective(*c.unstack(U, qp)), refs[k])
                r = by_step.get(k)
                rows.append({"phase": qp.phase, "N": qp.N, "status": status, "agrees": bool(ok),
                             "feasible": refs[k] is not None,
                             "instructions": r["instructions"] if r else math.nan,
                             "us_nominal": r["target_us_nominal"] if r else math.nan,
                             "us_low": r["target_us_low"] if r else math.nan,
                             "us_high": r["target_us_high"] if r else math.nan})
            result[name][solver] = rows
            print(f"  {name} {solver}: done in {time.time() - t0:.0f} s", file=sys.stderr, flush=True)
    return result


def table(result: dict) -> list[dict]:
    """Per target and cell: medians and p90s of both solvers over the cell's feasible QPs (as the host
    benchmark, which leaves the infeasible ones out of its times), their ratios (DAQP / flight_sw:
    above 1, flight_sw is faster) and the bad answers over all its QPs (an infeasible QP not called
    infeasible is bad)."""
    out = []
    for name, by_solver in result.items():
        order = list(host_bench.PHASE_HORIZONS)
        cells = sorted({(r["phase"], r["N"]) for r in by_solver["flight_sw"]},
                       key=lambda k: (order.index(k[0]) if k[0] in order else 99, k))
        for phase, N in cells:
            row = {"target": name, "phase": phase, "N": N}
            for solver, rows in by_solver.items():
                sel = [r for r in rows if (r["phase"], r["N"]) == (phase, N)]
                timed = [r for r in sel if r["feasible"]]
                us = np.array([r["us_nominal"] for r in timed])
                ins = np.array([r["instructions"] for r in timed])
                row[f"{solver}_count"] = len(sel)
                row[f"{solver}_infeasible"] = len(sel) - len(timed)
                row[f"{solver}_bad"] = sum(not r["agrees"] for r in sel)
                row[f"{solver}_us_median"] = float(np.median(us)) if len(us) else math.nan
                row[f"{solver}_us_p90"] = float(np.percentile(us, 90)) if len(us) else math.nan
                row[f"{solver}_insns_median"] = float(np.median(ins)) if len(ins) else math.nan
            for what in ("us_median", "us_p90", "insns_median"):
                row[f"ratio_{what}"] = row[f"daqp_{what}"] / row[f"flight_sw_{what}"]
            out.append(row)
    return out


def print_table(rows: list[dict]) -> None:
    print(f"{'target':<7}{'phase':<11}{'N':>4}  {'flight_sw us med / p90':>24}  {'DAQP us med / p90':>20}  "
          f"{'ratio med / p90':>16}  {'k insns med fsw / DAQP':>24}  {'bad fsw / DAQP':>15}")
    for r in rows:
        print(f"{r['target']:<7}{r['phase']:<11}{r['N']:>4}  "
              f"{r['flight_sw_us_median']:>12.1f} / {r['flight_sw_us_p90']:>7.1f}  "
              f"{r['daqp_us_median']:>9.1f} / {r['daqp_us_p90']:>7.1f}  "
              f"{r['ratio_us_median']:>7.2f} / {r['ratio_us_p90']:>5.2f}  "
              f"{r['flight_sw_insns_median'] / 1e3:>12.1f} / {r['daqp_insns_median'] / 1e3:>8.1f}  "
              f"{r['flight_sw_bad']:>5d}/{r['flight_sw_count']} / {r['daqp_bad']}/{r['daqp_count']}")
    print("\nus = modelled target time of one solve (cycle model, nominal) at the target clock; ratio = DAQP / "
          "flight_sw (above 1: flight_sw is faster on that CPU); k insns = thousands of instructions per solve; "
          "bad = answers off the reference by more than 1e-6 relative, not solved, or (on a QP the reference finds "
          "infeasible) not called infeasible; the times leave the infeasible QPs out")


def plot(rows: list[dict], path: Path) -> Path:
    """Per target, each cell's modelled median solve time of both solvers (bars, log scale) with the
    p90 as a tick above each bar, and DAQP / flight_sw's median ratio over each pair."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    targets = list(dict.fromkeys(r["target"] for r in rows))
    fig, axes = plt.subplots(len(targets), 1, figsize=(10, 3.4 * len(targets)), squeeze=False)
    for ax, target in zip(axes[:, 0], targets):
        sel = [r for r in rows if r["target"] == target]
        x = np.arange(len(sel))
        for i, (solver, label) in enumerate((("flight_sw", "flight_sw"), ("daqp", "DAQP"))):
            med = np.array([r[f"{solver}_us_median"] for r in sel])
            p90 = np.array([r[f"{solver}_us_p90"] for r in sel])
            pos = x + (i - 0.5) * 0.38
            ax.bar(pos, med, 0.38, label=f"{label} median")
            ax.scatter(pos, p90, marker="_", s=160, color="black", zorder=3, label="p90" if i == 0 else None)
        for xi, r in zip(x, sel):
            top = max(r["flight_sw_us_p90"], r["daqp_us_p90"])
            ax.annotate(f"{r['ratio_us_median']:.2f}x", (xi, top), textcoords="offset points", xytext=(0, 4),
                        ha="center", fontsize=7)
        ax.set_yscale("log")
        ax.set_ylim(top=ax.get_ylim()[1] * 8)
        ax.set_xticks(x, [f"{r['phase']}\nN = {r['N']}" for r in sel], fontsize=8)
        ax.set_ylabel("modelled solve time [us]")
        ax.set_title(f"{target}: one solve under QEMU, priced by the cycle model (labels: DAQP / flight_sw median)",
                     fontsize=10)
        ax.grid(axis="y", which="both", alpha=0.3)
        ax.legend(fontsize=7, ncol=3, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m rvd_pil.bench.target_solvers", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--qp-set", type=Path, default=None,
                    help="a QP set with phase labels (python -m rvd_pil.bench.solvers --closed-loop-set writes one); "
                         "default: the host benchmark's synthetic MPC set, --per-cell QPs per cell (seed 0)")
    ap.add_argument("--cells", default=",".join(ACTIVE_SET_CELLS),
                    help="phase:N cells, comma-separated, or 'all' (default: the docking and approach cells)")
    ap.add_argument("--per-cell", type=int, default=40, help="QPs per cell at most (default 40)")
    ap.add_argument("--targets", default="rpi3,q7s", help="emulated targets, comma-separated (default rpi3,q7s)")
    ap.add_argument("--out", type=Path, default=None,
                    help="write target-solvers.json (per-solve rows and the table) and target-solvers.png here")
    a = ap.parse_args(argv)
    if a.per_cell < 1:
        ap.error("--per-cell must be >= 1")
    if a.qp_set is not None and not a.qp_set.is_file():
        ap.error(f"no QP set at {a.qp_set}")
    qps = load_qp_set(str(a.qp_set)) if a.qp_set else host_bench.synthetic_set(a.per_cell, 0)
    source = a.qp_set or "the synthetic MPC set"
    if a.cells == "all":
        order = list(host_bench.PHASE_HORIZONS)
        cells = [f"{p}:{n}" for p, n in sorted({(qp.phase, qp.N) for qp in qps if qp.phase},
                                                 key=lambda c: (order.index(c[0]) if c[0] in order else 99, c))]
    else:
        cells = [c.strip() for c in a.cells.split(",") if c.strip()]
        bad = [c for c in cells if c.count(":") != 1 or not c.split(":")[1].isdigit()]
        if bad:
            ap.error(f"cells must read phase:N, got {bad}")
    qps = select(qps, cells, a.per_cell)
    if not qps:
        ap.error(f"no QP of {cells} in {source} (its QPs need phase labels)")
    t0 = time.time()
    print(f"{len(qps)} QPs of {source} ({', '.join(cells)}; at most {a.per_cell} per cell), targets {a.targets}\n")
    result = measure(qps, [t.strip() for t in a.targets.split(",") if t.strip()])
    rows = table(result)
    print_table(rows)
    if a.out is not None:
        a.out.mkdir(parents=True, exist_ok=True)
        (a.out / "target-solvers.json").write_text(json.dumps({"table": rows, "solves": result}, indent=1))
        print(f"\nwrote {a.out / 'target-solvers.json'} and {plot(rows, a.out / 'target-solvers.png')}")
    print(f"\nwall time {time.time() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
