"""The peers page (rvd_pil/bench/peer_laws.py) on two synthetic campaigns whose ratio is known: a peer
that counts exactly twice our instructions at every solve, and whose check runs repeat one count but
not another, must show 2 and name the failed check."""
from __future__ import annotations

import json
import shutil

import pandas as pd

import report_campaign
from rvd_pil.bench import peer_laws


def _scale_instructions(out, factor):
    for run in (out / "runs").glob("*/*"):
        for name in ("steps.csv", "cycles.csv"):
            df = pd.read_csv(run / name)
            df["instructions"] *= factor
            if name == "steps.csv":
                df["guidance_status"] = 0  # every step solved (the flight software's telemetry column)
            if "cycles_nominal" in df:
                for c in ("cycles_low", "cycles_nominal", "cycles_high"):
                    df[c] *= factor
            df.to_csv(run / name, index=False)


def _add_checks(out, target, differ: bool):
    """Two QEMU check runs of the ideal Case 1 (copies of a timing run) and the native one."""
    src = out / "runs" / target / "case1_vbar-N30-15-12"
    runs = json.loads((out / "campaign.json").read_text())
    for i in (1, 2):
        d = out / "runs" / target / f"case1-ideal-{i}"
        shutil.copytree(src, d)
        meta = json.loads((d / "meta.json").read_text())
        (d / "meta.json").write_text(json.dumps({**meta, "kind": "check"}))
        if differ and i == 2:
            df = pd.read_csv(d / "steps.csv")
            df.loc[3, "instructions"] += 1
            df.to_csv(d / "steps.csv", index=False)
        runs["runs"].append(f"runs/{target}/case1-ideal-{i}")
    (out / "campaign.json").write_text(json.dumps(runs))


def test_the_page_shows_the_known_ratio_and_the_failed_check(tmp_path):
    ours, peer = tmp_path / "fast_mpc", tmp_path / "lq_ecg"
    report_campaign.make(ours)
    report_campaign.make(peer)
    _scale_instructions(ours, 1.0)
    _scale_instructions(peer, 2.0)
    _add_checks(ours, "rpi3", differ=False)
    _add_checks(peer, "rpi3", differ=True)
    t = peer_laws.side_by_side(tmp_path, ["lq_ecg"])
    p = t[t["law"] == "lq_ecg"]
    assert len(p) == 6  # two targets x three phases
    assert (abs(p["insns_ratio"] - 2.0) < 1e-12).all()
    assert (abs(t[t["law"] == "fast_mpc"]["insns_ratio"] - 1.0) < 1e-12).all()
    chk = peer_laws.checks_table(tmp_path, ["lq_ecg"])
    insns = chk[chk["what was checked"].str.startswith("instructions per solve")].set_index("law")
    assert insns.loc["fast_mpc", "result"] == "PASS" and insns.loc["lq_ecg", "result"] == "FAIL"
    assert insns.loc["lq_ecg", "figure"].startswith("59 of 60 steps identical")
    page = peer_laws.write_page(tmp_path, t, ["lq_ecg"], {"what": "synthetic"}, chk).read_text()
    assert "Checks of every law" in page and "59 of 60 steps identical" in page
