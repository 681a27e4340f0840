"""rvd-pil: processor-in-the-loop harness for spacecraft rendezvous-and-docking guidance.

One import name for the whole project:

    rvd_pil.host_sim    the truth simulator, the PIL server and `rvd-run`
    rvd_pil.flight_sw   the flight software's C++ (guidance, solver, navigation) bound into Python
    rvd_pil.qemu        cross builds, QEMU user and system mode, the TCG plugins, the cycle model
    rvd_pil.bench       campaigns, reports and benchmarks
    rvd_pil.studies     studies (`rvd-study`)
"""
__version__ = "0.1.0"
