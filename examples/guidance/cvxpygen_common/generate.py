"""The three phase QPs of the flight software's MPC (flight_sw/guidance/phase_qp.cpp) as CVXPY models, and
their C code from CVXPYgen, for the peer laws cvxpygen_qoco and cvxpygen_osqp.

    python generate.py --out build/generated/<law> --solver QOCOGEN|OSQP [--horizons 15,30,45/5,15,30/5,12,30]

Run by rvd_pil/host_sim/guidance_build.py before every build of such a law (the law.toml's [generate] table). One
problem per phase and horizon (the PIL campaign's horizon sets by default), each with CVXPYgen's prefix
(r15_, a5_, d12_, ...). The generated C goes to OUT/<key>/, where the key hashes everything the code
depends on (this file, the solver, its settings, the horizons, the part size, the weights the flight
software's QP builder uses, the versions of cvxpy, cvxpygen and the solver's generator): an unchanged
key returns at once, and the build trees keep their objects. OUT/sources.json lists what the build
compiles. CVXPYgen's own output, the slow part (QOCOGEN: minutes per problem), is cached per problem
in OUT/../cvxpygen_solver_code/ under a key of what it depends on (solver_code), shared by every law
that generates that problem.

What is a parameter (changes per step, the law copies it from the QP our builder made): x0, the CW
dynamics A and B (set once: they follow the orbit, the period and the burn model), the linear state
cost q_i = -2 Q x_ref,i, the input box of every stage (it follows the thrusters' estimated force), and
every state row whose normal turns with the chaser or the target: the rotating keep-out hyperplanes,
the overshoot plane, the closing-speed row and the line-of-sight pyramids with their bounds. What is a
constant (checked by the law against its own QP at create): the weights Q, Q_f, R, the soft rows'
penalty lambda and the docking stop plane's penalty (the plane itself, through the set point, is a
parameter). Differences from our QP: none in the nominal QPs. The closing-speed rows of the
approach and the rendezvous are always there (the law makes them 0 <= 1 when the run has no cap or
braking curve); the recovery QPs, the 1-norm rendezvous
and the obstacle rows are not generated (the law refuses those configurations, and on an infeasible QP
commands zero thrust where our MPC solves its recovery QP).

Several generated problems in one executable: each problem's C files are copied into one folder (so
that their quoted includes find that problem's headers) and compiled through a wrapper that renames
every global symbol the solver code defines without the problem's prefix (found with nm on a native
object build), e.g. qoco_custom_solve -> r15_qoco_custom_solve. A small glue file per problem gives
the law one table (rvd_cpg.h) for all of them. Generated functions longer than --split-lines lines (the
straight-line LDL, solves and data of QOCOGEN) are cut into parts first (split_long_functions): GCC
then builds them in minutes instead of an hour, at the same -O3 as the flight software.
"""
from __future__ import annotations

import argparse
import fcntl
import hashlib
import inspect
import json
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
PHASES = {"rendezvous": 1, "approach": 2, "docking": 3}
# The PIL campaign's horizon sets (rvd_pil/bench/campaign.py HORIZON_SETS), per phase.
DEFAULT_HORIZONS = "15,30,45/5,15,30/5,12,30"
# Longest generated function compiled whole (split_long_functions): parts of 200 lines build the
# rendezvous N = 15 LDL (8400 lines in one function) in 15 s of CPU instead of 203 s (GCC 12, -O3,
# Cortex-A9; 400 lines: 25 s, 100 lines: 13 s).
SPLIT_LINES = 200
# Tolerances, stated explicitly for both solvers (QOCOGEN's settings start zeroed in the generated code:
# the law calls cpg_set_solver_default_settings() first, then these).
SETTINGS = {
    "QOCOGEN": {"abstol": 1e-7, "reltol": 1e-7, "max_iters": 100},
    "OSQP": {"eps_abs": 1e-5, "eps_rel": 1e-5, "max_iter": 4000, "check_termination": 25, "warm_starting": 1},
}
# Parameter order of rvd_cpg.h (RVD_CPG_*); every problem lists all, absent ones with size 0.
PARAM_NAMES = ("x0", "A", "B", "q", "ubox", "keepout_C", "keepout_d", "cone_C", "cone_d", "speed_C", "speed_d",
               "vel_d", "stop_C", "stop_d")


def weights(phase: str, N: int) -> dict:
    """The weights our builder puts in this phase's QP (flight_sw.PhaseQp with the default parameters):
    dissertation units, cost x'Qx + u'Ru (the OCP's 1/2 x'(2Q)x), terminal Q_f, soft penalty lambda, and the
    docking stop plane's penalty (0: none)."""
    from rvd_pil import flight_sw

    p = flight_sw.GuidanceParams()
    getattr(p, phase).N = N
    ph = {"rendezvous": flight_sw.Phase.Rendezvous, "approach": flight_sw.Phase.Approach,
          "docking": flight_sw.Phase.Docking}[phase]
    x = np.array([150.0, -1500.0, 50.0, 0.1, 0.1, 0.0]) if phase == "rendezvous" else \
        np.array([0.2, 40.0, 0.1, 0.0, -0.05, 0.0])
    qp = flight_sw.build_phase_qp(p, ph, x, np.array([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)]), np.zeros(3))
    Q, Qf = np.asarray(qp["Q"][0]) / 2, np.asarray(qp["Q"][N]) / 2
    R = np.asarray(qp["R"][0])[:3, :3] / 2
    layout = flight_sw.PhaseQp(ph, p)
    zs, stop = set(), set()
    for i, (rows, pen) in enumerate(zip(qp.get("idxs") or [], qp.get("zs") or [])):
        for row, v in zip(np.atleast_1d(rows), np.atleast_1d(pen)):
            (stop if row == layout.stop_row(i) else zs).add(float(v))
    if len(zs) > 1 or len(stop) > 1:
        raise SystemExit(f"{phase} N={N}: soft rows with several penalties {sorted(zs | stop)}: not the nominal QP")
    return {"Q": Q, "Qf": Qf, "R": R, "lambda": min(zs, default=0.0), "stop": min(stop, default=0.0)}


def model(phase: str, N: int, w: dict):
    """The phase QP in CVXPY, with the rows of phase_qp.cpp's StageLayout on stages 1..N."""
    import cvxpy as cp

    X = cp.Variable((6, N + 1), name="X")  # stage i is column i (column-major: contiguous per stage)
    U = cp.Variable((3, N), name="U")
    P = {name: None for name in PARAM_NAMES}
    P["x0"] = cp.Parameter(6, name="x0")
    P["A"] = cp.Parameter(36, name="A")  # row-major
    P["B"] = cp.Parameter(18, name="B")
    P["q"] = cp.Parameter(6 * (N + 1), name="q")  # stage-major
    P["ubox"] = cp.Parameter(6 * N, name="ubox")  # per stage: +x +y +z bounds, then those of -x -y -z
    A = cp.reshape(P["A"], (6, 6), order="C")
    B = cp.reshape(P["B"], (6, 3), order="C")
    q = cp.reshape(P["q"], (6, N + 1), order="F")
    ub = cp.reshape(P["ubox"], (6, N), order="F")
    cons = [X[:, 0] == P["x0"], X[:, 1:] == A @ X[:, :-1] + B @ U, U <= ub[:3, :], -U <= ub[3:, :]]
    Qs, Rs = np.sqrt(np.diag(w["Q"])), np.sqrt(np.diag(w["R"]))
    if not (np.allclose(w["Q"], np.diag(np.diag(w["Q"]))) and np.allclose(w["R"], np.diag(np.diag(w["R"])))):
        raise SystemExit(f"{phase}: Q and R must be diagonal")
    cost = (cp.sum_squares(np.diag(Qs) @ X[:, :N]) + cp.quad_form(X[:, N], w["Qf"]) +
            cp.sum_squares(np.diag(Rs) @ U) + cp.sum(cp.multiply(q, X)))
    stages = N  # state rows on stages 1..N

    def rows(name: str, height: int, part: slice, stage_cols, soft: bool, penalty: float | None = None):
        """height rows per stage on the position (or velocity) of the stages in stage_cols:
        (C_row . X[part, i]) (- s) <= d, C and d parameters; a soft row costs penalty (default lambda) per unit."""
        nonlocal cost
        n = len(stage_cols)
        P[f"{name}_C"] = cp.Parameter(3 * height * n, name=f"{name}_C")
        P[f"{name}_d"] = cp.Parameter(height * n, name=f"{name}_d")
        C = cp.reshape(P[f"{name}_C"], (3, height * n), order="F")  # column j: row j's 3 coefficients
        E = np.kron(np.eye(n), np.ones((1, height)))  # stage s -> its `height` rows
        lhs = cp.sum(cp.multiply(C, X[part, stage_cols] @ E), axis=0)
        if soft:
            s = cp.Variable(height * n, name=f"{name}_s", nonneg=True)
            cons.append(lhs - s <= P[f"{name}_d"])
            cost += (w["lambda"] if penalty is None else penalty) * cp.sum(s)
        else:
            cons.append(lhs <= P[f"{name}_d"])

    pos, vel, all_stages = slice(0, 3), slice(3, 6), list(range(1, N + 1))
    if phase == "rendezvous":
        rows("keepout", 1, pos, all_stages, soft=False)
        rows("speed", 1, vel, all_stages, soft=False)  # the braking curve towards the keep-out planes
        if w["lambda"] > 0:
            rows("cone", 4, pos, [N], soft=True)
    elif phase == "approach":
        rows("keepout", 1, pos, all_stages, soft=False)  # the overshoot plane
        rows("speed", 1, vel, all_stages, soft=False)
        if w["lambda"] > 0:
            rows("cone", 4, pos, all_stages, soft=True)
    else:
        rows("cone", 4, pos, all_stages, soft=False)
        P["vel_d"] = cp.Parameter(6 * stages, name="vel_d")
        vd = cp.reshape(P["vel_d"], (6, stages), order="F")
        cons += [X[3:, 1:] <= vd[:3, :], -X[3:, 1:] <= vd[3:, :]]
        if w["stop"] > 0:
            rows("stop", 1, pos, all_stages, soft=True, penalty=w["stop"])
    prob = cp.Problem(cp.Minimize(cost), cons)
    if not prob.is_dcp(dpp=True):
        raise SystemExit(f"{phase} N={N}: the model is not DPP")
    # Values for the generator (any in the parameters' domain; the law sets its own before every solve).
    rng = np.random.default_rng(0)
    for name, par in P.items():
        if par is not None:
            par.value = rng.uniform(0.5, 1.0, par.shape)
    return prob, X, U, P


def _versions(solver: str) -> list[str]:
    from importlib.metadata import PackageNotFoundError, version

    out = []
    for pkg in ("cvxpy", "cvxpygen", "qocogen" if solver == "QOCOGEN" else "osqp"):
        try:
            out.append(f"{pkg}=={version(pkg)}")
        except PackageNotFoundError:
            raise SystemExit(f"{pkg} is not installed: pip install '.[peers]' (pyproject.toml)") from None
    return out


def _flatten(code: Path, dest: Path) -> None:
    """Copies one problem's C files, as CVXPYgen wrote them, into `dest` (one folder, so that each quoted
    include finds this problem's header)."""
    dest.mkdir(parents=True, exist_ok=True)
    c = code / "c"
    files = list((c / "src").glob("cpg_*.c")) + list((c / "include").glob("*.h"))
    files += [p for p in (c / "solver_code").rglob("*") if p.suffix in (".c", ".h")]
    skip = {"cpg_example.c", "runtest.c", "emosqp.c"}
    seen: dict[str, Path] = {}
    for f in files:
        if f.name in skip or "lib/amd" in str(f):
            continue
        if f.name in seen and seen[f.name].read_bytes() != f.read_bytes():
            raise SystemExit(f"two different files named {f.name} in {code}")
        seen[f.name] = f
        shutil.copy2(f, dest / f.name)


_FUNCTION = re.compile(r"^void ([A-Za-z_]\w*)\(([^()]*)\) \{$")
_LOCAL = re.compile(r"^\s*(const\s+)?(unsigned\s+)?(int|double|float|char|long|short|\w+_(int|float)|[A-Z]\w*)"
                    r"[\s*]+[A-Za-z_]\w*\s*(=|;|\[)|^\s*(return|goto)\b|^\s*\w+:(?!:)")


def split_long_functions(text: str, max_lines: int) -> str:
    """The C text with every long `void f(...) { ... }` (more than max_lines lines, opening at column 0 and
    closing with a lone `}`) cut at top-level statements into noinline static parts called in turn.

    QOCOGEN writes its sparse LDL factorisation and solves, and the problem data, as straight-line
    functions of tens of thousands of lines; GCC's alias walking and first scheduling pass are quadratic in
    a function's (and a block's) length, so that one such function costs minutes at -O2/-O3 (rendezvous,
    N = 15: 200 s; N = 45: far more). Parts of max_lines lines compile in time linear in the file. A part
    boundary costs a call and the reload of what the previous part held in registers. Only functions whose
    state lives in their parameters are cut (no locals, return, goto or labels at the top level, no string
    literals); others are left whole."""
    lines = text.split("\n")
    out, i = [], 0
    while i < len(lines):
        m = _FUNCTION.match(lines[i])
        end = lines.index("}", i) if m and "}" in lines[i:] else -1
        if not m or end - i - 1 <= max_lines:
            out.append(lines[i])
            i += 1
            continue
        name, params, body = m.group(1), m.group(2), lines[i + 1:end]
        parts, part, depth, whole = [], [], 0, any('"' in ln for ln in body)
        for ln in body:
            if depth == 0 and _LOCAL.match(ln):
                whole = True
            if depth == 0 and len(part) >= max_lines and not ln.lstrip().startswith("else") \
                    and part[-1].rstrip().endswith((";", "}")):
                parts.append(part)
                part = []
            part.append(ln)
            depth += ln.count("{") - ln.count("}")
        parts.append(part)
        if whole or depth != 0 or len(parts) == 1:
            out += lines[i:end + 1]
        else:
            args = ", ".join(p.split()[-1].lstrip("*") for p in params.split(",")) if params.strip() not in ("", "void") else ""
            for k, part in enumerate(parts):
                out += [f"__attribute__((noinline)) static void {name}_part{k}({params}) {{", *part, "}", ""]
            out += [lines[i], *(f"   {name}_part{k}({args});" for k in range(len(parts))), "}"]
        i = end + 1
    return "\n".join(out)


def _global_symbols(sources: list[Path], folder: Path) -> set[str]:
    """Global symbols the sources define (compiled natively, read with nm)."""
    syms: set[str] = set()
    with tempfile.TemporaryDirectory() as tmp:
        for src in sources:
            obj = Path(tmp) / (src.name + ".o")
            subprocess.run(["cc", "-c", "-O0", "-w", f"-I{folder}", str(src), "-o", str(obj)], check=True,
                           capture_output=True, text=True)
            out = subprocess.run(["nm", "-g", "--defined-only", str(obj)], check=True, capture_output=True,
                                 text=True).stdout
            syms |= {ln.split()[-1] for ln in out.splitlines() if len(ln.split()) == 3}
    return syms


def _glue(prefix: str, phase: str, N: int, solver: str, P: dict, folder: Path, w: dict) -> Path:
    """One problem's entry in the law's table (rvd_cpg.h)."""
    pfx = prefix + "_"
    setters, sizes = [], []
    for k, name in enumerate(PARAM_NAMES):
        par = P[name]
        n = 0 if par is None else int(np.prod(par.shape))
        sizes.append(str(n))
        if n:
            setters.append(f"    case {k}: for (i = 0; i < {n}; ++i) {pfx}cpg_update_{name}(i, v[i]); break;")
    if solver == "QOCOGEN":
        status = (f"  switch ({pfx}CPG_Info.status) {{\n"
                  f"    case QOCO_CUSTOM_SOLVED: return RVD_CPG_SOLVED;\n"
                  f"    case QOCO_CUSTOM_MAX_ITER: return RVD_CPG_MAX_ITER;\n"
                  f"    case QOCO_CUSTOM_NUMERICAL_ERROR: return RVD_CPG_NUMERICAL_ERROR;\n"
                  f"    default: return RVD_CPG_OTHER;\n  }}")
        settings = "\n".join(f"  {pfx}cpg_set_solver_{k}({v!r});" for k, v in SETTINGS[solver].items())
    else:
        status = (f"  switch (solver.info->status_val) {{  /* CVXPYgen's info holds OSQP's status as text */\n"
                  f"    case OSQP_SOLVED: return RVD_CPG_SOLVED;\n"
                  f"    case OSQP_MAX_ITER_REACHED: return RVD_CPG_MAX_ITER;\n"
                  f"    case OSQP_PRIMAL_INFEASIBLE: case OSQP_PRIMAL_INFEASIBLE_INACCURATE: return RVD_CPG_INFEASIBLE;\n"
                  f"    case OSQP_NON_CVX: return RVD_CPG_NUMERICAL_ERROR;\n"
                  f"    default: return RVD_CPG_OTHER;\n  }}")
        settings = "\n".join(f"  {pfx}cpg_set_solver_{k}({v!r});" for k, v in SETTINGS[solver].items())
    soft = "cone_s" if (phase != "docking" and w["lambda"] > 0) else None
    text = f"""/* Generated by examples/guidance/cvxpygen_common/generate.py: the {phase} QP, N = {N}, {solver}. */
#include "rvd_rename.h"
#include "cpg_workspace.h"
#include "cpg_solve.h"
#include "rvd_cpg.h"

static void rvd_glue_set_param(int which, const double* v) {{
  cpg_int i;
  switch (which) {{
{chr(10).join(setters)}
    default: break;
  }}
}}

static void rvd_glue_settings(void) {{
  {pfx}cpg_set_solver_default_settings();
{settings}
}}

static int rvd_glue_status(void) {{
{status}
}}

static const double* rvd_glue_x(void) {{ return {pfx}CPG_Prim.X; }}
static const double* rvd_glue_u(void) {{ return {pfx}CPG_Prim.U; }}
static const double* rvd_glue_slack(void) {{ return {pfx + "CPG_Prim." + soft if soft else "0"}; }}
static double rvd_glue_objective(void) {{ return {pfx}CPG_Info.obj_val; }}
static int rvd_glue_iterations(void) {{ return (int){pfx}CPG_Info.iter; }}
static double rvd_glue_primal_residual(void) {{ return {pfx}CPG_Info.pri_res; }}
static double rvd_glue_dual_residual(void) {{ return {pfx}CPG_Info.dua_res; }}

static const double rvd_glue_Q[36] = {{{", ".join(repr(float(v)) for v in w["Q"].ravel())}}};
static const double rvd_glue_Qf[36] = {{{", ".join(repr(float(v)) for v in w["Qf"].ravel())}}};
static const double rvd_glue_R[9] = {{{", ".join(repr(float(v)) for v in w["R"].ravel())}}};

const rvd_cpg_problem {pfx}rvd_problem = {{
  {PHASES[phase]}, {N}, "{solver}", {{{", ".join(sizes)}}}, {w["lambda"]!r}, {w["stop"]!r}, rvd_glue_Q, rvd_glue_Qf, rvd_glue_R,
  rvd_glue_settings, rvd_glue_set_param, {pfx}cpg_solve, rvd_glue_status, rvd_glue_x, rvd_glue_u, rvd_glue_slack,
  rvd_glue_objective, rvd_glue_iterations, rvd_glue_primal_residual, rvd_glue_dual_residual
}};
"""
    path = folder / "rvd_glue.c"
    path.write_text(text)
    return path


def solver_code(phase: str, N: int, solver: str, w: dict, versions: list[str], cache: Path) -> Path:
    """The C code CVXPYgen writes for one problem, flattened, in cache/<prefix>-<solver>-<key>/, where the key hashes
    what that code depends on (the model, the weights, the solver, the generators' versions): QOCOGEN
    takes minutes per problem (rendezvous N = 45: 9 min), so an edit of the rest of this file (the glue,
    the settings, the part size) does not pay it again."""
    from cvxpygen import cpg

    prefix = f"{phase[0]}{N}"
    key = hashlib.sha256(json.dumps({
        "model": inspect.getsource(model), "params": PARAM_NAMES, "phase": phase, "N": N, "solver": solver,
        "versions": versions, "weights": {k: np.asarray(v).tolist() for k, v in w.items()}}, sort_keys=True).encode())
    folder = cache / f"{prefix}-{solver}-{key.hexdigest()[:16]}"
    cache.mkdir(parents=True, exist_ok=True)
    with open(cache / ".lock", "w") as lock:  # laws generating at once (a test's and the campaign's) share it
        fcntl.flock(lock, fcntl.LOCK_EX)
        if (folder / "complete").exists():
            return folder
        for old in cache.glob(f"{prefix}-{solver}-*"):  # one version kept per problem
            shutil.rmtree(old)
        raw = cache / f"tmp-{prefix}-{solver}"
        if raw.exists():
            shutil.rmtree(raw)
        prob, X, U, P = model(phase, N, w)
        cpg.generate_code(prob, code_dir=str(raw), solver=solver, prefix=prefix, wrapper=False)
        _flatten(raw, folder)
        shutil.rmtree(raw)
        (folder / "complete").write_text("")
    return folder


def generate_problem(phase: str, N: int, solver: str, dest: Path, cache: Path, versions: list[str],
                     split_lines: int) -> tuple[str, list[Path]]:
    w = weights(phase, N)
    prob, X, U, P = model(phase, N, w)
    prefix = f"{phase[0]}{N}"
    code = solver_code(phase, N, solver, w, versions, cache)
    folder = dest / prefix
    folder.mkdir(parents=True, exist_ok=True)
    sources = []
    for f in sorted(code.glob("*.[ch]")):
        text = f.read_text()
        if f.suffix == ".c" and split_lines:
            text = split_long_functions(text, split_lines)
        (folder / f.name).write_text(text)
        if f.suffix == ".c":
            sources.append(folder / f.name)
    shutil.copy2(HERE / "rvd_cpg.h", folder / "rvd_cpg.h")
    (folder / "rvd_rename.h").write_text("")
    syms = _global_symbols(sources, folder)
    rename = sorted(s for s in syms if not s.startswith(prefix + "_"))
    (folder / "rvd_rename.h").write_text(
        f"/* Global symbols of the {solver} code of {prefix}, renamed so several problems link into one executable. */\n"
        "#ifndef RVD_RENAME_H\n#define RVD_RENAME_H\n" +
        "".join(f"#define {s} {prefix}_{s}\n" for s in rename) + "#endif\n")
    wrappers = []
    for src in sources:
        wrap = folder / f"rvd_{src.name}"
        wrap.write_text(f'#include "rvd_rename.h"\n#include "{src.name}"\n')
        wrappers.append(wrap)
    wrappers.append(_glue(prefix, phase, N, solver, P, folder, w))
    return prefix, wrappers


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--solver", choices=sorted(SETTINGS), required=True)
    ap.add_argument("--horizons", default=DEFAULT_HORIZONS,
                    help="rendezvous/approach/docking horizons, comma-separated per phase (default %(default)s)")
    ap.add_argument("--split-lines", type=int, default=SPLIT_LINES,
                    help="cut generated functions longer than this into parts (0: never; default %(default)s)")
    a = ap.parse_args(argv)
    horizons = dict(zip(PHASES, ([int(n) for n in part.split(",") if n] for part in a.horizons.split("/"))))
    if len(horizons) != 3 or not all(horizons.values()):
        raise SystemExit(f"--horizons: three phases, got {a.horizons!r}")
    versions = _versions(a.solver)
    key_src = json.dumps({
        "generator": hashlib.sha256(Path(__file__).read_bytes() + (HERE / "rvd_cpg.h").read_bytes()).hexdigest(),
        "solver": a.solver, "settings": SETTINGS[a.solver], "horizons": horizons, "versions": versions,
        "split_lines": a.split_lines,
        "weights": {f"{ph}{N}": {k: np.asarray(v).tolist() for k, v in weights(ph, N).items()}
                    for ph, Ns in horizons.items() for N in Ns},
    }, sort_keys=True)
    key = hashlib.sha256(key_src.encode()).hexdigest()[:16]
    out = a.out.resolve()
    dest = out / key
    index = dest / "sources.json"
    if not index.exists():
        for old in out.iterdir() if out.exists() else ():  # one generation kept per law
            if old.is_dir() and re.fullmatch(r"[0-9a-f]{16}", old.name) and old != dest:
                shutil.rmtree(old)
        dest.mkdir(parents=True, exist_ok=True)
        sources, prefixes = [], []
        for ph, Ns in horizons.items():
            for N in Ns:
                done = dest / f"{ph[0]}{N}" / "done.json"  # an interrupted generation resumes per problem
                if done.exists():
                    prefix, srcs = json.loads(done.read_text())
                    srcs = [Path(x) for x in srcs]
                else:
                    prefix, srcs = generate_problem(ph, N, a.solver, dest, out.parent / "cvxpygen_solver_code", versions,
                                                    a.split_lines)
                    done.write_text(json.dumps([prefix, [str(x) for x in srcs]]))
                prefixes.append(prefix)
                sources += srcs
                print(f"generated {ph} N={N} ({a.solver}) as {prefix}_", flush=True)
        registry = dest / "rvd_cpg_registry.c"
        registry.write_text(
            '/* Generated by generate.py: every generated problem of this law. */\n#include "rvd_cpg.h"\n' +
            "".join(f"extern const rvd_cpg_problem {p}_rvd_problem;\n" for p in prefixes) +
            "const rvd_cpg_problem* const rvd_cpg_problems[] = {" +
            ", ".join(f"&{p}_rvd_problem" for p in prefixes) + "};\n" +
            f"const int rvd_cpg_n_problems = {len(prefixes)};\n")
        shutil.copy2(HERE / "rvd_cpg.h", dest / "rvd_cpg.h")
        sources.append(registry)
        (dest / "key.json").write_text(key_src)
        index.write_text(json.dumps({"sources": [str(s) for s in sources], "include_dirs": [str(dest)],
                                     "defines": []}, indent=1))
    shutil.copy2(index, out / "sources.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
