"""rvd_pil/bench/link_latency.py, flight section: the native row on a short run. Structure only, never speed
(the machine is shared): every step answered exactly once by the trivial flight path, the figures
finite and positive and consistent with each other, the JSON complete, unavailable rows explained."""
import json
import math
import shutil

import pytest

from rvd_pil.bench import link_latency as ll

STEPS = 50


def test_trivial_flight_run_answers_every_step_once(flight_exe):
    res = ll.flight_round_trip(STEPS, flight_exe=str(flight_exe))
    assert res["end"] == "step limit"
    assert res["steps"] == list(range(STEPS))
    assert res["nav_attempts"] == [1] * STEPS and res["nav_resends"] == 0
    tel = res["flight_telemetry"]
    assert tel["nav_duplicates"] == 0 and tel["nav_rejected"] == 0
    assert res["flight_exit_code"] == 0
    # The trivial path answered, not the guidance: zero thrust, solver not run, nothing solved.
    assert res["guidance_status"] == [2] and res["solver_status"] == [255]
    assert res["pulse_cmd_max_s"] == 0.0 and tel["steps"] == [0, 0, 0]
    # At rest on V-bar under CW truth with zero thrust the chaser must not move at all.
    assert res["truth_drift_m"] == 0.0
    rtt = res["round_trip_ms"]
    assert len(rtt) == STEPS and all(math.isfinite(x) and x > 0.0 for x in rtt)


def test_cli_native_row_writes_consistent_figures(flight_exe, tmp_path, capsys):
    out = tmp_path / "latency.json"
    rc = ll.main(["--sections", "flight", "--native-only", "--steps", str(STEPS), "--rounds", "2",
                  "--flight-warmup", "5", "--flight-sw", str(flight_exe), "--json", str(out)])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "nav -> cmd round trip, trivial guidance" in printed and "CLOCK_MONOTONIC" in printed
    data = json.loads(out.read_text())
    assert data["echo"] is None and "monotonic" in data["flight"]["clock"]
    (row,) = data["flight"]["rows"]
    assert row["key"] == "native" and row["skipped"] is None
    # 2 rounds of ceil(50 / 2) + 5 steps, the 5 warm-up steps of each left out.
    assert [r["steps"] for r in row["runs"]] == [30, 30]
    assert all(r["end"] == "step limit" and r["nav_resends"] == 0 for r in row["runs"])
    st = row["stats"]
    assert st["n"] == len(row["samples_ms"]) == STEPS
    assert all(math.isfinite(v) and v > 0.0 for k, v in st.items() if k != "n")
    assert st["median_ms"] <= st["p90_ms"] <= st["p99_ms"] <= st["max_ms"]
    assert st["max_ms"] == pytest.approx(max(row["samples_ms"]), abs=1e-4)
    assert row["ratio_to_native"] == {k: 1.0 for k in ("median_ms", "p90_ms", "p99_ms", "max_ms")}
    assert len(row["first_step_ms"]) == 2 and all(x > 0.0 for x in row["first_step_ms"])
    assert row["flight_arch"]  # the hello of the flight executable that answered


@pytest.mark.parametrize("present, missing", [((), "qemu-arm not found"),
                                              (("qemu-arm",), "cross compiler arm-linux-gnueabihf-g++ not found")])
def test_a_row_that_cannot_run_is_skipped_with_the_reason(tmp_path, monkeypatch, capsys, present, missing):
    for tool in present:  # a PATH holding only these tools
        real = shutil.which(tool)
        if real is None:
            pytest.skip(f"{tool} is not installed here: tools/install-deps test")
        (tmp_path / tool).symlink_to(real)
    row = ll._user_row("q7s", 10)
    monkeypatch.setenv("PATH", str(tmp_path))
    result = ll.flight_section([row], rounds=1, warmup=0, host_mode="peer")
    (entry,) = result["rows"]
    assert missing in entry["skipped"] and "stats" not in entry and entry["runs"] == []
    assert f"skipped: {missing}" in capsys.readouterr().out


def test_unknown_target_is_refused_by_name():
    args = ll.parse_args(["--sections", "flight", "--targets", "q7s,nosuchboard"])
    with pytest.raises(SystemExit, match="unknown target 'nosuchboard'"):
        ll.build_rows(args, workdir=None)
