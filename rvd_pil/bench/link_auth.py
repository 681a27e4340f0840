"""What the link's message tag (HMAC-SHA-256, flight_sw/link/sha256.cpp) costs per message, side by
side with the untagged codec, natively and on each emulated target (prints; asserts nothing):

    python -m rvd_pil.bench.link_auth [--targets q7s,rpi3] [--n 2000] [--json reports/link_auth.json]

Per message type (nav, cmd, telemetry, hello) and per platform:
  - native: wall time per message of encode, encode + seal, decode, open + decode (fastest of five
    rounds, tests/cpp/tools/link_auth_bench.cpp) and the tag's share (seal - encode, open - decode);
  - each target under QEMU user mode with the instruction-counting plugin: instructions per message
    for the same four operations (exact, repeatable), and the estimated target time of the tag from
    the target's CPU model (instructions x CPI / f_clk, rvd_pil/qemu/targets.toml; not calibrated on
    hardware), also as a fraction of the shortest control period (5 s, docking).
Wall times depend on this host and its load; the instruction counts do not.
"""
from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

from rvd_pil import paths

PROGRAM = "link_auth_bench"
LINE = re.compile(r"auth (.*)")
SHORTEST_PERIOD_S = 5.0


def _parse(stdout: str) -> dict[str, dict]:
    out = {}
    for m in LINE.finditer(stdout):
        fields = dict(kv.split("=", 1) for kv in m.group(1).split())
        name = fields.pop("msg")
        out[name] = {k: (float(v) if "." in v else int(v)) for k, v in fields.items()}
    return out


def native(n: int) -> dict[str, dict]:
    build = paths.require_checkout("the link authentication benchmark (tests/cpp/tools)") / "build" / "native"
    subprocess.run(["cmake", "--build", str(build), "--target", PROGRAM, "-j2"], check=True, capture_output=True)
    exe = next(p for p in build.rglob(PROGRAM) if p.is_file() and "CMakeFiles" not in p.parts)
    return _parse(subprocess.run([str(exe), str(n)], check=True, capture_output=True, text=True).stdout)


def emulated(name: str, n: int) -> tuple[object, dict[str, dict]]:
    from rvd_pil.qemu import build, plugin, targets, user

    t = targets.load(name)
    exe = build.cross_build(t, PROGRAM).path
    lib = plugin.build(download=True)
    with tempfile.TemporaryDirectory() as tmp:
        counter = plugin.InsnCounter(log=Path(tmp) / "insns.log", library=lib)
        r = user.run(t, exe, [str(n)], plugin=counter)
    if r.returncode != 0:
        raise RuntimeError(f"{name}: {PROGRAM} failed: {r.stderr}")
    return t, _parse(r.stdout)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m rvd_pil.bench.link_auth", description=__doc__.splitlines()[0])
    ap.add_argument("--targets", default="q7s,rpi3", help="emulated targets (rvd_pil/qemu/targets.toml), '' for none")
    ap.add_argument("--n", type=int, default=2000, help="messages per measurement (default 2000)")
    ap.add_argument("--json", default=None, help="also write the figures here")
    args = ap.parse_args(argv)
    report = {"native": native(args.n), "targets": {}}
    print("native (this host, wall time per message, fastest of 5 rounds; ns)")
    print(f"{'message':<10}{'bytes':>6}{'encode':>9}{'+ seal':>9}{'tag':>8}{'decode':>9}{'+ open':>9}{'tag':>8}")
    for name, f in report["native"].items():
        seal_tag, open_tag = f["seal_ns"] - f["encode_ns"], f["open_ns"] - f["decode_ns"]
        print(f"{name:<10}{f['bytes']:>6}{f['encode_ns']:>9.0f}{f['seal_ns']:>9.0f}{seal_tag:>8.0f}"
              f"{f['decode_ns']:>9.0f}{f['open_ns']:>9.0f}{open_tag:>8.0f}")
    for name in [x for x in args.targets.split(",") if x]:
        t, figures = emulated(name, args.n)
        report["targets"][name] = {"cpu": t.cpu, "clock_hz": t.clock_hz, "cpi": t.cpi.nominal, "messages": figures}
        print(f"\n{name}: {t.cpu} at {t.clock_hz / 1e6:.0f} MHz, CPI {t.cpi.nominal} (model, not calibrated); "
              "instructions per message (plugin)")
        print(f"{'message':<10}{'encode':>9}{'+ seal':>9}{'tag':>8}{'decode':>9}{'+ open':>9}{'tag':>8}"
              f"{'tag us':>9}{'per 5 s':>12}")
        for msg, f in figures.items():
            seal_tag, open_tag = f["seal_insns"] - f["encode_insns"], f["open_insns"] - f["decode_insns"]
            us = (seal_tag + open_tag) / 2 * t.cpi.nominal / t.clock_hz * 1e6
            print(f"{msg:<10}{f['encode_insns']:>9}{f['seal_insns']:>9}{seal_tag:>8}{f['decode_insns']:>9}"
                  f"{f['open_insns']:>9}{open_tag:>8}{us:>9.1f}{us * 1e-6 / SHORTEST_PERIOD_S:>12.1e}")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(report, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
