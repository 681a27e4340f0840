"""The PIL report (rvd_pil/bench/report.py) on a synthetic campaign whose figures are known beforehand
(tests/report_campaign.py): the verdict rows, their margins and pass/fail, readable numbers,
headings in words, the checks as a table, provenance, and a second campaign's runs kept out.
The page itself is checked in a real headless Chromium in tests/test_report_browser.py."""
from __future__ import annotations

import json
import re
import shutil

import pytest

from rvd_pil.bench import report
import report_campaign


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    out = tmp_path_factory.mktemp("pil")
    expected = report_campaign.make(out)
    report.write(out)
    return out, expected


def test_verdict_rows_carry_the_margins_and_the_verdict(campaign):
    out, expected = campaign
    rep = json.loads((out / "report.json").read_text())
    rows = {(r["target"], r["phase"]): r for r in rep["verdict"]}
    assert set(rows) == set(expected)
    for key, exp in expected.items():
        r = rows[key]
        assert r["period_s"] == report_campaign.PERIODS[{"rendezvous": 1, "approach": 2, "docking": 3}[key[1]]]
        for k in ("deadline_ms", "worst_ms", "p99_ms", "margin_worst", "margin_p99"):
            got = r[{"worst_ms": "worst_target_ms", "p99_ms": "p99_target_ms"}.get(k, k)]
            assert got == pytest.approx(exp[k], rel=1e-9), (key, k)
        assert r["misses"] == exp["misses"]
    # rpi3 fits everywhere and is safe; q7s misses the docking deadline and violates the corridor
    assert all(rows[("rpi3", p)]["pass"] for p in ("rendezvous", "approach", "docking"))
    assert rows[("q7s", "docking")]["fits"] is False and rows[("q7s", "docking")]["pass"] is False
    assert rows[("q7s", "docking")]["misses"] == 2
    assert rows[("q7s", "approach")]["fits"] and rows[("q7s", "approach")]["safety_violations"] == 1
    assert rows[("q7s", "approach")]["pass"] is False
    assert rows[("q7s", "rendezvous")]["pass"] is True
    # the runs table has the horizons as numbers, one column per phase
    import pandas as pd

    runs = pd.read_csv(out / "runs.csv")
    assert runs[["N_rendezvous", "N_approach", "N_docking"]].drop_duplicates().values.tolist() == [[30, 15, 12]]


def test_max_over_median_is_shown_over_the_campaign_and_within_a_run(campaign):
    """stats.csv and the details table give max / p50 of the estimated target time over all runs of a
    phase and horizon and within each run (its worst run named): random:1's rendezvous solves cost
    1.6x case1_vbar's, so there the ratio over both runs exceeds the one within either; elsewhere the
    two runs are alike and so are the ratios."""
    import pandas as pd

    out, expected = campaign
    stats = pd.read_csv(out / "stats.csv")
    for (target, phase), exp in expected.items():
        row = stats[(stats["target"] == target) & (stats["phase"] == phase)].iloc[0]
        assert row["max_over_p50"] == pytest.approx(exp["max_over_p50"], rel=1e-9), (target, phase)
        assert row["run_max_over_p50"] == pytest.approx(exp["run_max_over_p50"], rel=1e-9), (target, phase)
        if phase == "rendezvous":
            assert row["max_over_p50"] > 1.2 * row["run_max_over_p50"]
            assert "random1" in row["run_max_over_p50_at"] or "case1_vbar" in row["run_max_over_p50_at"]
        else:
            assert row["max_over_p50"] == pytest.approx(row["run_max_over_p50"], rel=1e-9)
    page = (out / "report.html").read_text()
    assert "max / p50 within a run (worst run)" in page and "max / p50" in page


def test_page_reads_as_a_verdict_first(campaign):
    out, _ = campaign
    page = (out / "report.html").read_text()
    text = re.sub(r"<[^>]+>", " ", re.sub(r"<(script|style)>.*?</\1>", " ", page, flags=re.S))
    # the verdict comes before every detail, and states the rule and the periods
    assert page.index("id='verdict'") < page.index("id='safety'") < page.index("id='checks'") < page.index("id='details'")
    assert "0.5 &times; T<sub>s</sub>" in page
    assert "rendezvous 30 s, approach 20 s, docking 5 s" in page
    assert "does NOT pass" in page and "fits and is safe" in page
    # readable numbers: no exponent anywhere in the visible text, the docking deadline grouped
    assert not re.search(r"\d[eE][+-]\d", text), re.search(r".{30}\d[eE][+-]\d.{30}", text)
    assert "2\u2009500" in text
    # headings in words, not file names; every series names its CPU
    for h in re.findall(r"<h[1-3][^>]*>(.*?)</h[1-3]>", page):
        assert not re.search(r"\.(png|csv|json)\b", re.sub(r"<[^>]+>", "", h)), h
    assert "Cortex-A53 at 1.2 GHz" in text and "Cortex-A9 at 0.667 GHz" in text
    # the dissertation cited by author and title
    assert "A. Fear" in text and "Autonomous Rendezvous and Docking of Small Satellites" in text
    # provenance
    for needle in ("report commit", "SHA-256 0123456789abcdef", "GCC 12.2.0", "qemu-aarch64", "LLVM (llvm-mca)"):
        assert needle in text, needle
    # the figures are inside the page (it works alone, offline), the PNG files beside it
    imgs = re.findall(r"<img src='([^']{0,40})", page)
    assert imgs and all(src.startswith("data:image/png;base64,") for src in imgs)
    assert (out / "hist_rpi3.png").is_file() and "href='hist_rpi3.png'" in page
    # links to the run records
    assert "href='runs/q7s/random1-N30-15-12/meta.json'" in page


def test_histograms_mark_deadline_and_dissertation(campaign, monkeypatch):
    out, _ = campaign
    import matplotlib.axes

    lines = []
    orig = matplotlib.axes.Axes.axvline

    def spy(self, x=0, *a, **kw):
        lines.append((x, kw.get("label")))
        return orig(self, x, *a, **kw)

    monkeypatch.setattr(matplotlib.axes.Axes, "axvline", spy)
    report.write(out)
    xs = {round(x, 6) for x, _ in lines}
    assert {15000.0, 10000.0, 2500.0} <= xs  # the deadlines, 0.5 Ts, in ms
    assert {270.40, 181.55, 30.1} <= xs  # the dissertation's means at N = 30, 15, 12


def test_checks_are_a_table():
    chk = {"rpi3": {"user_runs_docked": True, "user_instructions_identical": True, "user_instructions_compared": 103,
                    "user_instructions_steps_identical": 103, "user_instructions_max_difference": 0.0,
                    "user_dv_minus_native_mps": [2e-7, 5e-6], "block_counts_equal_instruction_counts": False,
                    "block_counts_compared": 206}}
    t = report.checks_table(chk)
    assert list(t.columns) == ["target", "what was checked", "figure", "limit", "result"]
    res = {r["what was checked"]: (r["figure"], r["result"].text) for r in t.to_dict(orient="records")}
    assert res["instructions per solve, two qemu-user runs (plugin)"] == ("103 of 103 steps identical", "PASS")
    dv = res["total delta-v under qemu-user minus the native build's"]
    assert dv[1] == "FAIL" and dv[0].startswith("0.005 mm/s")  # 5e-6 m/s is over the 1e-6 m/s limit
    assert res["block profiler total = instruction counter, every priced solve"][1] == "FAIL"


@pytest.mark.parametrize("value,text", [(15000.0, "15\u2009000"), (0.012345, "0.0123"), (2.0, "2"),
                                        (1.5e4, "15\u2009000"), (123456.7, "123\u2009457"), (3.14159, "3.14"),
                                        (16.04, "16.0"), (0.5, "0.5"), (2.13e-9, "2.13 \u00d7 10\u207b\u2079"),
                                        (float("nan"), "")])
def test_numbers_are_readable(value, text):
    assert report._fmt(value) == text


def test_second_campaign_never_mixes_with_the_first(tmp_path):
    """A folder's report reads only the runs its campaign.json lists; the campaign refuses a folder
    that holds another campaign, and --replace clears the old runs first."""
    from rvd_pil.bench import campaign

    report_campaign.make(tmp_path)
    stray = tmp_path / "runs" / "beaglebone" / "old-run"
    shutil.copytree(tmp_path / "runs" / "rpi3" / "case1_vbar-N30-15-12", stray)
    meta = json.loads((stray / "meta.json").read_text())
    (stray / "meta.json").write_text(json.dumps({**meta, "target": "beaglebone", "build": "beaglebone"}))
    report.write(tmp_path)
    rep = json.loads((tmp_path / "report.json").read_text())
    assert {r["target"] for r in rep["verdict"]} == {"rpi3", "q7s"}
    assert "beaglebone" not in {r["target"] for r in rep["runs"]}

    other = campaign.Spec(targets=["beaglebone"])
    with pytest.raises(campaign.CampaignConflict, match="other settings"):
        campaign.claim(tmp_path, other)
    assert (tmp_path / "runs" / "rpi3").is_dir()  # refused: nothing touched
    # the command line says so in one line, exit 2
    rc = campaign.main(["--targets", "rpi3", "--out", str(tmp_path), "--scenarios", "case1_vbar"])
    assert rc == 2
    campaign.claim(tmp_path, other, replace=True)
    assert not (tmp_path / "runs").exists()
    state = json.loads((tmp_path / "campaign.json").read_text())
    assert state["spec"]["targets"] == ["beaglebone"] and "runs" not in state
    # the same settings again: a resume, not a conflict
    campaign.claim(tmp_path, other)


def test_runs_of_no_campaign_are_refused(tmp_path):
    from rvd_pil.bench import campaign

    report_campaign.make(tmp_path)
    (tmp_path / "campaign.json").unlink()
    with pytest.raises(campaign.CampaignConflict, match="no known campaign"):
        campaign.claim(tmp_path, campaign.Spec(targets=["rpi3"]))


def test_a_flight_clock_on_target_time_is_never_shown_as_host_time(tmp_path):
    """Runs whose flight clock was on target time (hello step_clock 1): their reported solve times are
    target time, so the host time shown beside the dissertation's is the host's round trip of the
    step, and the flight's own figures are labelled as the flight clock."""
    import pandas as pd

    report_campaign.make(tmp_path)
    for meta_path in (tmp_path / "runs").rglob("meta.json"):
        meta = json.loads(meta_path.read_text())
        meta["flight_hello"]["step_clock"] = 1
        meta_path.write_text(json.dumps(meta))
        steps = pd.read_csv(meta_path.parent / "steps.csv")
        steps["round_trip_ms"] = 100.0 + steps["step"]
        steps.to_csv(meta_path.parent / "steps.csv", index=False)
    report.write(tmp_path)
    stats = pd.read_csv(tmp_path / "stats.csv")
    docking = stats[stats["phase"] == "docking"]
    assert (docking["wall_ms_max"] == 159.0).all()  # the round trip of the last docking step, 59
    assert list(docking["flight_clock_ms_max"]) == pytest.approx([15.19, 15.19])  # its solve_time_us, 15 190 us
    assert docking["wall_is_round_trip"].all()
    page = (tmp_path / "report.html").read_text()
    assert "emulated wall time" not in page and "ours QEMU round trip, mean [ms]" in page
    assert "on target time" in page
