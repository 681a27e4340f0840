"""The flight clock on target time: the counting plugin answers the flight software's clock reads
(marker op 3) with the guest's instruction count, and the flight takes its deadlines on
instructions x CPI / f_clk instead of the host's clock (flight_sw/solver/elapsed.hpp).

Independent truths: the probe's loop has exactly two instructions per iteration (as in
test_qemu_plugin.py), so two clock readings around loops of k and k' iterations differ by exactly
2(k' - k) between the two; the plugin's own marker counts bracket the readings. For the flight: a
budget no host can meet under emulation (1e-6 x Ts = 30 us) overruns on the host clock at every
step, and never on a target clock that prices an instruction at a femtosecond (CPI 1 at 1e15 Hz:
a 10-million-instruction step is 0.01 us), whatever the host's speed.
"""
from __future__ import annotations

import math
import re

import pytest

from rvd_pil.host_sim.pil import run_pil
from rvd_pil.host_sim.record import load_run
from rvd_pil.host_sim.server import ServerConfig
from rvd_pil.qemu import build, plugin, user
from rvd_pil.qemu.plugin import InsnCounter
from support.user_mode import counting_plugin_or_skip, cross_target_or_skip

pytestmark = pytest.mark.qemu

IDEAL = dict(truth="cw", sensor_noise=False, thrust_noise=False, impulsive=True)
HOST_CLOCK, TARGET_CLOCK, UNANSWERED = 0, 1, 2  # hello/telemetry step_clock


@pytest.fixture(scope="module")
def plugin_lib():
    return counting_plugin_or_skip()


@pytest.fixture(scope="module", params=["q7s", "rpi3"])
def target(request):
    return cross_target_or_skip(request.param)


def _clock_lines(stdout):
    return [{k: float(v) if k == "us" else int(v) for k, v in re.findall(r"(\w+)=(\S+)", line)}
            for line in stdout.splitlines() if line.startswith("clock ")]


def test_plugin_answers_the_clock_with_the_instruction_count(plugin_lib, target, tmp_path):
    exe = build.cross_build(target, "qemu_probe").path
    cpi, hz = 2.0, 766e6
    k1, k2 = 10_000, 30_000
    log = tmp_path / "counts.log"
    # "markers 1 10" first: the marker's one-off probe of the plugin stays out of the clock regions.
    proc = user.run(target, exe, ["markers", "1", "10", "target-clock", repr(cpi), repr(hz),
                                  "clock", str(k1), "clock", str(k2)],
                    plugin=InsnCounter(log=log, library=plugin_lib), timeout_s=120)
    assert proc.returncode == 0, proc.stderr
    assert f"target-clock source={TARGET_CLOCK}" in proc.stdout
    a, b = _clock_lines(proc.stdout)
    assert a["source"] == b["source"] == TARGET_CLOCK
    # Monotonic: every reading above the one before, across the two regions too.
    assert a["t0"] < a["t1"] < b["t0"] < b["t1"]
    # Exact: the readings' difference is the loop's 2k instructions plus the same constant (the
    # second reading's own instructions) in both regions.
    da, db = a["t1"] - a["t0"], b["t1"] - b["t0"]
    assert db - da == 2 * (k2 - k1)
    assert 0 < da - 2 * k1 < 200
    # The marker count of the region brackets both readings: it is the readings' span plus the
    # same few instructions of the markers and the first reading in both regions, and the plugin's
    # log has the counts the guest printed.
    assert a["insns"] - da == b["insns"] - db > 0
    assert plugin.read_log(log)[1:] == [(a["step"], a["insns"]), (b["step"], b["insns"])]
    assert "clock reads 5, slot mismatches 0" in log.read_text()  # use_target's probe, then 2 per region
    # elapsed = instructions x CPI / f_clk
    assert a["us"] == pytest.approx(da * cpi / hz * 1e6, rel=1e-12)


def test_without_the_plugin_the_clock_stays_on_the_host_and_says_so(target):
    exe = build.cross_build(target, "qemu_probe").path
    proc = user.run(target, exe, ["target-clock", "2", "766e6", "clock", "1000"], timeout_s=120)
    assert proc.returncode == 0, proc.stderr
    assert f"target-clock source={UNANSWERED}" in proc.stdout
    (a,) = _clock_lines(proc.stdout)
    assert a["source"] == UNANSWERED and a["insns"] == 0  # no plugin: no count either
    assert a["us"] == pytest.approx((a["t1"] - a["t0"]) / 1e3, rel=1e-12)  # nanoseconds of steady_clock


def _flight_run(tmp_path, name, target, plugin_lib, clock_args):
    exe = build.cross_build(target).path
    counter = InsnCounter(log=tmp_path / f"{name}.insns", library=plugin_lib)
    cfg = ServerConfig(max_steps=4, hello_timeout_s=180.0, cmd_timeout_s=120.0)
    summary, run_dir = run_pil(
        "case1_vbar", **IDEAL, config=cfg, run_dir=tmp_path / name,
        flight_command=lambda args: user.command(target, exe, [*args, *clock_args], plugin=counter),
        flight_args=["--deadline-fraction", "1e-6"])
    _, steps = load_run(run_dir)
    return summary, steps


def test_deadline_is_taken_on_target_time_not_host_time(plugin_lib, target, tmp_path):
    # Control: on the host's clock a 30 us budget overruns at every step under emulation.
    host, host_steps = _flight_run(tmp_path, "host-clock", target, plugin_lib, [])
    assert host.hello.step_clock == HOST_CLOCK
    assert len(host_steps) == 4 and (host_steps["overrun"] == 1).all()
    # The same steps priced at CPI 1 and 1e15 Hz: well inside the budget, whatever the host took.
    tgt, steps = _flight_run(tmp_path, "target-clock", target, plugin_lib, user.target_clock_args(1.0, 1e15))
    assert tgt.hello.step_clock == TARGET_CLOCK and tgt.telemetry.step_clock == TARGET_CLOCK
    assert len(steps) == 4
    assert (steps["overrun"] == 0).all() and (steps["overruns"] == 0).all()
    assert set(steps["solver_status"]) == {0} and set(steps["guidance_status"]) == {0}  # solved, ok
    # The reported times are target time: the step covers at least its counted solves, and
    # (a few thousand instructions of harness around them) far less than the host took.
    assert (steps["step_time_us"] * 1e-6 >= steps["instructions"] * 1.0 / 1e15).all()
    assert (steps["step_time_us"] * 1e-6 <= 2 * steps["instructions"] * 1.0 / 1e15).all()
    assert (steps["solve_time_us"] <= steps["step_time_us"]).all()
    assert "flight_deadline_fraction" not in tgt.host_speed_dependent


def test_native_run_falls_back_to_the_host_clock_and_says_so(tmp_path, flight_exe):
    summary, run_dir = run_pil("case1_vbar", **IDEAL, config=ServerConfig(max_steps=3), run_dir=tmp_path / "native",
                               flight_exe=str(flight_exe), flight_args=["--target-clock", "2,766e6"])
    assert summary.end == "step limit"
    assert summary.hello.step_clock == UNANSWERED and summary.telemetry.step_clock == UNANSWERED
    assert "no instruction-counting plugin answered" in (run_dir / "flight_sw.log").read_text()
    _, steps = load_run(run_dir)
    assert (steps["overrun"] == 0).all() and set(steps["guidance_status"]) == {0}
    assert all(math.isfinite(v) and v > 0 for v in steps["step_time_us"])
    assert "flight_deadline_fraction" in summary.host_speed_dependent  # the host's clock decides
