"""Faulty plug-in guidance laws (tests/guidance_laws/faulty): a law that returns NaN, an out-of-limit
delta-v, crashes, overruns its budget, allocates in its step, blocks past its period or returns an
error. Each time the harness keeps running, records what happened (a law_fault event, the cmd's
guidance status law_fault) and commands zero thrust; the run goes on to its end (here the scenario's
timeout), the flight process leaves cleanly.

Independent truth: before the fault the law commands half the radial limit, so the pulses the truth
applied are non-zero exactly until the fault's step; from then on nothing fires.
"""
from pathlib import Path

import numpy as np
import pytest

from rvd_pil.host_sim import scenario as scenarios
from rvd_pil.host_sim.guidance_build import LawBuildError, build_native, load_manifest
from rvd_pil.host_sim.pil import run_pil
from rvd_pil.host_sim.record import load_events, load_run
from rvd_pil.host_sim.server import ServerConfig

ROOT = Path(__file__).resolve().parent.parent
LAW = ROOT / "tests" / "guidance_laws" / "faulty"
IDEAL = dict(truth="cw", sensor_noise=False, thrust_noise=False, impulsive=True)
FROM_STEP = 3


@pytest.fixture(scope="module")
def faulty_exe():
    exe, _ = build_native(LAW)
    return exe


def _run(tmp_path, exe, fault, extra=()):
    sc = scenarios.load("case1_vbar").replace(timeout_s=300.0)
    args = ["--set", f"law.fault={fault}", "--set", f"law.from_step={FROM_STEP}", *extra]
    return run_pil(sc, **IDEAL, flight_exe=str(exe), flight_args=args, config=ServerConfig(delay_model="none"),
                   run_dir=tmp_path / f"fault{fault}")


@pytest.mark.parametrize("fault, text, extra, disabled", [
    (1, "NaN or Inf", (), False),
    (2, "outside the phase's limits", (), False),
    (3, "crashed", (), True),
    (4, "after its budget", ("--deadline-fraction", "0.001"), False),
    (5, "allocated heap memory", (), False),
    (6, "still running at the end of its period", ("--period", "0.5,0.5,0.5"), True),
    (7, "returned an error", (), False),
])
def test_a_faulty_law_gets_zero_thrust_and_the_run_goes_on(tmp_path, faulty_exe, fault, text, extra, disabled):
    summary, run_dir = _run(tmp_path, faulty_exe, fault, extra)
    assert summary.end == "timeout", summary.end
    meta, steps = load_run(run_dir)
    assert meta["flight_exit_code"] == 0
    assert meta["flight_config"]["law"] == "test_faulty"
    pulses = steps[[c for c in steps.columns if c.startswith("pulse_applied_")]].to_numpy()
    status = steps["guidance_status"].to_numpy()
    assert (pulses[:FROM_STEP].sum(axis=1) > 0).all() and (status[:FROM_STEP] == 0).all()
    assert (pulses[FROM_STEP:] == 0).all() and (status[FROM_STEP:len(steps) - 1] == 6).all()
    events = load_events(run_dir)
    faults = events[events["kind"] == "law_fault"]
    assert len(faults) >= 1 and text in faults["detail"].iloc[0]
    assert int(faults["step"].iloc[0]) == FROM_STEP
    if disabled:  # the law is never called again
        assert "law disabled" in faults["detail"].iloc[-1]
    assert meta["law_faults"] >= len(steps) - 1 - FROM_STEP


def test_the_harness_without_faults_flies_the_law(tmp_path, faulty_exe):
    summary, run_dir = _run(tmp_path, faulty_exe, 0)
    _, steps = load_run(run_dir)
    assert summary.end == "timeout" and (steps["guidance_status"].iloc[:-1] == 0).all()
    assert "law_fault" not in set(load_events(run_dir)["kind"])


def test_a_law_folder_that_does_not_build_is_one_line_naming_its_manifest(tmp_path):
    (tmp_path / "law.toml").write_text('name = "broken"\nsources = ["broken.c"]\n')
    (tmp_path / "broken.c").write_text("this is not C\n")
    with pytest.raises(LawBuildError) as e:
        build_native(tmp_path)
    assert str(tmp_path / "law.toml") in str(e.value) and "\n" not in str(e.value)
    # ... and it does not stay in the build tree, whose other targets still configure and build.
    assert not (ROOT / "build" / "native" / "guidance" / "broken.cmake").exists()
    (tmp_path / "law.toml").write_text('name = "broken"\nsource = ["broken.c"]\n')
    with pytest.raises(LawBuildError, match="unknown key.*source"):
        load_manifest(tmp_path)
