"""External anchor for the cycle model: OSQP's generated C code for OSQP's own quadcopter MPC
example (12 states, 4 inputs), cross-built for aarch64, estimated for a Cortex-A53 at 1.2 GHz, beside
the figures published for a Raspberry Pi 3B (3.55 ms at N = 10, 14.2 ms at N = 30, the whole
process timed with `time ./example`).

    python -m rvd_pil.bench.osqp_anchor                  # generate, cross-build, emulate, price; a table
    python -m rvd_pil.bench.osqp_anchor --out DIR        # also DIR/osqp-anchor.json (the PIL report shows it)

The generated code is written under build/osqp_anchor/ by the PyPI `osqp` package's codegen (never
committed). Its example program solves the problem once from the workspace that codegen embedded
(the setup, including the KKT factorization, happened on the host). The estimate covers the whole
process in user mode (libc start-up, the solve, printf, exit); the kernel's part of `time` (execve,
page faults, exit) is not modelled, so the model should come out somewhat below the measurement.
The generated Makefile compiles without optimization flags; both that (-O0) and -O2 are built,
since the publication does not say which was timed.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from rvd_pil import paths

WORK = paths.build_root() / "osqp_anchor"
PUBLISHED_MS = {10: 3.55, 30: 14.2}  # Raspberry Pi 3B, `time ./example`, as the project records them
TARGET = "rpi3"


def quadcopter_qp(N: int):
    """OSQP's MPC example (documentation, 'Model predictive control (MPC)'): the linearized
    quadcopter, tracking altitude 1 from rest, cast as one QP in x = (x_0..x_N, u_0..u_N-1)."""
    Ad = np.zeros((12, 12))
    np.fill_diagonal(Ad, 1.0)
    for i in range(3):
        Ad[i, 6 + i] = 0.1
    Ad[3, 0], Ad[3, 6], Ad[3, 9] = 0.0488, 0.0016, 0.0992
    Ad[4, 1], Ad[4, 7], Ad[4, 10] = -0.0488, -0.0016, 0.0992
    Ad[5, 11] = 0.0992
    Ad[9, 0], Ad[9, 6], Ad[9, 9] = 0.9734, 0.0488, 0.9846
    Ad[10, 1], Ad[10, 7], Ad[10, 10] = -0.9734, -0.0488, 0.9846
    Ad[11, 11] = 0.9846
    Bd = np.array([[0., -0.0726, 0., 0.0726], [-0.0726, 0., 0.0726, 0.], [-0.0152, 0.0152, -0.0152, 0.0152],
                   [0., -0.0006, 0., 0.0006], [0.0006, 0., -0.0006, 0.], [0.0106, 0.0106, 0.0106, 0.0106],
                   [0., -1.4512, 0., 1.4512], [-1.4512, 0., 1.4512, 0.], [-0.3049, 0.3049, -0.3049, 0.3049],
                   [0., -0.0236, 0., 0.0236], [0.0236, 0., -0.0236, 0.], [0.2107, 0.2107, 0.2107, 0.2107]])
    nx, nu = Bd.shape
    u0 = 10.5916
    umin, umax = np.full(nu, 9.6) - u0, np.full(nu, 13.0) - u0
    xmin = np.full(nx, -np.inf)
    xmax = np.full(nx, np.inf)
    xmin[:2], xmax[:2] = -np.pi / 6, np.pi / 6
    xmin[5] = -1.0
    Q = sp.diags([0., 0., 10., 10., 10., 10., 0., 0., 0., 5., 5., 5.])
    R = 0.1 * sp.eye(nu)
    x0 = np.zeros(nx)
    xr = np.zeros(nx)
    xr[2] = 1.0
    n_x, n_u = (N + 1) * nx, N * nu
    P = sp.block_diag([sp.kron(sp.eye(N + 1), Q), sp.kron(sp.eye(N), R)], format="csc")
    q = np.concatenate([np.tile(-Q @ xr, N + 1), np.zeros(n_u)])
    dynamics = sp.hstack([sp.kron(sp.eye(N + 1), -sp.eye(nx)) + sp.kron(sp.eye(N + 1, k=-1), sp.csc_matrix(Ad)),
                          sp.kron(sp.vstack([sp.csc_matrix((1, N)), sp.eye(N)]), sp.csc_matrix(Bd))])
    bounds = sp.eye(n_x + n_u)
    A = sp.vstack([dynamics, bounds], format="csc")
    eq = np.concatenate([-x0, np.zeros(N * nx)])
    lo = np.concatenate([eq, np.tile(xmin, N + 1), np.tile(umin, N)])
    hi = np.concatenate([eq, np.tile(xmax, N + 1), np.tile(umax, N)])
    return P, q, A, lo, hi


def generate(N: int) -> Path:
    """OSQP's codegen of the example at horizon N into build/osqp_anchor/N<N>/code."""
    import osqp

    out = WORK / f"N{N}" / "code"
    if (out / "workspace.c").exists():
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    P, q, A, lo, hi = quadcopter_qp(N)
    prob = osqp.OSQP()
    prob.setup(P, q, A, lo, hi, verbose=False)
    prob.codegen(str(out), parameters="vectors", force_rewrite=True)
    return out


def cross_build(code: Path, opt: str) -> Path:
    from rvd_pil.qemu import targets

    t = targets.load(TARGET)
    exe = code.parent / f"example{opt}"
    sources = sorted(str(p) for p in (code / "src").glob("*.c")) + [str(code / "workspace.c"), str(code / "emosqp.c")]
    cmd = [t.compiler.replace("g++", "gcc"), opt, *t.compile_flags, "-static", f"-I{code / 'inc' / 'public'}",
           f"-I{code / 'inc' / 'private'}", f"-I{code}", *sources, "-lm", "-o", str(exe)]
    if not exe.exists() or exe.stat().st_mtime < (code / "workspace.c").stat().st_mtime:
        subprocess.run(cmd, check=True, capture_output=True, text=True)
    return exe


def measure(N: int, opt: str) -> dict:
    from rvd_pil.qemu import cycles, plugin, targets, user

    t = targets.load(TARGET)
    exe = cross_build(generate(N), opt)
    model = cycles.CycleModel(t)
    prof_path = exe.with_suffix(".blocks")
    # no solve markers in OSQP's example: the whole process is priced, so the cache model sees all of it
    proc = user.run(t, exe, [], plugin=plugin.BlockProfiler(out=prof_path, cache=model.cache_geometry,
                                                            cache_scope="process"), timeout_s=300)
    if proc.returncode != 0 or "no error" not in proc.stdout:
        raise RuntimeError(f"{exe.name} (N = {N}) failed: {proc.stdout} {proc.stderr}")
    prof = cycles.read_profile(prof_path)
    c = model.region_cycles(prof.process, model.block_costs(exe, prof.blocks))
    ms = [x / t.clock_hz * 1e3 for x in (c.low, c.nominal, c.high)]
    n_var = (N + 1) * 12 + N * 4
    return {"N": N, "variables": n_var, "build": f"aarch64-linux-gnu-gcc {opt} -mcpu=cortex-a53 -static",
            "instructions": prof.process.insns, "CPI (model)": c.nominal / prof.process.insns,
            "model ms low": ms[0], "model ms nominal": ms[1], "model ms high": ms[2],
            "published ms (RPi 3B)": PUBLISHED_MS[N], "nominal / published": ms[1] / PUBLISHED_MS[N],
            "published within [low, high]": ms[0] <= PUBLISHED_MS[N] <= ms[2]}


def _stamp(opts: tuple[str, ...]) -> list:
    """What the result depends on: the executables and the cycle model (a re-run is skipped when unchanged)."""
    import hashlib

    from rvd_pil.qemu import cycles, targets

    exes = [cross_build(generate(N), opt) for N in PUBLISHED_MS for opt in opts]
    return [[e.name, hashlib.sha256(e.read_bytes()).hexdigest()[:16]] for e in exes] + \
        [cycles.CycleModel(targets.load(TARGET)).fingerprint()]


def run(out: Path | None = None, opts: tuple[str, ...] = ("-O2", "-O0")) -> dict:
    stamp = _stamp(opts)
    cached = Path(out) / "osqp-anchor.json" if out is not None else None
    if cached is not None and cached.exists():
        old = json.loads(cached.read_text())
        if old.get("stamp") == stamp:
            return old
    rows = [measure(N, opt) for N in PUBLISHED_MS for opt in opts]
    o2 = [r for r in rows if "-O2" in r["build"]]
    summary = ("OSQP codegen (PyPI osqp) of OSQP's quadcopter MPC example, cross-built for aarch64 and run once "
               "under qemu-aarch64 -cpu cortex-a53 with the block profiler; the whole process in user mode priced "
               "by the Cortex-A53 cycle model at 1.2 GHz (the kernel's part of `time` is not modelled). -O2: nominal / "
               "published = " + ", ".join(f"{r['nominal / published']:.2f} at N = {r['N']}" for r in o2) +
               " (goal: within 0.7-1.3).")
    result = {"summary": summary, "rows": rows, "stamp": stamp}
    if out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        (Path(out) / "osqp-anchor.json").write_text(json.dumps(result, indent=1))
    return result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m rvd_pil.bench.osqp_anchor", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--opt", action="append", help="compiler optimization flag(s) (default -O2 and -O0)")
    a = ap.parse_args(argv)
    res = run(a.out, tuple(a.opt) if a.opt else ("-O2", "-O0"))
    print(res["summary"])
    for r in res["rows"]:
        print(f"N={r['N']:3d} {r['build']:45s} insns {r['instructions']:>10d} CPI {r['CPI (model)']:.2f}  model "
              f"{r['model ms low']:.2f} / {r['model ms nominal']:.2f} / {r['model ms high']:.2f} ms  published "
              f"{r['published ms (RPi 3B)']} ms  ratio {r['nominal / published']:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
