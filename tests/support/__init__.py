"""Shared support of the test suite (imported as `support.<module>`: pytest puts tests/ on sys.path).
Independent references (CW matrix, quaternion and pyramid geometry, dense reference QP solvers), the
QP generators and QP-set file format the solver tests and rvd_pil/bench/ share, the Zenoh link harness, and
the system-mode guard. Nothing here imports a test module."""
