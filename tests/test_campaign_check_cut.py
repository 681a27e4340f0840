"""The campaign's checks cut at a set simulated time (--check-timeout-s): for a law whose ideal Case 1
never docks and would fly to the scenario's 12000 s timeout. The cut run is the full run's beginning,
ends 'timeout' at the cut, and the report judges such runs on reaching the cut instead of docking."""
from __future__ import annotations

import pandas as pd
import pytest

from rvd_pil.bench import campaign, report
from rvd_pil.host_sim.pil import find_flight_executable


def test_a_cut_check_run_is_the_full_runs_beginning(tmp_path):
    exe = find_flight_executable()
    camp = campaign.Campaign(campaign.Spec(targets=["q7s"], check_timeout_s=600.0), tmp_path)
    full = camp.run(tmp_path / "runs" / "full", "case1_vbar", fingerprint="full", ideal=True, flight_exe=exe)
    cut = camp.run(tmp_path / "runs" / "cut", "case1_vbar", fingerprint="cut", ideal=True, flight_exe=exe,
                   timeout_s=600.0)
    assert full["docked"] and full["t_end_s"] > 600.0
    assert cut["end"] == "timeout" and not cut["docked"]
    assert 540.0 <= cut["t_end_s"] <= 600.0 + 1e-9
    a = pd.read_csv(tmp_path / "runs" / "cut" / "steps.csv")
    b = pd.read_csv(tmp_path / "runs" / "full" / "steps.csv").iloc[:len(a)]
    assert len(a) >= 10
    # the same steps, the same commands: the cut only ends the run
    cols = ["t_s", "dv_x_mps", "dv_y_mps", "dv_z_mps", *[c for c in a if c.startswith("truth_")]]
    assert len(cols) > 4
    for col in cols:
        assert (a[col].to_numpy() == b[col].to_numpy()).all(), col
    # the same run asked for with a cut is another run: flown again, not the whole one reused
    again = camp.run(tmp_path / "runs" / "full", "case1_vbar", fingerprint="full", ideal=True, flight_exe=exe,
                     timeout_s=600.0)
    assert again["end"] == "timeout" and again["steps"] == cut["steps"]


def test_the_report_judges_cut_checks_on_reaching_the_cut():
    base = {"user_instructions_identical": True, "user_instructions_compared": 100,
            "user_instructions_steps_identical": 100, "user_instructions_max_difference": 0.0}
    ok = {**base, "user_check_timeout_s": 3000.0, "user_runs_ends": ["timeout at 3000 s", "timeout at 3000 s"],
          "user_runs_reached_cut": True}
    lost = {**ok, "user_runs_ends": ["timeout at 3000 s", "flight software lost at 90 s"],
            "user_runs_reached_cut": False}
    for chk, verdict in ((ok, "PASS"), (lost, "FAIL")):
        t = report.checks_table({"q7s": chk})
        row = t[t["what was checked"].str.contains("cut at 3000 s")]
        assert len(row) == 1 and row.iloc[0]["result"].text == verdict
        assert not t["what was checked"].str.contains("docked$").any()


def test_the_cut_defaults_to_plugin_laws_only():
    assert campaign.parse_args([])[0].check_timeout_s is None  # our MPC: the whole run
    law = ["--guidance", "examples/guidance/cw_target"]
    assert campaign.parse_args(law)[0].check_timeout_s == campaign.PLUGIN_CHECK_TIMEOUT_S
    assert campaign.parse_args([*law, "--check-timeout-s", "0"])[0].check_timeout_s is None
    assert campaign.parse_args(["--check-timeout-s", "1500"])[0].check_timeout_s == 1500.0
    for bad in ("-1", "nan"):
        with pytest.raises(SystemExit):
            campaign.parse_args(["--check-timeout-s", bad])
    assert campaign.parse_args(["--flight-time-s", "90"])[0].flight_time_s == 90.0
    assert campaign.parse_args([])[0].flight_time_s is None
    for bad in ("0", "-5", "nan"):
        with pytest.raises(SystemExit):
            campaign.parse_args(["--flight-time-s", bad])
