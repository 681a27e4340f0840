
import sys as _sys
from pathlib import Path as _Path

# The QP generators and reference solvers, the QP-set file format and the Zenoh link harness live in
# the test suite's support package (tests/support), shared with the benchmarks: `support.<module>`.
_TESTS = str(_Path(__file__).resolve().parents[1] / "tests")
if _TESTS not in _sys.path:
    _sys.path.append(_TESTS)
