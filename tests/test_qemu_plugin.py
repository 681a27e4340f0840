"""The instruction-counting plugin under QEMU user mode, on the Q7S (armhf Cortex-A9) and the
Raspberry Pi 3 (aarch64 Cortex-A53).

Independent truth: the probe's marked loop is written in assembly with exactly two instructions
per iteration, so the count of a region of k iterations must be 2k plus a constant (the marker's
own instructions), to the instruction. Counts must also reach the guest (the slot the plugin
writes) equal to the plugin's own log, and repeat exactly from run to run.

Needs the plugin, built against the qemu-plugin.h of Debian's qemu source package (a download
that belongs to `make pil`): skipped until `python -m rvd_pil.qemu prepare` has run, or set
RVD_QEMU_FETCH=1 to let the test fetch it.
"""
from __future__ import annotations

import re
import subprocess

import pytest

from rvd_pil.qemu import build, plugin, targets, user
from rvd_pil.qemu.plugin import InsnCounter
from support.user_mode import counting_plugin_or_skip, cross_target_or_skip

pytestmark = pytest.mark.qemu

SPIN = 20_000
STEPS = 4


@pytest.fixture(scope="module")
def plugin_lib():
    return counting_plugin_or_skip()


@pytest.fixture(scope="module", params=["q7s", "rpi3"])
def probe(request):
    target = cross_target_or_skip(request.param)
    return target, build.cross_build(target, "qemu_probe").path


def _run(target, exe, args, log, count="inline", lib=None):
    proc = user.run(target, exe, args, plugin=InsnCounter(log=log, count=count, library=lib), timeout_s=120)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


def _counts(stdout):
    return {int(m.group(1)): int(m.group(2)) for m in re.finditer(r"step=(\d+) .*?insns=(\d+)", stdout)}


def test_counts_are_exact_written_back_and_repeatable(plugin_lib, probe, tmp_path):
    target, exe = probe
    args = ["markers", str(STEPS), str(SPIN), "llt", "24"]
    out1 = _run(target, exe, args, tmp_path / "a.log", lib=plugin_lib)
    out2 = _run(target, exe, args, tmp_path / "b.log", lib=plugin_lib)
    assert out1.splitlines()[-1] == "counting=1 status=0"
    counts = _counts(out1)
    assert sorted(counts) == list(range(STEPS + 1))

    # Exact: region s runs SPIN*(s+1) iterations of two instructions plus a constant overhead
    # (the first region also carries the marker's one-off probe of the plugin).
    overhead = [counts[s] - 2 * SPIN * (s + 1) for s in range(STEPS)]
    assert len(set(overhead[1:])) == 1, overhead
    assert 0 < overhead[1] < 100 and overhead[1] <= overhead[0] < overhead[1] + 50

    # The slot the guest reads back equals the plugin's own log, region by region.
    assert plugin.read_log(tmp_path / "a.log") == sorted(counts.items())
    assert "slot mismatches 0" in (tmp_path / "a.log").read_text()
    # Deterministic to the instruction, the Cholesky region included.
    assert _counts(out2) == counts
    assert plugin.read_log(tmp_path / "b.log") == plugin.read_log(tmp_path / "a.log")


def test_dense_kernel_count_grows_cubically(plugin_lib, probe, tmp_path):
    """Cholesky costs n^3/3 flops: doubling n multiplies the count by less than 8 (the O(n^2)
    part) and by more than 4 once n is past loop overheads."""
    target, exe = probe
    counts = _counts(_run(target, exe, ["llt", "60", "llt", "120"], tmp_path / "llt.log", lib=plugin_lib))
    ratio = counts[1] / counts[0]
    assert 4.0 < ratio < 8.0, counts


def test_per_thread_mode_counts_the_same_single_thread(plugin_lib, probe, tmp_path):
    target, exe = probe
    args = ["markers", "3", str(SPIN), "llt", "16"]
    inline = _counts(_run(target, exe, args, tmp_path / "i.log", "inline", plugin_lib))
    per_vcpu = _counts(_run(target, exe, args, tmp_path / "v.log", "vcpu", plugin_lib))
    assert per_vcpu == inline


def test_per_thread_mode_excludes_other_threads(plugin_lib, probe, tmp_path):
    """A second guest thread spins while the main thread runs a marked 2k-instruction loop:
    count=vcpu still counts exactly the main thread's loop; count=inline cannot and says so."""
    target, exe = probe
    k = 200_000
    out = _run(target, exe, ["markers", "1", "10", "threaded", str(k)], tmp_path / "v.log", "vcpu", plugin_lib)
    overhead = _counts(out)[1] - 2 * k
    assert 0 < overhead < 100, out
    assert "second thread" not in (tmp_path / "v.log").read_text()
    _run(target, exe, ["markers", "1", "10", "threaded", str(k)], tmp_path / "i.log", "inline", plugin_lib)
    assert "second thread" in (tmp_path / "i.log").read_text()


def test_plugin_refuses_unknown_arguments(plugin_lib, probe):
    target, exe = probe
    proc = subprocess.run([target.qemu_user, "-cpu", target.qemu_cpu, "-plugin", f"{plugin_lib},bogus=1",
                           str(exe), "markers", "1", "10"], capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0
    assert "unknown argument 'bogus=1'" in proc.stderr


def test_host_target_cannot_count(tmp_path):
    with pytest.raises(ValueError, match="needs QEMU"):
        user.command(targets.load("host"), "/bin/true", plugin=InsnCounter(log=tmp_path / "x"))


def test_wild_slot_pointer_is_logged_not_fatal(plugin_lib, probe, tmp_path):
    """A marker whose slot points at unmapped memory: the plugin must not write (or crash QEMU),
    it logs the mismatch and still records the count; later markers work normally."""
    target, exe = probe
    out = _run(target, exe, ["wild", "markers", "1", str(SPIN)], tmp_path / "w.log", lib=plugin_lib)
    assert "wild done" in out and out.splitlines()[-1] == "counting=1 status=0"
    log = (tmp_path / "w.log").read_text()
    assert "guest slot 0x1008 not writable" in log and "slot mismatches 2" in log
    steps = dict(plugin.read_log(tmp_path / "w.log"))
    assert steps[99] >= 2000  # the 1000-iteration loop between the wild markers was counted
    assert steps[0] == _counts(out)[0] > 2 * SPIN
