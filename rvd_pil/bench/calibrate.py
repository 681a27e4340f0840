"""Board calibration of the cycle model: the same static executable, the same recorded inputs, on the
real board under `perf stat`, against the model's prediction for that very run.

    python -m rvd_pil.bench.calibrate prepare --target rpi3             # 1. the prediction (QEMU + model)
    python -m rvd_pil.bench.calibrate host --target rpi3 --board pi@rpi3 --host-address 192.168.1.10
                                                               # 2. the board run (ssh, perf stat)
    python -m rvd_pil.bench.calibrate apply --target rpi3 --perf perf.csv --board-run DIR
                                                               # 3. the factor -> rvd_pil/qemu/calibration.toml

The run is Case 1 in the ideal setting (CW truth, no noise, impulsive burns, no control delay): the
host simulator then sends the board exactly the navigation messages QEMU's run received, as long as
the board answers with the same commands, which it does when it runs the same binary (IEEE
arithmetic is exact in QEMU). `apply` checks that (the board run's commands must equal the QEMU
run's bit for bit) and that perf's user-mode instruction count matches the QEMU count of the whole
process within 1 % (the board also runs vDSO code QEMU does not), then writes

    factor = measured user-mode cycles / model nominal cycles of the whole process

for the CPU into rvd_pil/qemu/calibration.toml. The model multiplies every nominal estimate by it, and the
report marks them calibrated. L1D load misses measured vs modelled are recorded beside it: they
check the cache model.
"""
from __future__ import annotations

import argparse
import datetime as dt
import hashlib
import json
import shlex
import shutil
import sys
from pathlib import Path

from rvd_pil import paths

OUT = paths.build_root() / "calibration"
PERF_EVENTS = ("cycles:u", "instructions:u", "L1-dcache-load-misses:u")
IDEAL = dict(truth="cw", sensor_noise=False, thrust_noise=False, impulsive=True)


def _sha(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


def parse_perf_csv(text: str) -> dict[str, float]:
    """perf stat -x, output: {event without modifiers: count}. Raises when a counter was not
    counted (a VM without a PMU prints <not supported> or <not counted>)."""
    out = {}
    for line in text.splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        fields = line.split(",")
        if len(fields) < 3:
            continue
        value, event = fields[0].strip(), fields[2].strip().split(":")[0]
        if value.startswith("<"):
            raise ValueError(f"perf could not count {event}: {value} (no usable PMU on this machine)")
        out[event] = float(value)
    missing = [e.split(":")[0] for e in PERF_EVENTS if e.split(":")[0] not in out]
    if missing:
        raise ValueError(f"perf output lacks {', '.join(missing)}")
    return out


def prepare(target_name: str, out: Path = OUT) -> dict:
    """QEMU run of the ideal Case 1 with both plugins; the model's prediction for the whole process."""
    from rvd_pil.host_sim.pil import run_pil
    from rvd_pil.host_sim.server import ServerConfig
    from rvd_pil.qemu import build, cycles, plugin, targets, user

    t = targets.load(target_name)
    exe = build.cross_build(t)
    model = cycles.CycleModel(t)
    out = out / t.build_name
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    shutil.copy2(exe.path, out / exe.path.name)
    prof = out / "qemu.blocks"
    counter = plugin.InsnCounter(log=out / "qemu.insns")
    # perf counts the whole process on the board: the cache model sees every access here too
    profiler = plugin.BlockProfiler(out=prof, cache=model.cache_geometry, cache_scope="process")
    summary, run_dir = run_pil("case1_vbar", **IDEAL, config=ServerConfig(delay_model="none"),
                               flight_command=lambda args: user.command(t, exe.path, args, plugin=[counter, profiler]),
                               run_dir=out / "qemu-run")
    p = cycles.read_profile(prof)
    costs = model.block_costs(exe.path, p.blocks)
    whole = model.region_cycles(p.process, costs)
    pred = {"target": t.name, "cpu": t.cpu, "exe": exe.path.name, "exe_sha": _sha(exe.path),
            "steps": summary.steps, "instructions": p.process.insns,
            "cycles_low": whole.low, "cycles_nominal": whole.nominal, "cycles_high": whole.high,
            "l1d_load_misses": p.process.cache["load_l1_miss"], "model": model.fingerprint(),
            "qemu_run": str(run_dir.relative_to(out))}
    (out / "prediction.json").write_text(json.dumps(pred, indent=1))
    return pred


def board_command(board: str, remote_dir: str, exe_name: str, args: list[str]) -> list[str]:
    """The ssh command that runs the flight executable on the board under perf stat."""
    events = ",".join(PERF_EVENTS)
    inner = (f"cd {shlex.quote(remote_dir)} && perf stat -x, -o perf.csv -e {events} "
             f"./{shlex.quote(exe_name)} {shlex.join(args)}")
    return ["ssh", board, inner]


def host(target_name: str, board: str, host_address: str, remote_dir: str, out: Path = OUT) -> Path:
    """Serves the ideal Case 1 to the flight executable on the board (started over ssh under perf)
    and fetches perf's output."""
    import subprocess

    from rvd_pil.host_sim.pil import run_pil
    from rvd_pil.host_sim.server import ServerConfig
    from rvd_pil.qemu import targets

    t = targets.load(target_name)
    out = out / t.build_name
    pred = json.loads((out / "prediction.json").read_text())
    subprocess.run(["scp", str(out / pred["exe"]), f"{board}:{remote_dir}/"], check=True)
    run_dir = out / "board-run"
    if run_dir.exists():
        shutil.rmtree(run_dir)
    run_pil("case1_vbar", **IDEAL, config=ServerConfig(delay_model="none"), host_address=host_address,
            flight_command=lambda args: board_command(board, remote_dir, pred["exe"], args), run_dir=run_dir)
    subprocess.run(["scp", f"{board}:{remote_dir}/perf.csv", str(out / "perf.csv")], check=True)
    return run_dir


def apply(target_name: str, perf_csv: Path, board_run: Path, board: str, out: Path = OUT,
          calibration_file: Path | None = None) -> dict:
    """Checks the board run against the QEMU run and writes the CPU's factor."""
    from rvd_pil.host_sim.record import load_run
    from rvd_pil.qemu import cycles, targets

    t = targets.load(target_name)
    out = out / t.build_name
    pred = json.loads((out / "prediction.json").read_text())
    measured = parse_perf_csv(Path(perf_csv).read_text())
    _, qemu_steps = load_run(out / pred["qemu_run"])
    _, board_steps = load_run(Path(board_run))
    cols = [c for c in qemu_steps.columns if c.startswith("dv_cmd") or c.startswith("pulse")]
    if not cols:
        cols = [c for c in qemu_steps.columns if c.startswith("dv_")]
    same = len(qemu_steps) == len(board_steps) and qemu_steps[cols].equals(board_steps[cols])
    if not same:
        raise ValueError("the board's commands differ from the QEMU run's: not the same run, no calibration")
    ratio_insns = measured["instructions"] / pred["instructions"]
    if abs(ratio_insns - 1) > 0.01:
        raise ValueError(f"board instructions {measured['instructions']:.0f} vs QEMU {pred['instructions']} "
                         f"({ratio_insns:.4f}): not the same executable or inputs")
    factor = measured["cycles"] / pred["cycles_nominal"]
    entry = {"factor": round(factor, 4), "board": board, "date": dt.date.today().isoformat(),
             "exe_sha": pred["exe_sha"], "measured_cycles": measured["cycles"],
             "model_nominal_cycles": round(pred["cycles_nominal"]), "model_interval": [round(pred["cycles_low"]),
                                                                                       round(pred["cycles_high"])],
             "measured_instructions": measured["instructions"], "model_instructions": pred["instructions"],
             "measured_l1d_load_misses": measured["L1-dcache-load-misses"],
             "model_l1d_load_misses": pred["l1d_load_misses"]}
    path = Path(calibration_file or cycles.CALIBRATION)
    existing = cycles.calibrations() if path == cycles.CALIBRATION else {}
    existing[pred["cpu"]] = entry
    lines = ["# Board calibrations of the cycle model, written by `python -m rvd_pil.bench.calibrate apply`.",
             "# factor = perf's user-mode cycles / the model's nominal cycles for the same run (ideal Case 1).", ""]
    for cpu, e in sorted(existing.items()):
        lines.append(f"[cpu.{cpu}]")
        for k, v in e.items():
            lines.append(f"{k} = {json.dumps(v)}")
        lines.append("")
    path.write_text("\n".join(lines))
    return entry


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m rvd_pil.bench.calibrate", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=__doc__.split("\n\n", 1)[1])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p1 = sub.add_parser("prepare")
    p1.add_argument("--target", required=True)
    p2 = sub.add_parser("host")
    p2.add_argument("--target", required=True)
    p2.add_argument("--board", required=True, help="ssh destination, e.g. pi@rpi3")
    p2.add_argument("--host-address", required=True, help="this machine's address as the board sees it")
    p2.add_argument("--remote-dir", default="/tmp", help="working directory on the board")
    p3 = sub.add_parser("apply")
    p3.add_argument("--target", required=True)
    p3.add_argument("--perf", type=Path, required=True)
    p3.add_argument("--board-run", type=Path, required=True)
    p3.add_argument("--board", required=True, help="what the board is (recorded beside the factor)")
    a = ap.parse_args(argv)
    if a.cmd == "prepare":
        pred = prepare(a.target)
        print(json.dumps(pred, indent=1))
        print(f"\nnext: python -m rvd_pil.bench.calibrate host --target {a.target} --board USER@BOARD --host-address IP")
    elif a.cmd == "host":
        run_dir = host(a.target, a.board, a.host_address, a.remote_dir)
        print(f"board run: {run_dir}\nnext: python -m rvd_pil.bench.calibrate apply --target {a.target} "
              f"--perf {run_dir.parent / 'perf.csv'} --board-run {run_dir} --board '{a.board}'")
    else:
        print(json.dumps(apply(a.target, a.perf, a.board_run, a.board), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
