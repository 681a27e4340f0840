"""Studies (rvd-study): bad input, content keys, the fast path against the native PIL run, executors
that agree, and a study interrupted (SIGINT, SIGKILL) and resumed.

Grids are tiny (CW truth: a run is a fraction of a second); the full studies are benchmarks."""
import json
import os
import random
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from rvd_pil.host_sim.record import load_events, load_run
from rvd_pil.studies import OwnershipError, grid, report_study, run_study, spec
from rvd_pil.studies.aggregate import frames_equal
from rvd_pil.studies.metrics import WALL_TIME_METRICS, quadrant, safety

pytestmark = pytest.mark.slow  # minutes: scheduled first (tests/conftest.py)

ROOT = Path(__file__).resolve().parent.parent
RVD_STUDY = [sys.executable, "-m", "rvd_pil.studies.cli"]
IDEAL = """
[model]
truth = "cw"
sensor_noise = false
thrust_noise = false
impulsive = true
delay = "none"
"""
TIMING_COLUMNS = {"solve_time_us", "step_time_us", "round_trip_ms"}  # host wall clock: differ run to run


def write_study(path: Path, body: str) -> Path:
    path.write_text(textwrap.dedent(body))
    return path


def cli(*args, cwd=None, **kw):
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    return subprocess.run([*RVD_STUDY, *map(str, args), "--no-progress"], capture_output=True, text=True,
                          cwd=cwd or ROOT, env=env, timeout=600, **kw)


def deterministic(runs: pd.DataFrame) -> pd.DataFrame:
    return runs.drop(columns=[c for c in WALL_TIME_METRICS if c in runs.columns])


# ---- bad input: one line naming file and key, exit 2, nothing written ----------------------------
BAD = {
    "unknown_key": ("[study]\nname = 'x'\n[model]\ntrut = 'cw'\n", "model.trut: unknown key"),
    "wrong_type": ("[study]\nname = 'x'\n[noise]\nrepeats = '60'\n", "noise.repeats: expected an integer"),
    "empty_grid": ("[study]\nname = 'x'\n[scenarios]\nnames = []\n", "scenarios: no scenarios"),
    "empty_axis": ("[study]\nname = 'x'\n[scenarios]\nnames = ['case1_vbar']\n[[sweep]]\nname = 'a'\n"
                   "vary.'guidance.rendezvous.N' = []\n", "sweep[0].vary.guidance.rendezvous.N: empty list"),
    "unknown_target": ("[study]\nname = 'x'\n[execution]\nmode = 'qemu-user'\ntargets = ['q7s', 'q8s']\n",
                       "execution.targets[1]: unknown target 'q8s'"),
    "unknown_cpu": ("[study]\nname = 'x'\n[execution]\nmode = 'qemu-user'\ntargets = ['q7s']\ncpus = ['cortex-z9']\n",
                    "execution.cpus[0]: unknown CPU 'cortex-z9'"),
    "cpu_of_other_arch": ("[study]\nname = 'x'\n[execution]\nmode = 'qemu-user'\ntargets = ['q7s']\n"
                          "cpus = ['cortex-a53']\n", "execution.cpus[0]: CPU 'cortex-a53' is aarch64"),
    "missing_scenario_file": ("[study]\nname = 'x'\n[scenarios]\nnames = ['case1_vbar', 'no_such.toml']\n",
                              "scenarios.names[1]: scenario file no_such.toml does not exist"),
    "unknown_scenario": ("[study]\nname = 'x'\n[scenarios]\nnames = ['case9']\n",
                         "scenarios.names[0]: unknown scenario 'case9'"),
    "bad_axis_value": ("[study]\nname = 'x'\n[scenarios]\nnames = ['case1_vbar']\n[[sweep]]\nname = 'a'\n"
                       "vary.'guidance.docking.Ts_s' = [5.0, -1.0]\n",
                       "sweep[0].vary.guidance.docking.Ts_s[1]: expected a number > 0"),
    "estimated_delay_native": ("[study]\nname = 'x'\n[model]\ndelay = 'estimated'\n",
                               "model.delay: 'estimated' needs instruction counts"),
    "unknown_in_quick": ("[study]\nname = 'x'\n[quick.noise]\nrepeat = 3\n", "quick.noise.repeat: unknown key"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_is_one_line_naming_file_and_key_exit_2_nothing_written(tmp_path, case):
    body, expected = BAD[case]
    study = tmp_path / f"{case}.toml"
    study.write_text(body)
    out = tmp_path / "out"
    r = cli(study, "--out", out)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert str(study) in lines[0] and expected in lines[0], lines[0]
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == [study.name]


def test_a_missing_study_file_and_bad_options_exit_2(tmp_path):
    r = cli(tmp_path / "nope.toml", "--out", tmp_path / "out")
    assert r.returncode == 2 and "nope.toml: study file does not exist" in r.stderr
    r = cli("ch5_robustness", "--jobs", "0", "--out", tmp_path / "out")
    assert r.returncode == 2 and "--jobs must be >= 1" in r.stderr
    assert not (tmp_path / "out").exists()


def test_shipped_studies_load_at_both_sizes_with_the_dissertations_grids():
    sizes = {}
    for name in ("ch4_sensitivity", "ch5_robustness", "ch6_timing", "pil_default"):
        for quick in (False, True):
            st = spec.load(name, quick=quick)
            sizes[name, quick] = grid.distinct_runs(grid.expand(st))
    # ch4: 500 starts x (1 baseline + 14 + 17 + 11 other settings); ch5: 100 x 60; ch6: 2 targets x
    # 100 starts x 12 settings (the baseline is shared by the five sweeps); make pil: 2 x 3 x 3 + 2 x 2 + 1.
    assert sizes["ch4_sensitivity", False] == 500 * 43
    assert sizes["ch5_robustness", False] == 6000
    assert sizes["ch6_timing", False] == 2 * 100 * 12
    assert sizes["pil_default", False] == 23
    assert all(sizes[n, True] < sizes[n, False] for n in ("ch4_sensitivity", "ch5_robustness", "ch6_timing"))


def test_run_keys_follow_content_not_listing(tmp_path):
    st = spec.load(write_study(tmp_path / "k.toml", """
        [study]
        name = "keys"
        [scenarios]
        names = ["case1_vbar"]
        [[sweep]]
        name = "a"
        vary."guidance.rendezvous.N" = [15, 30]
        [[sweep]]
        name = "b"
        vary."guidance.rendezvous.Ts_s" = [30.0, 60.0]
        [[sweep]]
        name = "c"
        vary."scenario.sensors.sigma_position_m" = [0.05, 0.1]
    """))
    pts = grid.expand(st)
    eng = {"mode": "in-process", "flight_sw_module": "x"}
    keys = [grid.run_key(p, eng) for p in pts]
    # the baseline (N 30, Ts 30 s, sigma 5 cm) is in all three sweeps: one run
    assert len(pts) == 6 and len(set(keys)) == 4
    assert keys[1] == keys[2] == keys[4]
    # the same content under another engine (another executable) is another run
    assert grid.run_key(pts[0], {**eng, "flight_sw_module": "y"}) != keys[0]
    # and the keys do not depend on the order of the listing
    assert grid.run_key(pts[0], dict(reversed(list(eng.items())))) == keys[0]


# ---- metrics -----------------------------------------------------------------------------------
def test_quadrants_number_from_the_port_side():
    port = (0.0, -0.5, 0.0)  # Case 1: the port faces -y
    assert [quadrant(p, port) for p in ((100, -1000, 0), (-100, -1000, 0), (-100, 1000, 0), (100, 1000, 0))] == [1, 2, 3, 4]
    # the same geometry turned by +90 deg about z, (x, y) -> (-y, x): the same quadrants
    turn = lambda p: (-p[1], p[0], p[2])  # noqa: E731
    starts = ((100, -1000, 0), (-100, -1000, 0), (-100, 1000, 0), (100, 1000, 0))
    assert [quadrant(turn(p), turn(port)) for p in starts] == [1, 2, 3, 4]


def test_safety_metrics_tolerate_records_without_a_monitor_and_read_one_when_present():
    none = safety({}, None)
    assert none["safety_verdict"] is None and np.isnan(none["safety_violations"])
    got = safety({"safety": {"verdict": "unsafe", "violations": {"keepout": 2, "overshoot": [{"t": 1}, {"t": 2}, {"t": 3}],
                                                                 "collision": 0}}}, None)
    assert got["safety_verdict"] == "unsafe" and got["safety_violations"] == 5.0
    assert got["safety.keepout"] == 2 and got["safety.overshoot"] == 3
    assert safety({"safety": {"safe": True, "violation_count": 0}}, None)["safety_verdict"] == "safe"
    # the shape of host_sim's truth-based monitor: a total and per-limit statistics
    monitor = safety({"safety": {"verdict": "unsafe", "violations": 3, "per_limit": {
        "keepout": {"violations": 1, "worst": 0.4}, "approach_corridor": {"violations": 2, "worst": 3.0}}}}, None)
    assert monitor["safety_violations"] == 3 and monitor["safety.approach_corridor"] == 2


# ---- the fast path against the native PIL run ------------------------------------------------------
def _records_identical(a: Path, b: Path) -> list[str]:
    """What differs between two records, timing and self-description aside."""
    diffs = []
    ma, sa = load_run(a)
    mb, sb = load_run(b)
    if list(sa.columns) != list(sb.columns) or len(sa) != len(sb):
        return [f"shape {sa.shape} vs {sb.shape}"]
    for c in sa.columns:
        if c in TIMING_COLUMNS:
            continue
        x, y = sa[c].to_numpy(), sb[c].to_numpy()
        same = np.array_equal(x, y, equal_nan=True) if x.dtype.kind == "f" else bool((x == y).all())
        if not same:
            diffs.append(f"steps.csv {c}")
    ea, eb = load_events(a), load_events(b)
    pick = lambda e: [(k, d) for k, d in zip(e["kind"], e["detail"]) if k != "hello"]  # noqa: E731
    if pick(ea) != pick(eb):
        diffs.append(f"events {pick(ea)} vs {pick(eb)}")
    for k in ("end", "docked", "steps", "t_end_s", "dv_total_mps", "dv_l1_mps", "dv_per_phase_mps", "time_per_phase_s",
              "final_range_to_port_m", "nav_resends", "late_commands", "rejected_messages", "scenario", "seed", "options"):
        if ma.get(k) != mb.get(k):
            diffs.append(f"meta {k}: {ma.get(k)} vs {mb.get(k)}")
    for k in ("horizon", "period_s", "deadline_fraction", "solver_mode", "solver_max_iter"):
        if ma["flight_hello"][k] != mb["flight_hello"][k]:
            diffs.append(f"hello {k}")
    return diffs


def test_fast_path_and_native_pil_give_bit_identical_records_with_noise_and_the_nonlinear_truth(tmp_path, flight_exe):
    study = write_study(tmp_path / "fast_vs_native.toml", """
        [study]
        name = "fast_vs_native"
        [model]
        truth = "nonlinear"
        sensor_noise = true
        thrust_noise = true
        impulsive = false
        [scenarios]
        names = ["case1_vbar"]
        random = { first = 11, count = 1 }
        [noise]
        first_seed = 5
        [guidance]
        rendezvous = { N = 20 }
        approach = { Ts_s = 15.0 }
        keepout_radius_m = 190.0
        [[sweep]]
        name = "fast"
        execution = { mode = "in-process" }
        [[sweep]]
        name = "native"
        execution = { mode = "native" }
    """)
    res = run_study(study, jobs=2, out=tmp_path / "out", progress=False, write_report=False, say=lambda s: None)
    assert res.complete and res.total == 4
    runs = res.runs
    for label in ("case1_vbar", "random:11"):
        fast = runs[(runs["sweep"] == "fast") & (runs["scenario"] == label)]["key"].item()
        native = runs[(runs["sweep"] == "native") & (runs["scenario"] == label)]["key"].item()
        a, b = res.out / "runs" / fast, res.out / "runs" / native
        ma, _ = load_run(a)
        mb, _ = load_run(b)
        assert ma["flight_command"][0] == "in-process" and "rvd_flight_sw" in mb["flight_command"][0]
        assert ma["steps"] > 50 and ma["dv_total_mps"] > 1.0  # a real run with burns and noise
        assert _records_identical(a, b) == []
    # and the metrics the studies aggregate agree too
    cols = [c for c in deterministic(runs).columns if c not in ("key", "sweep", "mode")]
    f = runs[runs["sweep"] == "fast"][cols].reset_index(drop=True)
    n = runs[runs["sweep"] == "native"][cols].reset_index(drop=True)
    assert frames_equal(f, n)


# ---- executors agree ------------------------------------------------------------------------------
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture()
def dask_cluster(tmp_path):
    """`dask scheduler` and two `dask worker` processes on 127.0.0.1 (one thread each)."""
    from distributed import Client

    dask = str(Path(sys.executable).with_name("dask"))
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "RVD_STUDY_CACHE": str(tmp_path / "worker-cache")}
    logs = tmp_path / "dask-logs"
    logs.mkdir()
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                              stdout=open(logs / "scheduler.log", "w"), stderr=subprocess.STDOUT, env=env,
                              cwd=tmp_path)]
    try:
        for i in range(2):
            wdir = tmp_path / f"worker{i}"
            wdir.mkdir()
            procs.append(subprocess.Popen(
                [dask, "worker", address, "--nthreads", "1", "--nworkers", "1", "--no-dashboard",
                 "--local-directory", str(wdir), "--name", f"w{i}"],
                stdout=open(logs / f"worker{i}.log", "w"), stderr=subprocess.STDOUT, env=env, cwd=wdir))
        client = Client(address, timeout="60s")
        client.wait_for_workers(2, timeout=120)
        client.close()
        yield address, tmp_path / "worker-cache"
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def test_jobs_1_jobs_2_and_a_dask_cluster_give_identical_aggregates(tmp_path, flight_exe, dask_cluster):
    address, worker_cache = dask_cluster
    study = write_study(tmp_path / "agree.toml", """
        [study]
        name = "agree"
        [execution]
        mode = "native"
        [scenarios]
        names = ["case1_vbar", "case2_rbar"]
        random = { first = 3, count = 1 }
        [report]
        kind = "sensitivity"
        [[sweep]]
        name = "initial"
        [[sweep]]
        name = "rendezvous"
        vary."guidance.rendezvous.N" = [15, 30]
    """ + IDEAL)
    results = {}
    for label, kw in (("jobs1", {"jobs": 1}), ("jobs2", {"jobs": 2}), ("dask", {"dask": address})):
        results[label] = run_study(study, out=tmp_path / label, progress=False, say=lambda s: None, **kw)
        assert results[label].complete and results[label].total == 6
        assert (tmp_path / label / "report" / "report.html").is_file()
    ref = results["jobs1"]
    assert ref.runs["docked"].all()
    for label in ("jobs2", "dask"):
        r = results[label]
        assert frames_equal(deterministic(r.runs), deterministic(ref.runs)), label
        assert frames_equal(r.summary, ref.summary), label
        assert set(r.tables) == set(ref.tables)
        for name in ref.tables:
            assert frames_equal(r.tables[name], ref.tables[name]), (label, name)
    # the Dask workers got the flight executable through Dask (into their own cache), not by path
    cached = list(worker_cache.rglob("rvd_flight_sw"))
    assert cached and all(os.access(p, os.X_OK) for p in cached)
    flight_cmds = {json.loads((p / "meta.json").read_text())["flight_command"][0]
                   for p in (tmp_path / "dask" / "runs").iterdir()}
    assert flight_cmds and all(c.startswith(str(worker_cache)) for c in flight_cmds)


# ---- output folders belong to one study and grid ----------------------------------------------------
def test_another_study_or_grid_into_the_same_folder_is_refused(tmp_path):
    body = """
        [study]
        name = "own"
        [scenarios]
        names = ["case1_vbar"]
        [[sweep]]
        name = "a"
        vary."guidance.docking.N" = [5]
    """ + IDEAL
    a = write_study(tmp_path / "a.toml", body)
    out = tmp_path / "out"
    first = run_study(a, out=out, jobs=1, progress=False, say=lambda s: None)
    assert first.complete
    before = sorted(p.name for p in (out / "runs").iterdir())
    b = write_study(tmp_path / "b.toml", body.replace("[5]", "[5, 12]"))
    with pytest.raises(OwnershipError, match="another grid"):
        run_study(b, out=out, jobs=1, progress=False, say=lambda s: None)
    c = write_study(tmp_path / "c.toml", body.replace('"own"', '"other"'))
    r = cli(c, "--out", out)
    assert r.returncode == 2 and "belongs to study 'own'" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert sorted(p.name for p in (out / "runs").iterdir()) == before
    again = run_study(a, out=out, jobs=1, progress=False, say=lambda s: None)  # the same study resumes: nothing to do
    assert again.outcome is None and frames_equal(deterministic(again.runs), deterministic(first.runs))
    # a report of what is stored, matched by content, needs no ownership of the grid and computes nothing
    partial = report_study(b, out=out, say=lambda s: None)
    assert (partial.total, partial.finished, len(partial.runs)) == (2, 1, 1)
    assert frames_equal(deterministic(partial.runs), deterministic(first.runs))
    assert sorted(p.name for p in (out / "runs").iterdir()) == before
    r = cli(a, "--out", out, "--report-only")
    assert r.returncode == 0 and "report:" in r.stdout, r.stderr


# ---- interrupted and resumed ------------------------------------------------------------------------
def _stored(out: Path) -> int:
    ledger = out / "ledger.jsonl"
    return ledger.read_text().count('"event": "stored"') if ledger.exists() else 0


def test_interrupted_three_times_sigint_and_sigkill_then_resumed_gives_the_uninterrupted_aggregate(tmp_path):
    study = write_study(tmp_path / "resume.toml", """
        [study]
        name = "resume"
        [execution]
        mode = "native"
        [scenarios]
        random = { first = 20, count = 8 }
        [report]
        kind = "sensitivity"
        [[sweep]]
        name = "initial"
        [[sweep]]
        name = "docking"
        vary."guidance.docking.N" = [5, 12]
        vary."guidance.docking.Ts_s" = [3.0, 5.0]
    """ + IDEAL)
    total = grid.distinct_runs(grid.expand(spec.load(study)))
    assert total == 32
    out = tmp_path / "interrupted"
    rng = random.Random(20261201)
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    for sig in (signal.SIGINT, signal.SIGKILL, signal.SIGINT):
        target = _stored(out) + rng.randint(1, 4)
        proc = subprocess.Popen([*RVD_STUDY, str(study), "--out", str(out), "--jobs", "2", "--no-progress"],
                                cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 300
        while _stored(out) < target and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        if sig == signal.SIGKILL:  # while one works there (here: stopped), a second rvd-study is refused
            proc.send_signal(signal.SIGSTOP)
            second = cli(study, "--out", out, "--jobs", "1")
            assert second.returncode == 2 and "in use by another rvd-study" in second.stderr, second.stderr
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=300)
        if sig == signal.SIGINT:
            assert proc.returncode == 130, err
            assert "run the same command again" in err
        else:
            assert proc.returncode == -signal.SIGKILL
    stopped_at = _stored(out)
    assert 0 < stopped_at < total
    r = cli(study, "--out", out, "--jobs", "2")
    assert r.returncode == 0, r.stderr
    ref = run_study(study, out=tmp_path / "straight", jobs=2, progress=False, say=lambda s: None)
    res = run_study(study, out=out, jobs=2, progress=False, say=lambda s: None)  # nothing left: reads only
    assert res.outcome is None and res.complete
    assert frames_equal(deterministic(res.runs), deterministic(ref.runs))
    assert frames_equal(res.summary, ref.summary)
    for name in ref.tables:
        assert frames_equal(res.tables[name], ref.tables[name]), name
    # no run computed twice: every run stored once, none refused as a duplicate, nothing half-written left
    entries = [json.loads(line) for line in (out / "ledger.jsonl").read_text().splitlines()]
    stored = [e["key"] for e in entries if e["event"] == "stored"]
    assert len(stored) == len(set(stored)) <= total
    assert not [e for e in entries if e["event"] in ("duplicate", "failed")]
    assert len(list((out / "runs").iterdir())) == total
    assert not (out / ".incoming").exists() or not any((out / ".incoming").iterdir())


# ---- the report kinds on real records -------------------------------------------------------------
def test_qemu_user_study_counts_instructions_that_repeat_and_reports_timing(tmp_path):
    study = write_study(tmp_path / "qemu.toml", """
        [study]
        name = "qemu_tiny"
        [execution]
        mode = "qemu-user"
        targets = ["q7s"]
        repeat = 2
        [scenarios]
        names = ["case1_vbar"]
        [guidance]
        rendezvous = { N = 15 }
        [report]
        kind = "timing"
    """ + IDEAL)
    res = run_study(study, out=tmp_path / "out", jobs=2, progress=False, say=lambda s: None)
    assert res.complete and res.total == 2 and res.runs["docked"].all()
    s = res.solves
    assert len(s) > 50 and (s["instructions"] > 0).all()
    # estimated target time = instructions x CPI / f_clk of the registry's Cortex-A9 model
    from rvd_pil.qemu import targets

    t = targets.load("q7s")
    np.testing.assert_allclose(s["target_us_nominal"], s["instructions"] * t.cpi.nominal / t.clock_hz * 1e6, rtol=1e-12)
    stats = res.tables["solve_stats"]
    assert set(stats["phase"]) == {"rendezvous", "approach", "docking"}
    assert stats.loc[stats["phase"] == "rendezvous", "N"].tolist() == [15]
    check = res.tables["repeat_checks"]
    assert check["trajectory_identical"].all() and check["instructions_identical"].all()
    assert (res.out / "report" / "solves.parquet").is_file() and (res.out / "report" / "timing_solve_wall.csv").is_file()


def test_robustness_report_spreads_are_the_per_start_standard_deviations(tmp_path):
    study = write_study(tmp_path / "robust.toml", """
        [study]
        name = "robust_tiny"
        [model]
        truth = "cw"
        sensor_noise = true
        thrust_noise = true
        impulsive = false
        [scenarios]
        random = { first = 30, count = 2 }
        [noise]
        repeats = 3
        [report]
        kind = "robustness"
    """)
    res = run_study(study, out=tmp_path / "out", jobs=2, progress=False, say=lambda s: None)
    runs, per = res.runs, res.tables["per_start"]
    assert res.complete and len(runs) == 6 and len(per) == 2
    for _, row in per.iterrows():
        g = runs[(runs["start_id"] == row["start_id"]) & runs["docked"]]
        assert row["dv_std_mps"] == pytest.approx(np.std(g["dv_total_mps"].to_numpy(), ddof=1), rel=1e-12)
        assert row["t_f_std_min"] == pytest.approx(np.std(g["t_f_s"].to_numpy() / 60.0, ddof=1), rel=1e-12)
    assert runs.groupby("start_id")["dv_total_mps"].nunique().min() == 3  # the noise seeds differ
    overall = res.tables["overall"].iloc[0]
    assert overall["mean_of_per_start_dv_std_mps"] == pytest.approx(per["dv_std_mps"].mean())
    assert overall["dissertation_dv_std_mps"] == 4.25
    # safety: what the records' safety entries say (NaN where no monitor wrote one)
    metas = [json.loads((res.out / "runs" / k / "meta.json").read_text()) for k in runs["key"]]
    if any("safety" in m for m in metas):
        assert overall["safety_violations"] == sum(m["safety"]["violations"] for m in metas)
        assert overall["runs_with_safety_entry"] == 6
    else:
        assert np.isnan(overall["safety_violations"]) and overall["runs_with_safety_entry"] == 0
    for fig in ("mean_dv_tf.png", "spread.png", "success.png", "safety.png"):
        assert (res.out / "report" / fig).stat().st_size > 1000


def test_an_in_process_run_hands_over_the_qp_each_step_solved(tmp_path):
    """run_in_process(on_answer=...) calls back after each answered step with the flight application:
    its built-in guidance's last QP of the step's phase, solved afresh (cold, by solve_ocp_qp), gives
    the delta-v the step commanded (the record's dv_cmd), in every phase of a noisy run with the
    nonlinear truth. The application flies the built-in MPC from its start: its guidance is there before
    the first step."""
    from rvd_pil import flight_sw
    from rvd_pil.host_sim.scenario import load
    from rvd_pil.studies.inprocess import run_in_process
    from rvd_pil.studies.settings import GuidanceSettings

    seen = []

    def on_answer(step, app):
        g = app.guidance
        if g.phase in (flight_sw.Phase.Rendezvous, flight_sw.Phase.Approach, flight_sw.Phase.Docking):
            seen.append((step, g.phase, g.last_qp(g.phase)))

    summary, run_dir = run_in_process(load("case1_vbar"), GuidanceSettings.from_table({}), seed=2, truth="nonlinear",
                                      run_dir=tmp_path / "run", on_answer=on_answer)
    assert summary.docked
    steps = pd.read_csv(run_dir / "steps.csv").set_index("step")
    checked, next_step_alike = {}, 0
    for step, phase, qp in seen:
        row = steps.loc[step]
        if row["guidance_status"] != 0:  # (a recovered step flew the recovery QP)
            continue
        res = flight_sw.solve_ocp_qp(**qp)
        assert res.status == "solved", step
        box = np.asarray(qp["d"][0])[:6]  # stage 0's input bounds, u <= box[:3] and -u <= box[3:]
        dv = np.clip(np.asarray(res.u[0])[:3], -box[3:], box[:3])  # (as the guidance clips its plan)
        flown = row[["dv_cmd_x_mps", "dv_cmd_y_mps", "dv_cmd_z_mps"]].to_numpy(float)
        # the flight solved it warm, this solve is cold: both to the solver's tolerance (0.1 mm/s is
        # under a third of the thrusters' minimum impulse bit)
        assert np.abs(dv - flown).max() <= 1e-4, (step, dv, flown)
        checked[phase] = checked.get(phase, 0) + 1
        if step + 1 in steps.index:  # the check tells steps apart: the next step's delta-v is another
            after = steps.loc[step + 1, ["dv_cmd_x_mps", "dv_cmd_y_mps", "dv_cmd_z_mps"]].to_numpy(float)
            next_step_alike += int(np.abs(dv - after).max() <= 1e-4)
    assert len(checked) == 3 and min(checked.values()) >= 10, checked
    assert next_step_alike < 0.4 * sum(checked.values()), next_step_alike  # (coasting steps alike: 27 %)
    app = flight_sw.FlightApp(["--run", "r"])
    assert app.guidance is not None and app.guidance.phase == flight_sw.Phase.Rendezvous
