"""The safety Monte Carlo's random starts around another scenario's target (--base): the runs fly that
target (Case 3's, turning at 0.15 deg/s), the set-up file says so, and an unknown base is refused
before any run starts."""
import json

from rvd_pil.bench import safety_mc


def test_random_starts_keep_the_base_scenarios_turning_target(tmp_path, flight_exe, capsys):
    out = tmp_path / "mc"
    assert safety_mc.main(["--base", "case3_rotating", "--starts", "1", "--noise-seeds", "1", "--jobs", "1",
                           "--out", str(out), "--flight-args", "--horizon 15,5,5"]) == 0
    setup = json.loads((out / "setup.json").read_text())
    assert setup["base"] == "case3_rotating" and setup["flight_args"] == ["--horizon", "15,5,5"]
    meta = json.loads((out / "runs" / "random_1-seed_0" / "meta.json").read_text())
    assert meta["scenario"]["target"]["spin_rate_deg_s"] == 0.15
    assert meta["scenario"]["chaser"]["position_lvlh_m"] != [140.0, -1580.0, 60.0]  # a random start, not Case 3's
    assert meta["docked"] and meta["safety"]["verdict"] == "safe", meta["safety"]
    assert "runs: 1" in capsys.readouterr().out
    # The same folder with another base is another set-up: refused.
    assert safety_mc.main(["--starts", "1", "--noise-seeds", "1", "--out", str(out)]) == 2


def test_an_unknown_base_is_refused_before_any_run(tmp_path, capsys):
    assert safety_mc.main(["--base", "no_such_scenario", "--out", str(tmp_path / "mc")]) == 2
    assert "unknown scenario 'no_such_scenario'" in capsys.readouterr().err
    assert not (tmp_path / "mc").exists()
