"""rvd_pil.bench: the PIL campaign and its report (`python -m rvd_pil.bench.campaign`), and the benchmarks
that print figures side by side (solvers, link, cycle model, studies)."""
import sys as _sys

from rvd_pil import paths as _paths

# The QP generators and reference solvers, the QP-set file format and the Zenoh link harness live in
# the test suite's support package (tests/support of a checkout), shared with the benchmarks that use
# them (`support.<module>`; they say so when there is no checkout).
_root = _paths.checkout()
if _root is not None and str(_root / "tests") not in _sys.path:
    _sys.path.append(str(_root / "tests"))
