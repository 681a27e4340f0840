"""Microbenchmarks with known answers for the cycle model: kernels.cpp cross-built per CPU, run
under QEMU user mode with the instruction counter and the block profiler, priced by the CPU's
cycle model (rvd_pil/qemu/cycles.py), compared with the published figures of expected.toml.

    python -m rvd_pil.bench.microbench.run                 # every CPU of expected.toml, a table
    python -m rvd_pil.bench.microbench.run --cpu cortex-a9

Each kernel runs ITERATIONS loop iterations in one solve marker; its modelled cycles per
iteration are the region's core cycles (steady state; cold pipeline beside it) over ITERATIONS.
"""
from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

from rvd_pil import paths
from rvd_pil.qemu import cycles, plugin, targets, user

HERE = Path(__file__).resolve().parent
SOURCE = HERE / "kernels.cpp"
EXPECTED = HERE / "expected.toml"
OUT = paths.build_root() / "microbench"
KERNELS = ("fma_chain", "fma_stream", "load_chain", "div_chain", "call_loop")
ITERATIONS = 2000

# CPU of the cycle model -> (registered target, CPU the code is built for and QEMU emulates).
# The Cortex-A55 has no QEMU 7.2 model: code built for the A53 runs on it, so the A53 build and
# emulation are priced with the A55 model.
CPUS = {"cortex-a53": ("rpi3", "cortex-a53"), "cortex-a55": ("rpi3", "cortex-a53"),
        "cortex-a72": ("rpi4", "cortex-a72"), "cortex-a9": ("q7s", "cortex-a9"),
        "cortex-a8": ("beaglebone", "cortex-a8")}


def expected() -> dict:
    with EXPECTED.open("rb") as f:
        return tomllib.load(f)


def build(target: targets.Target) -> Path:
    """kernels.cpp for the target's CPU (static), rebuilt when the source is newer."""
    exe = OUT / target.cpu / "kernels"
    if exe.exists() and exe.stat().st_mtime >= SOURCE.stat().st_mtime:
        return exe
    exe.parent.mkdir(parents=True, exist_ok=True)
    cmd = [target.compiler, "-std=c++17", "-O2", "-static", *target.compile_flags, f"-I{paths.source_root()}",
           str(SOURCE), "-o", str(exe)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"microbenchmark build failed: {' '.join(cmd)}\n{proc.stderr}")
    return exe


@dataclass
class Result:
    cpu: str
    kernel: str
    iterations: int
    insns: int
    steady_per_iteration: float
    cold_per_iteration: float
    memory_high_per_iteration: float
    published: tuple[float, float] | None   # (low, high); equal for a single figure
    how: str
    source: str

    @property
    def within(self) -> bool | None:
        """Steady-state model inside the published figure (range) within the tolerance."""
        if self.published is None:
            return None
        tol = expected()["tolerance"]
        lo, hi = self.published
        return lo * (1 - tol) <= self.steady_per_iteration <= hi * (1 + tol)


def measure(cpu: str, iterations: int = ITERATIONS, workdir: Path | None = None) -> list[Result]:
    """Runs every kernel once for the cycle model `cpu` and prices it."""
    tname, build_cpu = CPUS[cpu]
    target = targets.load(tname, cpu=build_cpu)
    exe = build(target)
    workdir = workdir or OUT / cpu
    workdir.mkdir(parents=True, exist_ok=True)
    model = cycles.CycleModel(target, cpu)
    prof_path = workdir / "kernels.blocks"
    counter = plugin.InsnCounter(log=workdir / "kernels.insns")
    profiler = plugin.BlockProfiler(out=prof_path, cache=model.cache_geometry)
    args = [a for k in KERNELS for a in (k, str(iterations))]
    proc = user.run(target, exe, args, plugin=[counter, profiler], timeout_s=120)
    if proc.returncode != 0:
        raise RuntimeError(f"{exe} failed under {target.qemu_user} -cpu {target.qemu_cpu}: {proc.stderr}")
    counted = {int(m.group(1)): int(m.group(2)) for m in re.finditer(r"step=(\d+) iterations=\d+ insns=(\d+)", proc.stdout)}
    prof = cycles.read_profile(prof_path)
    costs = model.block_costs(exe, prof.blocks)
    table = expected().get(cpu, {})
    out = []
    for region in prof.regions:
        kernel = KERNELS[region.step]
        if counted.get(region.step) != region.insns:
            raise RuntimeError(f"{cpu} {kernel}: block-count total {region.insns} != instruction count "
                               f"{counted.get(region.step)}")
        c = model.region_cycles(region, costs)
        pub = table.get(kernel)
        published = None
        if pub is not None:
            v = pub["cycles"]
            published = (float(v[0]), float(v[1])) if isinstance(v, list) else (float(v), float(v))
        out.append(Result(cpu, kernel, iterations, region.insns, c.core_steady / iterations, c.core_cold / iterations,
                          c.mem_high / iterations, published, pub["how"] if pub else "",
                          " ".join(pub["source"].split()) if pub else "no usable published figure"))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m rvd_pil.bench.microbench.run", description=__doc__.split("\n\n")[0])
    ap.add_argument("--cpu", action="append", help="cycle-model CPU (repeatable; default all)")
    ap.add_argument("--iterations", type=int, default=ITERATIONS)
    a = ap.parse_args(argv)
    print(f"{'cpu':11s} {'kernel':11s} {'steady':>8s} {'cold':>8s} {'published':>11s}  ok    how       (cycles per loop iteration)")
    bad = 0
    for cpu in a.cpu or list(CPUS):
        for r in measure(cpu, a.iterations):
            pub = "-" if r.published is None else (f"{r.published[0]:g}" if r.published[0] == r.published[1]
                                                   else f"{r.published[0]:g}-{r.published[1]:g}")
            ok = {True: "yes", False: "NO", None: "n/a"}[r.within]
            bad += r.within is False
            print(f"{r.cpu:11s} {r.kernel:11s} {r.steady_per_iteration:8.2f} {r.cold_per_iteration:8.2f} {pub:>11s}  "
                  f"{ok:5s} {r.how or '-':9s} {r.source[:90]}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
