"""Running a study: the grid, its runs keyed by content, the executors, progress and a clean stop.

    result = run_study("ch5_robustness", quick=True, jobs=2)          # local processes
    result = run_study("ch5_robustness", dask="tcp://10.0.0.5:8786")  # a Dask distributed cluster
    result.runs, result.summary, result.solves                        # pandas DataFrames

Executors: local processes (default: all cores), each in its own session so a Ctrl-C at the
terminal reaches only the client, and killed with the client; or a Dask cluster, to which the
executables travel as bytes (scattered once to every worker) and from which each record comes back
as bytes. The first Ctrl-C (or SIGTERM) stops handing out runs and waits for the runs under way,
storing each as it finishes; a second one abandons them. Either way every finished run is stored,
and running the same study again computes only the rest.
"""
from __future__ import annotations

import concurrent.futures as cf
import contextlib
import ctypes
import multiprocessing
import os
import signal
import sys
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

from . import engine as engines
from . import grid, spec
from .store import Store

PR_SET_PDEATHSIG = 1


def _local_worker_init() -> None:
    """Each local worker: its own session (the terminal's Ctrl-C goes to the client alone, which
    then stops cleanly) and killed when the client dies (a SIGKILLed client leaves no worker)."""
    os.setsid()
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    except OSError:
        pass
    if os.getppid() == 1:  # the client died before prctl took effect
        os._exit(1)


@contextlib.contextmanager
def _main_not_imported():
    """Spawned workers would import the caller's main script again (multiprocessing's "safe
    importing of main module" rule), running an unguarded script's study a second time in every
    worker. They need only this package, so they are started with __main__ hidden."""
    main = sys.modules.get("__main__")
    saved = {k: getattr(main, k) for k in ("__file__", "__spec__") if main is not None and hasattr(main, k)}
    try:
        if main is not None:
            main.__spec__ = None
            if hasattr(main, "__file__"):
                del main.__file__
        yield
    finally:
        for k, v in saved.items():
            setattr(main, k, v)


class LocalExecutor:
    def __init__(self, jobs: int):
        self.jobs = jobs
        self.pool = self._new_pool()
        self.slots = jobs + 1  # one queued behind the busy workers, so none waits for the client

    def _new_pool(self):
        # One BLAS thread per worker (set before the workers import numpy): the runs are the
        # parallelism, and threaded BLAS on small matrices is much slower on a loaded machine.
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        return cf.ProcessPoolExecutor(max_workers=self.jobs, mp_context=multiprocessing.get_context("spawn"),
                                      initializer=_local_worker_init)

    def describe(self) -> str:
        return f"{self.jobs} local process{'es' if self.jobs > 1 else ''}"

    def submit(self, task: dict):
        from .run import execute

        with _main_not_imported():  # workers are started on demand, inside submit
            try:
                return self.pool.submit(execute, task)
            except cf.process.BrokenProcessPool:
                # A worker died (its runs under way fail and are retried on the next start): new workers.
                self.pool.shutdown(wait=False, cancel_futures=True)
                self.pool = self._new_pool()
                return self.pool.submit(execute, task)

    def wait(self, futures, timeout: float):
        done, _ = cf.wait(futures, timeout=timeout, return_when=cf.FIRST_COMPLETED)
        return done

    def close(self, abandon: bool) -> None:
        if abandon:
            for p in list(getattr(self.pool, "_processes", {}).values()):
                try:
                    os.killpg(p.pid, signal.SIGKILL)  # the worker and the flight process it started
                except (ProcessLookupError, PermissionError):
                    pass
            self.pool.shutdown(wait=False, cancel_futures=True)
        else:
            self.pool.shutdown(wait=True)


class DaskExecutor:
    def __init__(self, address: str, engines_used: list):
        from distributed import Client

        self.client = Client(address, timeout="30s")
        info = self.client.scheduler_info()
        self.threads = sum(w.get("nthreads", 1) for w in info["workers"].values())
        if not self.threads:
            raise RuntimeError(f"the Dask scheduler at {address} has no workers")
        self.slots = 2 * self.threads
        self.address = address
        self.data = {}
        for eng in engines_used:
            for art in (eng.exe, eng.plugin):
                if art is not None and art.sha not in self.data:
                    # once to every worker; tasks then refer to it by future
                    self.data[art.sha] = self.client.scatter(art.read(), broadcast=True, hash=False)

    def describe(self) -> str:
        return f"Dask cluster {self.address} ({self.threads} worker threads)"

    def submit(self, task: dict):
        from .run import execute

        eng = task["engine"]
        exe = self.data.get(eng.exe.sha) if eng.exe else None
        plug = self.data.get(eng.plugin.sha) if eng.plugin else None
        return self.client.submit(execute, task, exe, plug, key=f"rvd-run-{task['key']}-{uuid.uuid4().hex[:8]}",
                                  pure=False)

    def wait(self, futures, timeout: float):
        from distributed import wait

        try:
            wait(list(futures), timeout=timeout, return_when="FIRST_COMPLETED")
        except TimeoutError:
            pass
        return {f for f in futures if f.done()}

    def close(self, abandon: bool) -> None:
        try:
            if self.data:
                self.client.cancel(list(self.data.values()))
        finally:
            self.client.close()


class _Stop:
    """First SIGINT/SIGTERM: stop handing out runs; second: abandon the runs under way."""

    def __init__(self, say):
        self.requested = 0
        self.say = say
        self._old = {}

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum, frame):
        self.requested += 1
        if self.requested == 1:
            self.say("\nstopping: no new runs; waiting for the runs under way (Ctrl-C again to abandon them)")

    def __exit__(self, *exc):
        for sig, old in self._old.items():
            signal.signal(sig, old)


@dataclass
class Plan:
    study: spec.Study
    points: list              # every grid point (sweep membership)
    keys: list                # run key of each point
    tasks: dict               # key -> task (one per distinct run, in grid order)
    engines: dict
    fingerprint: str

    @property
    def owner(self) -> dict:
        return {"study": self.study.name, "quick": self.study.quick, "grid": self.fingerprint,
                "runs": len(self.tasks), "source": str(self.study.source)}


def plan(study: spec.Study, say=print) -> Plan:
    """Expands the grid (validating scenarios), resolves the engines (builds) and keys every run."""
    import hashlib

    points = grid.expand(study)
    engines_by = {}
    for p in points:
        k = (p.mode, p.target, p.cpu)
        if k not in engines_by:
            engines_by[k] = engines.resolve(p.mode, p.target, p.cpu, say=say)
    keys, tasks = [], {}
    for p in points:
        eng = engines_by[(p.mode, p.target, p.cpu)]
        key = grid.run_key(p, eng.identity)
        keys.append(key)
        if key not in tasks:
            tasks[key] = {"key": key, "study": study.name, "point": p, "engine": eng}
    fingerprint = hashlib.sha256("\n".join(sorted(tasks)).encode()).hexdigest()
    return Plan(study, points, keys, tasks, engines_by, fingerprint)


def stored_plan(study: spec.Study, store: Store) -> tuple[Plan, int]:
    """The grid mapped onto the runs stored in `store` by their content (for a report of what is
    there, whatever built it; points without a stored run are left out), and the grid's size."""
    import hashlib
    import json

    from .run import content_id

    by_content = {}
    for key in store.finished():
        run = json.loads((store.runs / key / "meta.json").read_text())["study_run"]
        by_content[run.get("content")] = key
    points, keys, tasks = [], [], {}
    every = grid.expand(study)
    for p in every:
        key = by_content.get(content_id(p))
        if key is None:
            continue
        points.append(p)
        keys.append(key)
        tasks.setdefault(key, {"key": key, "study": study.name, "point": p, "engine": None})
    fingerprint = hashlib.sha256("\n".join(sorted(tasks)).encode()).hexdigest()
    return Plan(study, points, keys, tasks, {}, fingerprint), grid.distinct_runs(every)


@dataclass
class Outcome:
    stored: int = 0
    failed: dict = field(default_factory=dict)   # key -> error text
    stopped: bool = False
    abandoned: int = 0
    cpu_s: float = 0.0
    wall_s: float = 0.0


def execute_plan(p: Plan, store: Store, todo: list[str], executor, *, progress: bool = True, say=print) -> Outcome:
    from tqdm import tqdm

    out = Outcome()
    t0 = time.monotonic()
    tty = sys.stderr.isatty()
    bar = tqdm(total=len(todo), unit="run", desc=p.study.label, file=sys.stderr, disable=not progress,
               dynamic_ncols=tty, smoothing=0.05, mininterval=0.5 if tty else 30.0)
    queue = list(reversed(todo))
    running: dict = {}
    broken_in_a_row = 0  # runs lost to dead workers since the last run that came back
    with _Stop(lambda s: bar.write(s)) as stop:
        try:
            while queue or running:
                while queue and len(running) < executor.slots and not stop.requested:
                    key = queue.pop()
                    running[executor.submit(p.tasks[key])] = key
                if stop.requested > 1:
                    break
                if stop.requested and not running:
                    break
                for fut in executor.wait(set(running), timeout=0.5):
                    key = running.pop(fut)
                    try:
                        res = fut.result()
                    except BaseException as exc:  # noqa: BLE001 - a worker's failure is the run's, not ours
                        if isinstance(exc, cf.CancelledError):
                            continue
                        out.failed[key] = f"{type(exc).__name__}: {exc}"
                        store.failed(key, out.failed[key])
                        bar.set_postfix(failed=len(out.failed))
                        if isinstance(exc, cf.process.BrokenProcessPool):
                            broken_in_a_row += 1
                            if broken_in_a_row > 2 * executor.slots:
                                raise RuntimeError(f"the local worker processes die before finishing any run ({exc})") from None
                    else:
                        store.commit(res)
                        out.stored += 1
                        out.cpu_s += res.get("cpu_s", 0.0)
                        broken_in_a_row = 0
                    bar.update(1)
        finally:
            out.stopped = stop.requested > 0
            out.abandoned = len(running)
            executor.close(abandon=bool(running))
            bar.close()
    out.wall_s = time.monotonic() - t0
    return out


def default_out(study: spec.Study) -> Path:
    return Path("reports") / "studies" / (f"{study.name}-quick" if study.quick else study.name)


def default_jobs() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
