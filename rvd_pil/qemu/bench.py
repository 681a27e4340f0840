"""Emulation figures, measured side by side in one run (prints; asserts nothing):

    python -m rvd_pil.qemu.bench [TARGET ...]        default: q7s rpi3

Per target, on the probe's dense Cholesky (Eigen LLT, n = 60 and 200):
  - instructions per factorization (plugin) and the CPI-model estimate of target time;
  - emulation slowdown: in-guest wall time under qemu-user / native wall time, same source;
  - plugin overhead: in-guest wall time with the plugin (inline, per-vCPU) / without;
  - system mode: host seconds to boot to the program, and to power-off.
Wall times are the minimum over interleaved repeats (the machine is shared); they are host-dependent, the
instruction counts are not.
"""
from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from . import build, plugin, system, targets, user
from .plugin import InsnCounter

SIZES = (60, 200)
REPEATS = 5  # factorizations per size and process
ROUNDS = 5   # processes per configuration, interleaved


def _llt(stdout: str) -> dict[int, tuple[int, int]]:
    """n -> (min ns, insns) over the llt lines."""
    out: dict[int, tuple[int, int]] = {}
    for m in re.finditer(r"llt step=\d+ n=(\d+) insns=(\d+) ns=(\d+)", stdout):
        n, insns, ns = int(m.group(1)), int(m.group(2)), int(m.group(3))
        best = out.get(n, (ns, insns))
        out[n] = (min(best[0], ns), insns)
    return out


def _probe_args() -> list[str]:
    return [x for n in SIZES for _ in range(REPEATS) for x in ("llt", str(n))]


def bench_target(name: str, native_exe: Path) -> None:
    t = targets.load(name)
    if not shutil.which(t.compiler):
        print(f"{name}: {t.compiler} missing, skipped")
        return
    exe = build.cross_build(t, "qemu_probe").path
    lib = plugin.build(download=False)
    args = _probe_args()
    # Interleaved rounds, minimum over all: another process stealing the CPU hits whole runs.
    runs: dict[str, list[dict]] = {"native": [], "plain": [], "inline": [], "vcpu": []}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(ROUNDS):
            runs["native"].append(_llt(subprocess.run([str(native_exe), *args], capture_output=True,
                                                      text=True, check=True).stdout))
            runs["plain"].append(_llt(user.run(t, exe, args).stdout))
            for c in ("inline", "vcpu") if lib else ():
                counter = InsnCounter(Path(tmp) / f"{c}.log", c, lib)
                runs[c].append(_llt(user.run(t, exe, args, plugin=counter).stdout))
    best = {k: {n: (min(r[n][0] for r in v), v[0][n][1]) for n in SIZES} for k, v in runs.items() if v}
    native, plain = best["native"], best["plain"]
    counted = {c: best[c] for c in ("inline", "vcpu") if c in best}
    print(f"\n{name}: {t.cpu} at {t.clock_hz / 1e6:.0f} MHz, CPI {t.cpi.nominal} [{t.cpi.low}-{t.cpi.high}]"
          f"{' (estimate)' if not t.cpi.calibrated else ''}")
    for n in SIZES:
        line = f"  LLT n={n:3d}: native {native[n][0] / 1e3:8.1f} us, qemu-user {plain[n][0] / 1e3:8.1f} us " \
               f"(x{plain[n][0] / native[n][0]:.0f})"
        if counted:
            insns = counted["inline"][n][1]
            nom, lo, hi = t.target_time_s(insns)
            line += (f", plugin inline x{counted['inline'][n][0] / plain[n][0]:.2f}, "
                     f"per-vCPU x{counted['vcpu'][n][0] / plain[n][0]:.2f}; {insns} insns -> target "
                     f"{nom * 1e6:.0f} us [{lo * 1e6:.0f}-{hi * 1e6:.0f}]")
        print(line)
    if t.system:
        img = system.image(t, download=False)
        if img is None:
            print("  system mode: image not prepared (python -m rvd_pil.qemu prepare)")
            return
        r = system.run(t, exe, ["llt", "200"], img=img)
        m = _llt("\n".join(r.output))
        print(f"  system mode ({t.system.machine}, icount): boot to program {r.boot_s:.1f} s, to power-off "
              f"{r.wall_s:.1f} s; in-guest LLT n=200 {m[200][0] / 1e3:.1f} us (= instructions incl. "
              f"interrupts, shift=0)")


def main(argv: list[str]) -> int:
    host = targets.load("host")
    native_exe = build.cross_build(host, "qemu_probe").path
    for name in argv or ["q7s", "rpi3"]:
        bench_target(name, native_exe)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
