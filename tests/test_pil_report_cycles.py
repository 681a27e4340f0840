"""A small PIL campaign (rvd_pil/bench/campaign.py) on the Raspberry Pi 3 target end to end: the timing run and
the ideal Case 1 checks are priced by the cycle model, and the report (rvd_pil/bench/report.py) carries the
cycles, the interval, the old CPI figure beside them and the timing-model section.

Independent truths: the instruction counter (the block profiler's total per solve must equal it),
the run-to-run repeat of the ideal Case 1 (cycles identical), and the interval's order.
"""
from __future__ import annotations

import json
import os
import shutil

import pytest

from rvd_pil.qemu import cycles, plugin, targets

pytestmark = [pytest.mark.qemu, pytest.mark.slow]


def test_campaign_report_carries_cycle_estimates(tmp_path):
    fetch = os.environ.get("RVD_QEMU_FETCH") == "1"
    if plugin.build(download=fetch) is None or plugin.build_profile(download=fetch) is None:
        pytest.skip("plugins not built: run `python -m rvd_pil.qemu prepare` (or set RVD_QEMU_FETCH=1)")
    if shutil.which(cycles.LLVM_MCA) is None or not shutil.which(targets.load("rpi3").compiler):
        pytest.skip("llvm-15 or the aarch64 cross compiler missing: tools/install-deps pil")
    from rvd_pil.bench import report
    from rvd_pil.bench.campaign import Campaign, Spec

    spec = Spec(targets=["rpi3"], scenarios=["case1_vbar"], horizon_sets=[(15, 5, 5)], system_mode=False)
    info = Campaign(spec, tmp_path).target("rpi3")
    assert info["delay_cpi"]["source"].startswith("cycle model")
    report.write(tmp_path)
    rep = json.loads((tmp_path / "report.json").read_text())

    chk = rep["checks"]["rpi3"]
    assert chk["user_instructions_identical"] and chk["user_cyc_cycles_nominal_identical"]
    assert chk["block_counts_equal_instruction_counts"] and chk["block_counts_compared"] > 100

    stats = rep["stats"]
    assert {s["phase"] for s in stats} == {"rendezvous", "approach", "docking"}
    for s in stats:
        assert s["target_ms_mean_low"] <= s["target_ms_mean"] <= s["target_ms_mean_high"]
        assert s["target_ms_max_low"] <= s["target_ms_max"] <= s["target_ms_max_high"]
        assert 0.5 < s["cpi_model_mean"] < 6
        assert s["target_ms_cpi_mean"] > 0 and s["calibrated"] is False
        # cycles / f_clk, from the run's own cycles.csv: the mean time follows the mean cycles
        assert s["target_ms_mean"] == pytest.approx(s["cycles_mean"] / 1.2e9 * 1e3, rel=1e-9)
    html = (tmp_path / "report.html").read_text()
    for needle in ("Timing model", "The model ignores", "Correction table", "Microbenchmarks with known answers",
                   "What a board calibration would change", "CPI guess"):
        assert needle in html
    micro = json.loads((tmp_path / "microbench-cortex-a53.json").read_text())
    assert all(r["within"] for r in micro if r["within"] is not None)
