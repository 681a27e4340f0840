"""rvd-run never hides a failure: a missing executable, an ARM executable without a runner, a bad
flight option, a crashed flight process and every malformed input give their cause on the console
(one line for an input error, exit 2; no traceback). With --target the run goes under QEMU with the
instruction counter and the estimated control delay, and every time in the summary names its source."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parent.parent


def rvd_run(*args, cwd=None, timeout=300) -> subprocess.CompletedProcess:
    """The installed console script, as a user would call it."""
    exe = Path(sys.executable).parent / "rvd-run"
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "rvd_pil.host_sim.cli"]
    return subprocess.run([*cmd, *map(str, args)], capture_output=True, text=True, timeout=timeout, cwd=cwd)


def one_line_error(r: subprocess.CompletedProcess) -> str:
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert "Traceback" not in r.stderr + r.stdout
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 or lines[0].startswith("usage:"), r.stderr
    return lines[-1]


def test_missing_flight_executable_fails_at_once(tmp_path):
    r = rvd_run("case1_vbar", "--truth", "cw", "--ideal", "--flight-sw", "/nonexistent", "--out", tmp_path / "run")
    assert "/nonexistent: no such file" in one_line_error(r)
    assert not (tmp_path / "run").exists()  # nothing ran, nothing recorded: never a silent fallback


def test_arm_executable_without_runner_names_the_cause(tmp_path):
    cc = shutil.which("arm-linux-gnueabihf-gcc")
    if cc is None:
        pytest.fail("arm-linux-gnueabihf-gcc missing: tools/install-deps test installs it")
    src = tmp_path / "main.c"
    src.write_text("int main(void) { return 0; }\n")
    exe = tmp_path / "arm_program"
    subprocess.run([cc, "-static", "-o", str(exe), str(src)], check=True)
    r = rvd_run("case1_vbar", "--truth", "cw", "--ideal", "--flight-sw", exe, "--out", tmp_path / "run")
    line = one_line_error(r)
    assert "ARM (32-bit) executable" in line and "--target" in line and '"qemu-arm -cpu' in line
    # and as --target for the wrong architecture: rpi3 is AArch64
    r = rvd_run("case1_vbar", "--target", "rpi3", "--flight-sw", exe, "--out", tmp_path / "run2")
    assert "target rpi3 needs AArch64" in one_line_error(r)


def test_bad_flight_option_shows_the_flight_softwares_message(tmp_path, flight_exe):
    r = rvd_run("case1_vbar", "--truth", "cw", "--ideal", "-q", "--out", tmp_path / "run", "--", "--no-such-option")
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert "flight software failed (exit code 2)" in r.stderr
    assert "unknown option '--no-such-option'" in r.stderr
    assert "usage:" not in r.stderr  # its message, not its usage text


def test_crashed_flight_process_is_reported_with_its_signal(tmp_path, flight_exe):
    # the runner is the flight process as the host sees it: here it dies of SIGSEGV at once
    r = rvd_run("case1_vbar", "--truth", "cw", "--ideal", "-q", "--out", tmp_path / "run",
                "--runner", "sh -c 'kill -SEGV $$'")
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert "flight software failed (killed by signal 11)" in r.stderr


@pytest.mark.parametrize("args,needle", [
    (["no_such_scenario"], "no_such_scenario"),
    (["random:x"], "random:<seed> needs an integer seed"),
    (["case1_vbar", "--cpu", "cortex-a8"], "--cpu needs --target"),
    (["case1_vbar", "--target", "cray1"], "unknown target 'cray1'"),
    (["case1_vbar", "--target", "q7s", "--cpu", "pentium"], "unknown CPU 'pentium'"),
    (["case1_vbar", "--target", "q7s", "--runner", "qemu-arm"], "leave --runner out"),
    (["case1_vbar", "--runner", "no-such-emulator"], "runner 'no-such-emulator': not found"),
    (["case1_vbar", "--seed", "one"], "invalid int value"),
])
def test_bad_inputs_give_one_line(tmp_path, args, needle):
    line = one_line_error(rvd_run(*args, "--out", tmp_path / "run"))
    assert needle in line


def test_malformed_scenario_file_names_the_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[initial\nx = 1\n")
    line = one_line_error(rvd_run(str(bad), "--out", tmp_path / "run"))
    assert "bad.toml" in line


def test_existing_record_directory_is_refused(tmp_path, flight_exe):
    run = tmp_path / "run"
    assert rvd_run("case1_vbar", "--truth", "cw", "--ideal", "-q", "--out", run).returncode == 0
    line = one_line_error(rvd_run("case1_vbar", "--truth", "cw", "--ideal", "-q", "--out", run))
    assert "exists" in line


@pytest.mark.qemu
@pytest.mark.slow
def test_target_runs_under_qemu_with_counts_and_estimated_delay(tmp_path):
    from rvd_pil.qemu import plugin, targets

    if plugin.build(download=False) is None:
        pytest.fail("the counting plugin is not built: `python -m rvd_pil.qemu prepare` (make test runs it)")
    t = targets.load("rpi3")
    r = rvd_run("case1_vbar", "--truth", "cw", "--ideal", "--delay", "estimated", "--target", "rpi3",
                "--no-cycle-model", "-q", "--out", tmp_path / "run", timeout=900)
    assert r.returncode == 0, r.stderr
    out = r.stdout
    # every time says where it comes from
    assert "solve times, target time on the flight clock (instructions counted by the plugin x CPI / f_clk)" in out
    assert "instructions per solve (counting plugin, exact)" in out
    assert f"control delay: estimated target time = instructions x CPI {t.cpi.nominal:g}" in out
    assert "docked" in out
    meta = json.loads((tmp_path / "run" / "meta.json").read_text())
    assert meta["delay_model"] == "estimated" and meta["target"] == "rpi3"
    assert "qemu-aarch64" in meta["flight_command"][0]
    # the flight's deadlines on the target time the delay is priced in (one CPI for both)
    assert meta["flight_hello"]["step_clock"] == 1
    i = meta["flight_command"].index("--target-clock")
    assert meta["flight_command"][i + 1] == f"{t.cpi.nominal!r},{t.clock_hz!r}"
    # the delay applied at each step is the estimated target time of that step's solves
    steps = pd.read_csv(tmp_path / "run" / "steps.csv")
    counted = steps[steps["instructions"] > 0]
    assert counted["delay_s"].isna().sum() <= 1 and counted["delay_s"].iloc[:-1].notna().all()  # the docking step applies none
    counted = counted[counted["delay_s"].notna()]
    assert len(counted) > 50
    expected = (counted["instructions"] * t.cpi.nominal / t.clock_hz).clip(upper=counted["period_s"])
    assert counted["delay_s"].to_numpy() == pytest.approx(expected.to_numpy(), rel=1e-12)
