"""rvd-study: run a study file (the grid of runs it names), resumably, and write its report.

    rvd-study ch5_robustness --quick              a shipped study (rvd_pil/studies/*.toml) at its quick size
    rvd-study rvd_pil/studies/ch6_timing.toml --jobs 2    two local processes (default: all cores)
    rvd-study my_study.toml --dask tcp://10.0.0.5:8786 --out results/my_study
    rvd-study --list                              the shipped studies

Runs already stored in the output folder are not computed again: after Ctrl-C (or a kill) the same
command continues where it stopped. The output folder (default reports/studies/<name>[-quick])
belongs to one study and grid; another study or grid is refused there.

Exit status: 0 done, 1 some runs failed (the others are stored), 2 bad input (nothing written),
130 stopped by Ctrl-C (finished runs kept).
"""
from __future__ import annotations

import argparse
import os
import sys

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # one BLAS thread per run: runs are the parallelism


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="rvd-study", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=__doc__.split("\n\n", 1)[1])
    ap.add_argument("study", nargs="?", help="study file (TOML) or the name of a shipped study")
    ap.add_argument("--quick", action="store_true", help="the study's quick size (minutes)")
    where = ap.add_mutually_exclusive_group()
    where.add_argument("--jobs", type=int, default=None, help="local worker processes (default: all cores)")
    where.add_argument("--dask", metavar="ADDRESS", default=None, help="Dask scheduler, e.g. tcp://127.0.0.1:8786")
    ap.add_argument("--out", default=None, help="output folder (default reports/studies/<name>[-quick])")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    ap.add_argument("--report-only", action="store_true",
                    help="redraw the report from the runs stored in the output folder (computes and builds nothing)")
    ap.add_argument("--list", action="store_true", help="list the shipped studies and exit")
    return ap


def main(argv=None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    from . import spec

    if args.list:
        from . import grid

        for name in spec.available():
            full, quick = (grid.distinct_runs(grid.expand(spec.load(name, quick=q))) for q in (False, True))
            print(f"{name:<18} {full:>6} runs ({quick} with --quick)  {spec.load(name).description}")
        return 0
    if not args.study:
        ap.error("a study file is needed (or --list)")
    if args.jobs is not None and args.jobs < 1:
        ap.error(f"--jobs must be >= 1, got {args.jobs}")
    from . import OwnershipError, StudyError, report_study, run_study

    if args.report_only:
        try:
            result = report_study(args.study, quick=args.quick, out=args.out,
                                  say=lambda s: print(s, file=sys.stderr, flush=True))
        except (StudyError, OwnershipError) as exc:
            print(f"rvd-study: {exc}", file=sys.stderr)
            return 2
        print(f"report: {result.report}")
        return 0
    try:
        result = run_study(args.study, quick=args.quick, jobs=args.jobs, dask=args.dask, out=args.out,
                           progress=not args.no_progress, say=lambda s: print(s, file=sys.stderr, flush=True))
    except (StudyError, OwnershipError) as exc:
        print(f"rvd-study: {exc}", file=sys.stderr)
        return 2
    except (OSError, RuntimeError) as exc:  # no flight executable, a failed cross build, no Dask scheduler
        print(f"rvd-study: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    o = result.outcome
    if o is not None:
        rate = o.stored / o.wall_s * 3600 if o.wall_s > 0 else float("nan")
        per_core = o.stored / o.cpu_s * 3600 if o.cpu_s > 0 else float("nan")
        print(f"{result.study.label}: stored {o.stored} runs in {o.wall_s:.0f} s ({rate:.0f} runs/h; "
              f"{per_core:.0f} runs per CPU-hour of the workers)"
              + (f", {len(o.failed)} failed" if o.failed else ""), file=sys.stderr)
        for key, err in list(o.failed.items())[:3]:
            print(f"  failed {key}: {err}", file=sys.stderr)
    if not result.complete:
        print(f"{result.study.label}: {result.finished} of {result.total} runs stored in {result.out}; run the "
              "same command again to continue", file=sys.stderr)
        return 130 if (o is not None and o.stopped) else 1
    print(f"report: {result.report}")
    if o is not None and o.failed:
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
