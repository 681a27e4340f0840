"""Shared fixtures. BLAS threads are pinned to one: on a shared 2-core machine OpenBLAS threading made
scipy's small dense kernels ~100x slower, and the suite never needs BLAS parallelism."""
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(autouse=True)
def _no_cpu_override(monkeypatch):
    """A user's $QEMU_CPU must not change what the tests check (tests that swap the CPU set it)."""
    from rvd_pil.qemu import targets

    monkeypatch.delenv(targets.CPU_ENV, raising=False)


@pytest.fixture(scope="session")
def flight_exe() -> Path:
    """The native flight executable (built by `make build`, which `make test` runs first)."""
    from rvd_pil.host_sim.pil import find_flight_executable

    try:
        return find_flight_executable()
    except FileNotFoundError as exc:
        pytest.fail(str(exc))



@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """Under `make test` (RVD_REQUIRE_ALL_TESTS=1) the machine has everything installed, so a test that
    skips (a missing tool, an image not fetched) is a broken set-up and is reported as a failure with
    its reason instead of hiding behind a skip. Run by hand, skips stay skips."""
    outcome = yield
    report = outcome.get_result()
    if report.skipped and os.environ.get("RVD_REQUIRE_ALL_TESTS") == "1" and not hasattr(report, "wasxfail"):
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
        report.outcome = "failed"
        report.longrepr = f"skipped under make test (everything should be installed): {reason}"


def pytest_collection_modifyitems(session, config, items):
    """Files with a slow test first (their order otherwise kept): `make test` runs one pytest worker
    per core, each file on one worker, and a long file started last would finish alone."""
    slow_files = {item.path for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: item.path not in slow_files)
