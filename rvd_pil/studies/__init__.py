"""rvd-pil studies: many runs from one study file, in parallel, resumable, with a report.

    from rvd_pil.studies import run_study
    result = run_study("ch5_robustness", quick=True, jobs=2)
    result.runs        # one row per grid point: coordinates and metrics
    result.summary     # per sweep point: counts, success, mean/std/min/max of the metrics
    result.solves      # per solved guidance step (timing studies)
    result.tables      # the report's tables (deterministic); result.timing: its wall-time tables

The command line is `rvd-study FILE [--quick] [--jobs N] [--dask ADDRESS] [--out DIR]`
(rvd_pil/studies/cli.py); the study file format is described in rvd_pil/studies/README.md.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from .spec import Study, StudyError, load  # noqa: F401
from .store import OwnershipError  # noqa: F401


@dataclass
class StudyResult:
    study: Study
    out: Path
    fingerprint: str
    total: int                 # distinct runs in the grid
    finished: int              # of those, stored
    runs: pd.DataFrame
    summary: pd.DataFrame
    solves: pd.DataFrame
    tables: dict = field(default_factory=dict)
    timing: dict = field(default_factory=dict)
    outcome: object = None     # what this call computed (None: nothing was left to run)
    report: Path | None = None

    @property
    def complete(self) -> bool:
        return self.finished == self.total


def collect(study: Study, plan, store, outcome=None) -> StudyResult:
    """The DataFrames of what is stored for this plan (complete or not)."""
    from . import aggregate, report

    runs = aggregate.runs_frame(plan, store)
    summary = aggregate.summary_frame(runs, study.report["metrics"])
    want_solves = study.report["kind"] == "timing" or any(p.mode == "qemu-user" for p in plan.points)
    solves = aggregate.solves_frame(plan, store, runs) if want_solves and not runs.empty else pd.DataFrame()
    done = store.finished() & set(plan.tasks)
    result = StudyResult(study=study, out=store.out, fingerprint=plan.fingerprint, total=len(plan.tasks),
                         finished=len(done), runs=runs, summary=summary, solves=solves, outcome=outcome)
    result.tables, result.timing = report.build_tables(result)
    return result


def report_study(study: str | Path | Study, *, quick: bool = False, out: str | Path | None = None,
                 say=print) -> StudyResult:
    """The DataFrames and report of the runs stored in `out`, computing nothing and building
    nothing (e.g. to redraw a report after the executables changed); the points are matched to the
    stored runs by their content."""
    from . import execute, report
    from .store import Store

    st = study if isinstance(study, Study) else load(study, quick=quick)
    store = Store(out if out is not None else execute.default_out(st))
    if not (store.out / "study.json").is_file():
        raise OwnershipError(f"{store.out} holds no study to report")
    store.check({"study": st.name, "quick": st.quick}, grid=False)
    p, total = execute.stored_plan(st, store)
    result = collect(st, p, store)
    result.total = total
    say(f"{st.label}: report of {result.finished} stored runs of {result.total} -> {store.out}")
    if not result.runs.empty:
        result.report = report.write(result)
    return result


def run_study(study: str | Path | Study, *, quick: bool = False, jobs: int | None = None, dask: str | None = None,
              out: str | Path | None = None, progress: bool = True, write_report: bool = True,
              say=print) -> StudyResult:
    """Runs what is not stored yet of a study and returns its DataFrames (see the module docstring).

    Raises StudyError (bad study file) or OwnershipError (`out` holds another study or grid) before
    anything is written."""
    from . import execute, report
    from .store import Store

    st = study if isinstance(study, Study) else load(study, quick=quick)
    store = Store(out if out is not None else execute.default_out(st))
    store.check({"study": st.name, "quick": st.quick}, grid=False)  # before any build
    p = execute.plan(st, say=say)
    store.check(p.owner)
    store.claim(p.owner, st.source)
    try:
        done = store.finished() & set(p.tasks)
        todo = [k for k in p.tasks if k not in done]
        say(f"{st.label}: {len(p.tasks)} runs ({len(p.points)} grid points), {len(done)} stored, {len(todo)} to run "
            f"-> {store.out}")
        outcome = None
        if todo:
            if dask:
                executor = execute.DaskExecutor(dask, list(p.engines.values()))
            else:
                executor = execute.LocalExecutor(max(1, min(jobs or execute.default_jobs(), len(todo))))
            say(f"{st.label}: computing on {executor.describe()}")
            outcome = execute.execute_plan(p, store, todo, executor, progress=progress, say=say)
            outcome.executor = executor.describe()
        result = collect(st, p, store, outcome)
        if write_report and result.complete:
            result.report = report.write(result)
    finally:
        store.release()
    return result
