"""Instructions per solve under QEMU for both targets, per phase and horizon, from the PIL campaign's
own counting (the TCG plugin around every solver call of a guidance step: the phase QP, plus the
recovery QP when it runs), beside the figures of the solver before soft rows, the fixed-size
kernels and the infeasibility certificate. Prints figures; asserts nothing.

    python -m rvd_pil.bench.solver_insns                    # runs the campaign (user mode, no checks) into reports/insns
    python -m rvd_pil.bench.solver_insns --out reports/pil  # summarise an existing campaign directory

Per (target, phase, N): solves, mean and max instructions per solve, mean iterations, max/median
estimated target time (the closed-loop goal: <= 2), the ratio to the earlier figures where the
earlier campaign measured them (rpi3 means of `make pil` before the change), and which solve was
the largest: its run's step, "first" when it was the phase's first solve of that run (a cold start
unless a look-ahead prepared it), and its interior-point iterations when it ran any, or the rows its
active-set method changed (the law's logged value, law_values.csv).
"""
from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

from rvd_pil import paths

# `make pil` before the change, rpi3 (Cortex-A53) means of instructions per solve.
EARLIER_MEAN = {("rpi3", "rendezvous", 30): 2.73e6, ("rpi3", "approach", 15): 5.42e6, ("rpi3", "docking", 12): 0.92e6}


def logged_value(run_dir: Path, step: int, name: str) -> float | None:
    """The value the law logged under `name` at `step` of a run (law_values.csv), None when it logged none."""
    import pandas as pd
    path = run_dir / "law_values.csv"
    if not path.exists() or path.stat().st_size == 0:
        return None
    vals = pd.read_csv(path)
    hit = vals[(vals["step"] == step) & (vals["name"] == name)]
    return float(hit["value"].iloc[0]) if len(hit) else None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=None, help="an existing campaign directory to summarise (default: run one)")
    ap.add_argument("--targets", default="q7s,rpi3")
    args = ap.parse_args(argv)
    out = Path(args.out) if args.out else paths.reports_root() / "insns"
    if not args.out:
        subprocess.run([sys.executable, "-m", "rvd_pil.bench.campaign", "--targets", args.targets, "--no-checks", "--no-system",
                        "--out", str(out)], check=True)
    from rvd_pil.bench.report import load_campaign, solves
    metas, df = load_campaign(out)
    rows = solves(metas, df)
    rows = rows[rows["mode"] == "user"] if "mode" in rows else rows
    print(f"instructions per solve (QEMU user mode, plugin counts), campaign {out}")
    print(f"{'target':<7}{'phase':<11}{'N':>4}{'solves':>8}{'mean insns':>12}{'max insns':>12}{'mean it':>9}"
          f"{'max/median t':>14}{'vs earlier':>12}  largest solve")
    order = {"rendezvous": 0, "approach": 1, "docking": 2}
    for (target, phase, n), g in sorted(rows.groupby(["target", "phase_name", "N"]),
                                        key=lambda kv: (kv[0][0], order[kv[0][1]], kv[0][2])):
        mean = g["instructions"].mean()
        ratio = g["target_us_nominal"].max() / g["target_us_nominal"].median()
        ref = EARLIER_MEAN.get((target, phase, int(n)))
        vs = f"{mean / ref - 1:+.0%}" if ref else "-"
        worst = g.loc[g["target_us_nominal"].idxmax()]
        first = worst["step"] == g.loc[g["run"] == worst["run"], "step"].min()
        where = f"{worst['scenario_label']} step {int(worst['step'])}" + (" (first)" if first else "")
        if worst["iterations"] > 0:
            where += f", {int(worst['iterations'])} it"
        elif (changes := logged_value(out / worst["run"], int(worst["step"]), "active_set_changes")) is not None:
            where += f", {changes:.0f} changes"
        print(f"{target:<7}{phase:<11}{int(n):>4}{len(g):>8}{mean / 1e6:>11.2f}M{g['instructions'].max() / 1e6:>11.2f}M"
              f"{g['iterations'].mean():>9.1f}{ratio:>14.2f}{vs:>12}  {where}")
    print("vs earlier: change of the mean against `make pil` before the change (rpi3; the other cells were not "
          "measured then); max/median t: the closed loop's largest solve over its median (estimated target time)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
