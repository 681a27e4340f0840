"""The cycle model (rvd_pil/qemu/cycles.py) and the block-profile plugin (rvd_pil/qemu/plugin/block_profile.c).

Independent truths:
  - the instruction-counting plugin: the block profiler's total (executions x block size) of every
    solve region, and of the whole process, must equal its count exactly;
  - run-to-run: instruction counts, block counts, cache-model misses and the cycle estimates of the
    same executable with the same inputs are identical; and they stay so when what differs from run
    to run differs: the clock's readings inside a solve, the work between two solves;
  - published timings: the microbenchmarks (rvd_pil/bench/microbench/) whose cost per iteration follows from
    Arm's documents (rvd_pil/bench/microbench/expected.toml, each figure cited) are reproduced within 10 %;
  - llvm-15 itself: the LLVM figures the correction table replaces are the ones llvm-mca-15 uses;
  - analytic cache behaviour: a pointer chase over a working set larger than L2 misses every line
    in both levels, one inside L1 misses only on its first pass.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess

import pytest

from rvd_pil.qemu import asm_dataflow, build, cycles, plugin, targets, user

pytestmark = pytest.mark.qemu


@pytest.fixture(scope="module")
def libs():
    fetch = os.environ.get("RVD_QEMU_FETCH") == "1"
    counter = plugin.build(download=fetch)
    profiler = plugin.build_profile(download=fetch)
    if counter is None or profiler is None:
        pytest.skip("plugins not built: run `python -m rvd_pil.qemu prepare` (or set RVD_QEMU_FETCH=1)")
    if shutil.which(cycles.LLVM_MCA) is None:
        pytest.skip("llvm-mca-15 missing: tools/install-deps pil")
    return counter, profiler


@pytest.fixture(scope="module", params=["q7s", "rpi3"])
def probe(request):
    t = targets.load(request.param)
    if not shutil.which(t.compiler):
        pytest.skip(f"{t.compiler} missing: run tools/install-deps pil")
    return t, build.cross_build(t, "qemu_probe").path


def _profiled_run(t, exe, args, tmp, libs, tag, cache=True, scope="solves", env=None):
    counter_lib, profile_lib = libs
    model = cycles.CycleModel(t)
    ic = plugin.InsnCounter(log=tmp / f"{tag}.insns", library=counter_lib)
    bp = plugin.BlockProfiler(out=tmp / f"{tag}.blocks", cache=model.cache_geometry if cache else None,
                              library=profile_lib, cache_scope=scope)
    proc = user.run(t, exe, args, plugin=[ic, bp], timeout_s=120, env=env)
    assert proc.returncode == 0, proc.stderr
    return model, plugin.read_log(tmp / f"{tag}.insns"), cycles.read_profile(tmp / f"{tag}.blocks"), \
        (tmp / f"{tag}.insns").read_text()


def test_block_counts_total_equals_the_instruction_count(libs, probe, tmp_path):
    t, exe = probe
    _, counted, prof, log = _profiled_run(t, exe, ["markers", "3", "5000", "llt", "40", "llt", "80"], tmp_path, libs, "a")
    assert [(r.step, r.insns) for r in prof.regions] == counted
    for r in prof.regions:  # the region total is recomputed here from the block table itself
        assert sum(n * prof.blocks[b].n_insns for b, n in r.counts.items()) == r.insns
    total = int(re.search(r"total insns (\d+)", log).group(1))
    assert prof.process.insns == total == sum(n * prof.blocks[b].n_insns for b, n in prof.process.counts.items())
    # the marked two-instruction loop: its block ran SPIN*(s+1) times in region s (the first
    # iteration may belong to the block that enters the loop)
    for s, r in enumerate(prof.regions[:3]):
        assert 5000 * (s + 1) - 1 <= max(r.counts.values()) <= 5000 * (s + 1)


def test_instruction_counts_and_cycle_estimates_repeat_exactly(libs, probe, tmp_path):
    t, exe = probe
    args = ["markers", "2", "3000", "llt", "60"]
    model, c1, p1, _ = _profiled_run(t, exe, args, tmp_path, libs, "one")
    _, c2, p2, _ = _profiled_run(t, exe, args, tmp_path, libs, "two")
    assert c1 == c2
    costs1 = model.block_costs(exe, p1.blocks)
    costs2 = model.block_costs(exe, p2.blocks)
    for r1, r2 in zip(p1.regions, p2.regions, strict=True):
        assert r1.cache == r2.cache
        assert {p1.blocks[b].key: n for b, n in r1.counts.items()} == {p2.blocks[b].key: n for b, n in r2.counts.items()}
        assert model.region_cycles(r1, costs1) == model.region_cycles(r2, costs2)
    llt = model.region_cycles(p1.regions[-1], costs1)
    assert llt.low <= llt.nominal <= llt.high
    assert llt.core_steady <= llt.core_cold
    assert 0.3 < llt.core_steady / llt.insns < 6  # a dense FP64 kernel: CPI of a few tenths to a few


def _by_key(prof, region):
    return {prof.blocks[b].key: n for b, n in region.counts.items()}


def test_clock_readings_inside_a_solve_do_not_change_its_figures(libs, probe, tmp_path):
    """The guidance step checks its deadline on steady_clock inside the counted region, and the
    clock reads differently in every run. The flight's conversion of an elapsed time
    (flight_sw/solver/elapsed.hpp) must execute the same blocks whatever the value: around 2^21 ns,
    where libgcc's int64-to-double conversion (Armv7 has no instruction for it) changes path, around
    2^32 ns and far beyond. std::chrono's own conversion is the control: on the A9 it executes as
    many instructions at 3 ms as at 1 ms, through other blocks (what made the estimate vary)."""
    t, exe = probe
    elapsed = [1_000_000, 2_000_000, 2_200_000, 3_000_000, 4_294_000_000, 5_000_000_000, 2**52]
    args = ["elapsed", "1000"] + [a for ns in elapsed for a in ("elapsed", str(ns))]  # the first warms the caches
    args += ["chrono", "1000000", "chrono", "3000000"]
    model, counted, prof, _ = _profiled_run(t, exe, args, tmp_path, libs, "clock")
    assert [(r.step, r.insns) for r in prof.regions] == counted
    costs = model.block_costs(exe, prof.blocks)
    first, *rest = prof.regions[1:1 + len(elapsed)]
    for r in rest:
        assert _by_key(prof, r) == _by_key(prof, first)
        assert r.cache == first.cache
        assert model.region_cycles(r, costs) == model.region_cycles(first, costs)
    at_1ms, at_3ms = prof.regions[-2:]
    if t.arch == "armhf":
        assert at_1ms.insns == at_3ms.insns and _by_key(prof, at_1ms) != _by_key(prof, at_3ms)


def test_the_users_environment_does_not_reach_an_emulated_flight_process(libs, probe, tmp_path, monkeypatch):
    """QEMU user mode hands its environment to the guest, and its size moves the guest's initial
    stack and so the cache sets of stack data. A flight process under QEMU gets a fixed environment
    (the link key has a fixed length), so a checkout at another path or a longer shell environment
    gives the same figures; a native flight process keeps the caller's environment."""
    from rvd_pil.host_sim.pil import EMULATED_FLIGHT_ENV, flight_environment

    t, exe = probe
    key = bytes(range(32))
    figures = []
    for extra in ("", "x" * 100):
        monkeypatch.setenv("RVD_TEST_PADDING", extra)
        cmd = user.command(t, exe, ["llt", "40"])
        env = flight_environment(cmd, key)
        assert set(env) == set(EMULATED_FLIGHT_ENV) | {"RVD_LINK_KEY"} and env["RVD_LINK_KEY"] == key.hex()
        assert flight_environment([str(exe)], key)["RVD_TEST_PADDING"] == extra  # native: the caller's
        _, _, prof, _ = _profiled_run(t, exe, ["llt", "40"], tmp_path, libs, f"env{len(extra)}", env=env)
        figures.append([(r.insns, r.cache) for r in prof.regions])
    assert figures[0] == figures[1] and figures[0]


def test_the_work_between_solves_does_not_change_a_solves_cache_figures(libs, probe, tmp_path):
    """The code between two solves waits for the host: how often its loops run, and so what it leaves
    in the caches, changes from run to run. The cache model sees the solves only, so a solve reading
    16 KB the previous solve read hits in L1 whether 768 KB (more than L2) of other memory traffic
    ran between the two or none. Over the whole process (cache_scope="process", a board
    calibration's setting) the traffic evicts the table from both levels: the check can fail."""
    t, exe = probe

    def second_solve(kb, scope):
        # the same argument lengths ("000" / "768"): the same initial stack, so the same stack addresses
        _, counted, prof, _ = _profiled_run(t, exe, ["sum", "16", "touch", kb, "sum", "16"], tmp_path, libs,
                                            f"{scope}{kb}", scope=scope)
        assert [(r.step, r.insns) for r in prof.regions] == counted
        return prof, prof.regions[1]

    (pq, quiet), (pb, busy) = second_solve("000", "solves"), second_solve("768", "solves")
    assert _by_key(pq, quiet) == _by_key(pb, busy)
    assert quiet.cache == busy.cache
    assert quiet.cache["load_acc"] >= 2048 and quiet.cache["load_l1_miss"] == 0
    (_, quiet), (_, busy) = second_solve("000", "process"), second_solve("768", "process")
    lines = 16 * 1024 // 64
    assert quiet.cache["load_l1_miss"] < lines // 10  # the printf between the two evicts a few
    assert busy.cache["load_l1_miss"] >= lines and busy.cache["load_l2_miss"] >= lines


def test_borrowed_miss_rates_reproduce_the_cache_model_on_the_same_inputs(libs, probe, tmp_path):
    """A run without the cache model, priced with the per-block miss rates of a run with it, gets
    the same memory term when both ran the same code on the same inputs."""
    t, exe = probe
    args = ["llt", "60", "llt", "60"]
    model, _, with_cache, _ = _profiled_run(t, exe, args, tmp_path, libs, "cache")
    _, _, without, _ = _profiled_run(t, exe, args, tmp_path, libs, "nocache", cache=False)
    assert not without.cache_on and all(v == 0 for v in without.regions[0].cache.values())
    rates = with_cache.miss_rates()
    exact = cycles.profile_summary(model, exe, with_cache)
    borrowed = cycles.profile_summary(model, exe, without, rates)
    for e, b in zip(exact, borrowed, strict=True):
        assert b["memory_term"] == "borrowed miss rates" and b["miss_rate_coverage"] == 1.0
        assert b["core_steady"] == e["core_steady"]
    # rates over both regions applied to each: the same total (the first solve misses more than
    # the second, which finds the code and part of its data cached)
    for k in ("mem_low", "mem_high"):
        assert sum(b[k] for b in borrowed) == pytest.approx(sum(e[k] for e in exact), rel=1e-9)


def test_cache_model_misses_follow_the_working_set(libs, tmp_path):
    """qemu_probe's llt factors an n x n matrix of doubles; twice the same size, the second solve works
    on the first one's addresses. n = 40 (12.5 KB) sits in the A53's 32 KB L1D, so the second
    factorization almost never misses and never leaves L2; n = 300 (720 KB) exceeds the 512 KB L2,
    so it misses in both levels, the same way each time."""
    t = targets.load("rpi3")
    exe = build.cross_build(t, "qemu_probe").path
    _, _, prof, _ = _profiled_run(t, exe, ["llt", "40", "llt", "40", "llt", "300", "llt", "300"], tmp_path, libs, "ws")
    _, small, big1, big2 = prof.regions
    assert small.cache["load_l1_miss"] < 0.01 * small.cache["load_acc"] and small.cache["load_l2_miss"] == 0
    assert big1.cache["load_l1_miss"] > 0.01 * big1.cache["load_acc"]
    assert big1.cache["load_l2_miss"] > 5000
    assert abs(big2.cache["load_l2_miss"] - big1.cache["load_l2_miss"]) < 0.05 * big1.cache["load_l2_miss"]
    model = cycles.CycleModel(t)
    lo_s, hi_s = model.memory_cycles(small.cache)
    lo_b, hi_b = model.memory_cycles(big1.cache)
    assert lo_b / big1.insns > 10 * lo_s / small.insns  # the memory term per instruction follows


@pytest.mark.parametrize("cpu", ["cortex-a53", "cortex-a55", "cortex-a72", "cortex-a9", "cortex-a8"])
def test_microbenchmarks_reproduce_published_timings(libs, cpu, tmp_path):
    from rvd_pil.bench.microbench import run as microbench

    tname, build_cpu = microbench.CPUS[cpu]
    t = targets.load(tname, cpu=build_cpu)
    if not shutil.which(t.compiler):
        pytest.skip(f"{t.compiler} missing: run tools/install-deps pil")
    results = microbench.measure(cpu, workdir=tmp_path)
    assert [r.kernel for r in results] == list(microbench.KERNELS)
    published = [r for r in results if r.published is not None]
    assert published, f"{cpu}: no kernel with a published figure"
    for r in published:
        assert r.within, (f"{cpu} {r.kernel}: model {r.steady_per_iteration:.2f} cycles/iteration, published "
                          f"{r.published} ({r.source})")
    for r in results:  # the cold pipeline is never cheaper than the steady state
        assert r.cold_per_iteration >= r.steady_per_iteration - 1e-9


def _mca(cpu: str, triple: str, text: str, iterations: int = 1) -> dict:
    features = [] if triple.startswith("aarch64") else ["-mattr=+neon,+vfp3"]
    out = subprocess.run([cycles.LLVM_MCA, f"-mtriple={triple}", f"-mcpu={cpu}", *features, f"-iterations={iterations}",
                          "-json", "-instruction-info", "-resource-pressure=0"], input=text, capture_output=True,
                         text=True, check=True).stdout
    return json.loads(out)["CodeRegions"][0]


def test_correction_table_names_llvm15s_own_figures(libs):
    """Every `llvm_latency` of rvd_pil/qemu/cycle_models.toml is what llvm-mca-15 gives the entry's example
    instruction (so the table still describes the LLVM it corrects)."""
    checked = 0
    for cpu, entry in cycles.models().items():
        for c in entry.get("correction", []):
            example = c["example"]
            ins = asm_dataflow.parse("aarch64" if entry["triple"].startswith("aarch64") else "armhf", example)
            corr = cycles.Correction(re.compile(c["mnemonic"]), re.compile(c.get("operand", "")), None, None, None,
                                     None, None, None, None, "", "", True)
            assert corr.matches(ins), f"{cpu}: example '{example}' does not match its own entry"
            if "llvm_latency" in c:
                info = _mca(entry["mca_cpu"], entry["triple"], example + "\n")
                assert info["InstructionInfoView"]["InstructionList"][0]["Latency"] == c["llvm_latency"], (cpu, example)
                checked += 1
            if "llvm_accumulate_latency" in c:  # a chain through the accumulator only
                chain = _mca(entry["mca_cpu"], entry["triple"], c["accumulate_chain"] + "\n", iterations=200)
                per = chain["SummaryView"]["TotalCycles"] / 200
                assert per == pytest.approx(c["llvm_accumulate_latency"], abs=0.1), (cpu, c["accumulate_chain"])
                checked += 1
            if "llvm_occupancy" in c:
                info = _mca(entry["mca_cpu"], entry["triple"], example + "\n")
                assert info["InstructionInfoView"]["InstructionList"][0]["RThroughput"] == pytest.approx(
                    c["llvm_occupancy"]), (cpu, example)
                checked += 1
    assert checked >= 10


def test_calls_cost_a_branch_not_llvm_mca_s_hundred_cycles(libs):
    """llvm-mca charges a call 100 cycles; the rewrite prices BL / BLR / BLX as the branch they are."""
    lines, n = cycles.rewrite_for_mca("aarch64", ["bl\t#100", "blr\tx3", "ret"])
    assert lines == ["b\t#100", "br\tx3", "ret"] and n == 2
    assert _mca("cortex-a53", "aarch64-linux-gnu", "\n".join(lines) + "\n", 100)["SummaryView"]["TotalCycles"] < 400
    lines, n = cycles.rewrite_for_mca("armhf", ["bl\t#100", "blx\tr3", "push\t{r4, r5, r6, lr}", "pop\t{r4, r5, r6, pc}",
                                                "itt\teq", "moveq\tr0, #1", "vpush\t{d8, d9}"])
    assert n == 6 and not any(ln.startswith(("it", "push", "pop", "vpush")) for ln in lines)
    assert any(ln.startswith("mov\tr0") for ln in lines)  # the IT's condition left with the IT
    info = _mca("cortex-a9", "thumbv7a-linux-gnueabihf", "\n".join(lines) + "\n", 10)  # llvm-mca takes them all
    assert info["SummaryView"]["Instructions"] == 10 * len(lines)


def test_dataflow_parser_reads_registers_and_roles():
    i = asm_dataflow.parse("aarch64", "fmadd\td0, d1, d2, d0")
    assert i.dests == ("v0",) and set(i.srcs) == {"v0", "v1", "v2"} and i.acc == "v0"
    i = asm_dataflow.parse("aarch64", "ldp\tx29, x30, [sp], #16")
    assert set(i.dests) == {"r29", "r30", "sp"} and i.srcs == ("sp",) and i.is_load
    i = asm_dataflow.parse("aarch64", "str\td0, [x3, x2, lsl #3]")
    assert i.dests == () and set(i.srcs) == {"v0", "r3", "r2"} and i.is_store
    i = asm_dataflow.parse("aarch64", "subs\tx0, x0, #1")
    assert set(i.dests) == {"r0", "nzcv"}
    i = asm_dataflow.parse("armhf", "vmla.f64\td0, d1, d2")
    assert i.acc == "d0" and "d0" in i.srcs
    i = asm_dataflow.parse("armhf", "adds\tr0, #1")          # T32 two-operand form: r0 is read too
    assert "r0" in i.srcs and set(i.dests) == {"r0", "nzcv"}
    i = asm_dataflow.parse("armhf", "vldr\ts3, [r1]")        # s3 lives in d1
    assert i.dests == ("d1",)
    block = asm_dataflow.parse_block("armhf", ["cmp\tr0, #0", "ite\teq", "moveq\tr1, #1", "movne\tr1, #2"])
    assert "nzcv" in block[2].srcs and "r1" in block[3].srcs  # predicated: reads flags and its old value


def test_corrected_chain_moves_the_in_order_steady_state():
    """A block of 8 chained FMADDs: LLVM's A53 accumulate latency 10 replaced by 4 moves the
    steady state from 80 to 32 cycles, whatever llvm-mca's own figure (the delta applies)."""
    insns = [asm_dataflow.parse("aarch64", "fmadd\td0, d1, d2, d0") for _ in range(8)]
    corr = [cycles.Correction(re.compile("^fmadd$"), re.compile(r"^d"), 8, 10, 4, 10, None, None, None, "", "", True)]
    cold, steady, n = cycles.correct(insns, [10.0] * 8, corr, mca_cold=81, mca_steady=80, rthroughput=8, uops=8,
                                     dispatch=2, in_order=True)
    assert n == 8 and steady == pytest.approx(32) and cold < 81


def test_cortex_a8_prices_vfp_by_the_trm_table():
    vfp = cycles.models()["cortex-a8"]["vfp"]["cycles"]
    block = asm_dataflow.parse_block("armhf", ["vmla.f64\td0, d1, d2", "vadd.f64\td3, d4, d5", "adds\tr0, #1",
                                               "bne\t#-12"])
    steady, cold = cycles.a8_block_cycles(block, vfp)
    assert steady == vfp["vmla"][0] + vfp["vadd"][0]           # the VFP is busier than the 2 integer ops
    assert cold == vfp["vmla"][1] + vfp["vadd"][1] + 2


def test_memory_term_is_zero_without_misses_and_grows_with_them():
    model = cycles.CycleModel(targets.load("rpi3"))
    zero = dict.fromkeys(cycles.CACHE_FIELDS, 0)
    assert model.memory_cycles(zero) == (0, 0)
    some = dict(zero, load_l1_miss=100, load_l2_miss=10, store_l1_miss=50)
    lo, hi = model.memory_cycles(some)
    assert 0 < lo < hi
    assert model.memory_cycles(dict(some, load_l2_miss=20))[0] > lo


def test_perf_stat_output_is_parsed_and_refused_without_a_pmu():
    from rvd_pil.bench import calibrate

    # this machine's own `perf stat -x, -e cycles:u,instructions:u,L1-dcache-load-misses:u` (a VM: no PMU)
    vm = ("# started on Tue Dec  1 19:41:58 2026\n\n<not supported>,,cycles:u,0,100.00,,\n"
          "<not supported>,,instructions:u,0,100.00,,\n<not supported>,,L1-dcache-load-misses,0,100.00,,\n")
    with pytest.raises(ValueError, match="no usable PMU"):
        calibrate.parse_perf_csv(vm)
    board = "1234567,,cycles:u,1000,100.00,,\n1000000,,instructions:u,1000,100.00,1.23,insn per cycle\n" \
            "4567,,L1-dcache-load-misses:u,1000,100.00,,\n"
    assert calibrate.parse_perf_csv(board) == {"cycles": 1234567.0, "instructions": 1000000.0,
                                                "L1-dcache-load-misses": 4567.0}
    cmd = calibrate.board_command("pi@rpi3", "/tmp", "rvd_flight_sw", ["--connect", "tcp/10.0.0.2:7447"])
    assert cmd[:2] == ["ssh", "pi@rpi3"] and "perf stat -x, -o perf.csv -e cycles:u,instructions:u" in cmd[2]


def test_calibration_factor_is_applied_and_marked(libs, tmp_path, monkeypatch):
    """prepare (a real QEMU run of the ideal Case 1) then apply with a board measurement 1.25 x the
    model's nominal cycles: the factor is written, the model scales its nominal figures by it and
    marks them calibrated; a board run that executed other instructions is refused."""
    from rvd_pil.bench import calibrate

    t = targets.load("rpi3")
    if not shutil.which(t.compiler):
        pytest.skip(f"{t.compiler} missing: run tools/install-deps pil")
    pred = calibrate.prepare("rpi3", out=tmp_path)
    run = tmp_path / "rpi3" / pred["qemu_run"]
    perf = tmp_path / "perf.csv"
    cal = tmp_path / "calibration.toml"
    perf.write_text(f"{pred['cycles_nominal'] * 1.25:.0f},,cycles:u,1,100.00,,\n"
                    f"{pred['instructions'] * 1.003:.0f},,instructions:u,1,100.00,,\n"
                    f"{pred['l1d_load_misses']},,L1-dcache-load-misses:u,1,100.00,,\n")
    entry = calibrate.apply("rpi3", perf, run, "test board", out=tmp_path, calibration_file=cal)
    assert entry["factor"] == pytest.approx(1.25, abs=1e-3)
    monkeypatch.setattr(cycles, "CALIBRATION", cal)
    model = cycles.CycleModel(t)
    prof = cycles.read_profile(tmp_path / "rpi3" / "qemu.blocks")
    costs = model.block_costs(tmp_path / "rpi3" / pred["exe"], prof.blocks)
    c = model.region_cycles(prof.process, costs)
    assert c.calibrated and c.nominal == pytest.approx(1.25 * pred["cycles_nominal"], rel=1e-3)
    perf.write_text(f"{pred['cycles_nominal']:.0f},,cycles:u,1,100.00,,\n{pred['instructions'] * 1.05:.0f},,instructions:u,1,,\n"
                    f"1,,L1-dcache-load-misses:u,1,,\n")
    with pytest.raises(ValueError, match="not the same executable or inputs"):
        calibrate.apply("rpi3", perf, run, "test board", out=tmp_path, calibration_file=cal)
