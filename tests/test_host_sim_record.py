"""Acceptance 5: run records survive SIGKILL; plus the record format's contract (exact floats,
extra columns, events, torn lines, refusing to overwrite)."""

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rvd_pil.host_sim.record import HOST_DIED, STEP_COLUMNS, RunRecorder, load_events, load_run
from rvd_pil.host_sim.simulator import Simulator

REPO = Path(__file__).resolve().parents[1]

# The child logs a deterministic closed loop forever (a real run never knows when it is killed).
CHILD = r"""
import sys
import numpy as np
from rvd_pil.host_sim.simulator import Simulator
from rvd_pil.host_sim.record import RunRecorder
sim = Simulator("case1_vbar", truth="nonlinear", seed=42)
rec = RunRecorder(sys.argv[1], {"scenario": "case1_vbar", "seed": 42}, extra_columns=["solve_time_us", "note"])
rng = np.random.default_rng(1)
k = 0
while True:
    m = sim.measure()
    r = sim.apply_command(rng.uniform(0.0, 1.0, 6), 5.0, delay_s=0.1)
    rec.log_step(m, r, target=sim.target_state(m.t_s), solve_time_us=1000.0 + k, note=f"step {k}, ok")
    print(k, flush=True)
    k += 1
"""


def replay(steps):
    """The same loop in this process, for comparison with what the killed child wrote."""
    sim = Simulator("case1_vbar", truth="nonlinear", seed=42)
    rng = np.random.default_rng(1)
    rows = []
    for _ in range(steps):
        m = sim.measure()
        r = sim.apply_command(rng.uniform(0.0, 1.0, 6), 5.0, delay_s=0.1)
        rows.append(np.concatenate((r.truth_before, m.state, r.pulse_commanded_s, r.thrust_error_percent,
                                    r.truth_after)))
    return np.array(rows)


def test_sigkill_midway_keeps_every_completed_step(tmp_path):
    run_dir = tmp_path / "run"
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(run_dir)], cwd=REPO, env=env,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        last_reported = -1
        while last_reported < 40:  # the child reports a step after its line is written
            line = child.stdout.readline()
            assert line, f"child ended early: {child.stderr.read()}"
            last_reported = int(line)
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=30)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
        child.stdout.close()
        child.stderr.close()
    assert child.returncode == -signal.SIGKILL

    meta, df = load_run(run_dir)
    # Never closed, and its writer is gone: the next read says so, on disk too.
    assert meta["status"] == HOST_DIED
    assert f"pid {child.pid}" in meta["host_died"]["reason"]
    assert meta["host_died"]["steps_recorded"] == len(df)
    assert json.loads((run_dir / "meta.json").read_text())["status"] == HOST_DIED
    assert meta["seed"] == 42 and meta["extra_columns"] == ["solve_time_us", "note"]
    assert len(df) >= last_reported + 1
    assert df["step"].tolist() == list(range(len(df)))
    assert df["note"].iloc[-1] == f"step {len(df) - 1}, ok"
    assert df["solve_time_us"].tolist() == [1000.0 + i for i in range(len(df))]
    # Every logged value is the exact double the simulation produced.
    expected = replay(len(df))
    cols = ([f"truth_{s}" for s in ("x_m", "y_m", "z_m", "vx_mps", "vy_mps", "vz_mps")]
            + [f"meas_{s}" for s in ("x_m", "y_m", "z_m", "vx_mps", "vy_mps", "vz_mps")]
            + [f"pulse_cmd_{t}_s" for t in ("px", "mx", "py", "my", "pz", "mz")]
            + [f"thrust_error_{t}_pct" for t in ("px", "mx", "py", "my", "pz", "mz")]
            + [f"after_{s}" for s in ("x_m", "y_m", "z_m", "vx_mps", "vy_mps", "vz_mps")])
    np.testing.assert_array_equal(df[cols].to_numpy(), expected)


def test_torn_last_line_is_dropped(tmp_path):
    sim = Simulator("case2_rbar", seed=3)
    rec = RunRecorder(tmp_path / "run", {"seed": 3})
    for _ in range(5):
        m = sim.measure()
        rec.log_step(m, sim.apply_command(np.full(6, 0.2), 20.0))
    # simulate a kill in the middle of the 6th write
    path = tmp_path / "run" / "steps.csv"
    with open(path, "ab") as f:
        f.write(b"5,100.0,20.0,0.0,12.5,-3")
    _, df = load_run(tmp_path / "run")
    assert len(df) == 5 and df.attrs["torn_tail_bytes"] == len(b"5,100.0,20.0,0.0,12.5,-3")
    assert df["step"].tolist() == [0, 1, 2, 3, 4]


def test_floats_extra_columns_and_events_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    values = rng.standard_normal(500) * 10.0 ** rng.integers(-30, 30, 500)
    values[:3] = [0.1, 1 / 3, -2.5e-308]
    with RunRecorder(tmp_path / "run", {"campaign": "unit", "cpu": "cortex-a53"},
                     extra_columns=["value", "status"]) as rec:
        for i, v in enumerate(values):
            rec.write_row({"step": i, "t_s": i * 0.5, "value": v, "status": "ok" if i % 2 else "max_iter"})
        rec.log_event("flight_software_lost", 'no cmd for step 7 within 5 s, "retrying"', step=7, t_s=3.5)
        rec.log_event("reconnected")
    meta, df = load_run(tmp_path / "run")
    assert meta["status"] == "finished" and meta["steps_written"] == 500 and meta["cpu"] == "cortex-a53"
    assert list(df.columns) == list(STEP_COLUMNS) + ["value", "status"]
    np.testing.assert_array_equal(df["value"].to_numpy(), values)  # bit-exact
    assert df["status"].iloc[0] == "max_iter" and np.isnan(df["truth_x_m"].iloc[0])
    events = load_events(tmp_path / "run")
    assert events["kind"].tolist() == ["flight_software_lost", "reconnected"]
    assert events["detail"].iloc[0] == 'no cmd for step 7 within 5 s, "retrying"'
    assert events["step"].iloc[0] == 7 and np.isnan(events["step"].iloc[1])


def test_step_without_a_command_records_truth_and_measurement(tmp_path):
    sim = Simulator("case1_vbar", seed=1)
    with RunRecorder(tmp_path / "run") as rec:
        m = sim.measure()
        rec.log_step(m, None, truth_lvlh=sim.truth_lvlh(), target=sim.target_state())
        rec.log_event("flight_software_lost", "no cmd", step=m.step, t_s=m.t_s)
    _, df = load_run(tmp_path / "run")
    assert df["truth_y_m"].iloc[0] == -1580.0
    assert df["range_com_m"].iloc[0] == pytest.approx(np.sqrt(140.0**2 + 1580.0**2 + 60.0**2), rel=1e-15)
    assert np.isnan(df["pulse_cmd_px_s"].iloc[0]) and np.isnan(df["after_x_m"].iloc[0])


def test_recorder_refuses_bad_use(tmp_path):
    RunRecorder(tmp_path / "run").close()
    with pytest.raises(FileExistsError):
        RunRecorder(tmp_path / "run")  # never overwrites a record
    with pytest.raises(ValueError, match="clashing"):
        RunRecorder(tmp_path / "b", extra_columns=["t_s"])
    with pytest.raises(ValueError, match="set by the recorder"):
        RunRecorder(tmp_path / "c", {"status": "x"})
    with RunRecorder(tmp_path / "d", extra_columns=["iterations"]) as rec:
        with pytest.raises(ValueError, match="unknown column"):
            rec.write_row({"step": 0, "iters": 3})
    with pytest.raises(FileNotFoundError):
        load_run(tmp_path / "nowhere")


def test_failed_run_is_marked(tmp_path):
    with pytest.raises(RuntimeError):
        with RunRecorder(tmp_path / "run") as rec:
            rec.write_row({"step": 0})
            raise RuntimeError("flight software crashed")
    meta = json.loads((tmp_path / "run" / "meta.json").read_text())
    assert meta["status"] == "failed" and "flight software crashed" in meta["error"]
    _, df = load_run(tmp_path / "run")
    assert len(df) == 1


def test_a_record_whose_writer_lives_stays_running_and_one_from_elsewhere_gets_a_note(tmp_path):
    rec = RunRecorder(tmp_path / "live", {"seed": 1})
    assert load_run(tmp_path / "live")[0]["status"] == "running"  # this process writes it
    rec.close()
    assert load_run(tmp_path / "live")[0]["status"] == "finished"
    other = RunRecorder(tmp_path / "other", {"seed": 2})
    meta = json.loads((tmp_path / "other" / "meta.json").read_text())
    meta["writer"]["hostname"] = "another-machine"
    (tmp_path / "other" / "meta.json").write_text(json.dumps(meta))
    seen = load_run(tmp_path / "other")[0]  # as if copied from another machine while running
    assert seen["status"] == "running" and "cannot be told" in seen["status_note"]
    other.close()
