"""Run records: one directory per run, written incrementally so a killed run keeps every step it
completed.

    <run_dir>/meta.json   scenario, seed, model options, versions, anything the caller adds;
                          rewritten atomically (temp file + rename), "status" running -> finished/failed
    <run_dir>/steps.csv   header + one line per control step (truth, measurement, command, realised
                          thrust, truth after, then the caller's extra columns)
    <run_dir>/events.csv  header + one line per event (faults such as "flight software lost")

Each line is written with a single os.write() on a file opened O_APPEND and unbuffered, so once a
step is logged it is in the kernel: a SIGKILL right after cannot lose it, and a kill during the
write can at worst leave a torn last line, which `load_run` drops. (Power loss is another matter:
pass fsync=True to also push every line to the disk.) Floats are written with repr(), so reading
them back with `load_run` gives the very same doubles.

meta.json names the process writing the record ("writer": pid, its start time, boot id, host name).
A record still "running" whose writer is gone (killed, crashed, the machine rebooted) is marked
"host died" by the next `load_run` (and meta.json rewritten so), with what is known about the end.

Some columns measure time on a clock (`TIMING_COLUMNS`: solve and step times on the flight clock,
the host's wall time or, under QEMU with --target-clock, target time (meta flight_hello.step_clock);
the link's round trip, host wall time); everything else in a run without wall-clock-dependent settings repeats bit for bit, which
`record_digest` checks in one number.
"""

from __future__ import annotations

import csv
import datetime as _dt
import functools
import hashlib
import io
import json
import math
import os
import platform
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

THRUSTER_LABELS = ("px", "mx", "py", "my", "pz", "mz")  # +x, -x, +y, -y, +z, -z
_STATE = ("x_m", "y_m", "z_m", "vx_mps", "vy_mps", "vz_mps")


def _state_cols(prefix: str) -> list[str]:
    return [f"{prefix}_{s}" for s in _STATE]


def _per_thruster(prefix: str, unit: str) -> list[str]:
    return [f"{prefix}_{label}{unit}" for label in THRUSTER_LABELS]


#: Columns every steps.csv starts with (truth_* at t_s, before the command; after_* at t_s + period_s).
STEP_COLUMNS: tuple[str, ...] = tuple(
    ["step", "t_s", "period_s", "delay_s"]
    + _state_cols("truth")
    + _state_cols("meas")
    + ["target_qw", "target_qx", "target_qy", "target_qz",
       "target_wx_rad_s", "target_wy_rad_s", "target_wz_rad_s",
       "port_x_m", "port_y_m", "port_z_m", "range_com_m", "range_port_m"]
    + _per_thruster("pulse_cmd", "_s")
    + _per_thruster("pulse_applied", "_s")
    + _per_thruster("dropped_mib", "")
    + _per_thruster("truncated", "")
    + _per_thruster("thrust_error", "_pct")
    + _per_thruster("dv", "_mps")
    + ["dv_x_mps", "dv_y_mps", "dv_z_mps"]
    + _state_cols("after")
)
EVENT_COLUMNS: tuple[str, ...] = ("wall_time_utc", "step", "t_s", "kind", "detail")
#: Per-step columns (where present) that measure time on some clock (flight_hello.step_clock says which), not the simulated run.
TIMING_COLUMNS: tuple[str, ...] = ("solve_time_us", "step_time_us", "round_trip_ms")
_RESERVED_META = {"format", "status", "created_utc", "versions", "columns", "extra_columns", "closed_utc",
                  "steps_written", "writer"}
HOST_DIED = "host died"


def _process_start_ticks(pid: int) -> int | None:
    """Start time of a process in clock ticks since boot (/proc/PID/stat field 22), None if gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat[stat.rindex(")") + 2:].split()  # after the command name, which may hold spaces
    if fields[0] in ("Z", "X"):                    # a zombie has finished
        return None
    return int(fields[19])


def _boot_id() -> str | None:
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        return None


def writer_identity() -> dict[str, Any]:
    """Who is writing a record: enough to tell later whether that process still runs."""
    return {"pid": os.getpid(), "start_ticks": _process_start_ticks(os.getpid()), "boot_id": _boot_id(),
            "hostname": socket.gethostname()}


def writer_alive(writer: Mapping[str, Any] | None) -> bool | None:
    """True/False when it can be told whether the process of `writer_identity()` still runs, else None
    (no identity, or written on another machine)."""
    if not writer or writer.get("hostname") != socket.gethostname() or writer.get("start_ticks") is None:
        return None
    if writer.get("boot_id") != _boot_id():
        return False  # the machine rebooted since
    return _process_start_ticks(int(writer["pid"])) == writer["start_ticks"]


def _utc_now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")


@functools.lru_cache(maxsize=1)
def _software_versions() -> tuple:
    return tuple(_collect_versions().items())


def software_versions() -> dict[str, Any]:
    """Versions of what produced a record (and the git commit of the source tree, if any)."""
    return dict(_software_versions())


def _collect_versions() -> dict[str, Any]:
    import scipy
    import pandas

    from . import __version__

    info: dict[str, Any] = {"host_sim": __version__, "python": sys.version.split()[0], "numpy": np.__version__,
                            "scipy": scipy.__version__, "pandas": pandas.__version__,
                            "platform": platform.platform()}
    here = Path(__file__).resolve().parent
    try:
        commit = subprocess.run(["git", "-C", str(here), "rev-parse", "HEAD"], capture_output=True, text=True,
                                timeout=5)
        if commit.returncode == 0:
            info["git_commit"] = commit.stdout.strip()
            dirty = subprocess.run(["git", "-C", str(here), "status", "--porcelain", "--untracked-files=no"],
                                   capture_output=True, text=True, timeout=5)
            info["git_dirty"] = bool(dirty.stdout.strip()) if dirty.returncode == 0 else None
    except (OSError, subprocess.SubprocessError):
        pass
    return info


def _json_ready(obj):
    if isinstance(obj, Mapping):
        return {str(key): _json_ready(v) for key, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_ready(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _json_ready(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    return obj


def _write_all(fd: int, data: bytes) -> None:
    """One write() call; loop only in the (regular-file-unusual) case of a short write."""
    view = memoryview(data)
    while view:
        written = os.write(fd, view)
        view = view[written:]


def _atomic_write_json(path: Path, obj) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump(obj, f, indent=2, sort_keys=False, allow_nan=True)
        f.write("\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _format(value) -> str:
    if value is None:
        return ""
    if isinstance(value, (bool, np.bool_)):
        return "1" if value else "0"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return repr(v) if math.isfinite(v) else ("nan" if math.isnan(v) else ("inf" if v > 0 else "-inf"))
    return str(value)


class RunRecorder:
    """Writes one run directory (see the module docstring). Use as a context manager, or call
    close(); an exception inside the `with` block marks the run "failed" and is re-raised.

    extra_columns: names of the caller's own per-step columns (solve time, iterations, status, ...),
    appended after STEP_COLUMNS and filled through log_step(..., name=value)."""

    def __init__(self, run_dir: str | Path, meta: Mapping[str, Any] | None = None,
                 extra_columns: Iterable[str] = (), *, fsync: bool = False):
        self.run_dir = Path(run_dir)
        self.fsync = bool(fsync)
        extra = tuple(str(c) for c in extra_columns)
        clash = set(extra) & set(STEP_COLUMNS)
        if clash or len(set(extra)) != len(extra):
            raise ValueError(f"extra columns must be new and unique; clashing or repeated: "
                             f"{sorted(clash) or sorted(c for c in extra if extra.count(c) > 1)}")
        bad = [c for c in extra if not c or any(ch in c for ch in ",\"\n\r")]
        if bad:
            raise ValueError(f"extra column names must be non-empty without commas, quotes or newlines: {bad!r}")
        self.extra_columns = extra
        self.columns = STEP_COLUMNS + extra
        self.run_dir.mkdir(parents=True, exist_ok=True)
        for name in ("meta.json", "steps.csv", "events.csv"):
            if (self.run_dir / name).exists():
                raise FileExistsError(f"{self.run_dir / name} exists: a run directory is written once "
                                      "(choose a new directory)")
        given = _json_ready(dict(meta or {}))
        reserved = set(given) & _RESERVED_META
        if reserved:
            raise ValueError(f"metadata keys {sorted(reserved)} are set by the recorder itself")
        self.meta: dict[str, Any] = {
            "format": "rvd-pil run record 1",
            "status": "running",
            "created_utc": _utc_now(),
            "versions": software_versions(),
            "columns": list(self.columns),
            "extra_columns": list(extra),
            "writer": writer_identity(),
        }
        self.meta.update(given)
        _atomic_write_json(self.run_dir / "meta.json", self.meta)
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND
        self._steps_fd = os.open(self.run_dir / "steps.csv", flags, 0o644)
        self._events_fd = os.open(self.run_dir / "events.csv", flags, 0o644)
        self._write(self._steps_fd, self.columns)
        self._write(self._events_fd, EVENT_COLUMNS)
        self.steps_written = 0

    # ---- writing ----------------------------------------------------------------------------
    def _write(self, fd: int, values: Iterable[Any]) -> None:
        buf = io.StringIO()
        csv.writer(buf, lineterminator="\n").writerow([_format(v) for v in values])
        _write_all(fd, buf.getvalue().encode("utf-8"))
        if self.fsync:
            os.fsync(fd)

    def write_row(self, row: Mapping[str, Any]) -> None:
        """Write one steps.csv line from a {column: value} mapping (missing columns stay empty)."""
        if self._steps_fd < 0:
            raise RuntimeError(f"run record {self.run_dir} is closed")
        unknown = set(row) - set(self.columns)
        if unknown:
            raise ValueError(f"unknown column(s) {sorted(unknown)}; declare extra columns when creating the "
                             "recorder")
        self._write(self._steps_fd, [row.get(c) for c in self.columns])
        self.steps_written += 1

    def log_step(self, measurement, result=None, *, target=None, truth_lvlh=None, **extra) -> None:
        """Log one control step.

        measurement: rvd_pil.host_sim.simulator.Measurement sent to the flight software;
        result: the StepResult of the command applied (None if there was none, e.g. the flight
          software was lost: then only truth/measurement are written, the command columns stay empty);
        target: rvd_pil.host_sim.attitude.TargetState at the measurement time (for the port and range to it);
        truth_lvlh: the true state at the measurement time, needed only when result is None;
        extra: values for the declared extra columns."""
        row: dict[str, Any] = dict(extra)
        row["step"] = measurement.step
        row["t_s"] = measurement.t_s
        truth = result.truth_before if result is not None else truth_lvlh
        if truth is not None:
            row.update(zip(_state_cols("truth"), np.asarray(truth, float)))
            row["range_com_m"] = float(np.linalg.norm(np.asarray(truth, float)[0:3]))
        row.update(zip(_state_cols("meas"), measurement.state))
        row.update(zip(("target_qw", "target_qx", "target_qy", "target_qz"), measurement.q_lvlh_body))
        row.update(zip(("target_wx_rad_s", "target_wy_rad_s", "target_wz_rad_s"), measurement.omega_body_rad_s))
        if target is not None:
            row.update(zip(("port_x_m", "port_y_m", "port_z_m"), target.port_position_lvlh_m))
            if truth is not None:
                row["range_port_m"] = float(np.linalg.norm(np.asarray(truth, float)[0:3] - target.port_position_lvlh_m))
        if result is not None:
            row["period_s"] = result.period_s
            row["delay_s"] = result.delay_s
            for prefix, unit, values in (("pulse_cmd", "_s", result.pulse_commanded_s),
                                         ("pulse_applied", "_s", result.pulse_applied_s),
                                         ("dropped_mib", "", result.dropped_mib),
                                         ("truncated", "", result.truncated),
                                         ("thrust_error", "_pct", result.thrust_error_percent),
                                         ("dv", "_mps", result.dv_thruster_mps)):
                row.update(zip(_per_thruster(prefix, unit), values))
            row.update(zip(("dv_x_mps", "dv_y_mps", "dv_z_mps"), result.dv_lvlh_mps))
            row.update(zip(_state_cols("after"), result.truth_after))
        self.write_row(row)

    def log_event(self, kind: str, detail: str = "", *, step: int | None = None, t_s: float | None = None) -> None:
        """Append an event line (e.g. kind="flight_software_lost", detail="no cmd for step 17 in 5 s")."""
        if self._events_fd < 0:
            raise RuntimeError(f"run record {self.run_dir} is closed")
        if not kind:
            raise ValueError("event kind must be a non-empty string")
        self._write(self._events_fd, (_utc_now(), step, t_s, kind, detail))

    def update_meta(self, **fields) -> None:
        """Add or change metadata fields (meta.json is rewritten atomically)."""
        self.meta.update(_json_ready(fields))
        _atomic_write_json(self.run_dir / "meta.json", self.meta)

    def close(self, status: str = "finished", **fields) -> None:
        """Mark the run `status` (finished / failed / ...) with optional result fields; idempotent."""
        if self._steps_fd < 0:
            return
        for fd in (self._steps_fd, self._events_fd):
            os.fsync(fd)
            os.close(fd)
        self._steps_fd = self._events_fd = -1
        self.update_meta(status=status, closed_utc=_utc_now(), steps_written=self.steps_written, **fields)

    def __enter__(self) -> "RunRecorder":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close("finished")
        else:
            self.close("failed", error=f"{exc_type.__name__}: {exc}")


# ---- reading ------------------------------------------------------------------------------------
def _read_complete_lines(path: Path) -> tuple[bytes, int]:
    """File content up to its last newline, and the number of bytes of a torn last line."""
    data = path.read_bytes() if path.exists() else b""
    cut = data.rfind(b"\n") + 1
    return data[:cut], len(data) - cut


def _exact_floats(pd) -> dict:
    """read_csv options that parse repr() floats to the same doubles: pandas 3's default parser
    does; pandas 2 needs the round-trip parser (its default can be 1 ulp off)."""
    return {} if int(pd.__version__.split(".")[0]) >= 3 else {"float_precision": "round_trip"}


def _mark_if_writer_died(run_dir: Path, meta: dict) -> dict:
    """A record left "running" by a process that no longer exists is marked HOST_DIED (meta.json
    rewritten if it can be); one whose writer cannot be checked gets a status note instead."""
    if meta.get("status") != "running":
        return meta
    alive = writer_alive(meta.get("writer"))
    if alive:
        return meta
    if alive is None:
        meta["status_note"] = ("still marked running; whether its writer lives cannot be told here "
                               f"(written by {meta.get('writer') or 'an unknown process'})")
        return meta
    data, _ = _read_complete_lines(run_dir / "steps.csv")
    meta.update(status=HOST_DIED, end=meta.get("end") or "host died",
                host_died={"detected_utc": _utc_now(), "steps_recorded": max(data.count(b"\n") - 1, 0),
                           "reason": f"the host process (pid {meta['writer']['pid']}) ended without closing the "
                                     "record; every step it logged before is kept"})
    try:
        _atomic_write_json(run_dir / "meta.json", meta)
    except OSError:
        pass  # a read-only record is still reported as such
    return meta


def load_run(path: str | Path):
    """(meta dict, steps DataFrame) of a run directory, also of a run killed mid-way: a torn last
    line is dropped (its size is in df.attrs["torn_tail_bytes"]). Floats read back bit-exactly. A
    record whose host died without closing it comes back (and stays) marked HOST_DIED."""
    import pandas as pd

    run_dir = Path(path)
    meta_path = run_dir / "meta.json"
    if not meta_path.is_file():
        raise FileNotFoundError(f"{run_dir} is not a run directory (no meta.json)")
    meta = _mark_if_writer_died(run_dir, json.loads(meta_path.read_text(encoding="utf-8")))
    data, torn = _read_complete_lines(run_dir / "steps.csv")
    columns = meta.get("columns", list(STEP_COLUMNS))
    if data.count(b"\n") <= 1:  # no file, header only, or a torn header
        df = pd.DataFrame({c: pd.Series(dtype=float) for c in columns})
    else:
        df = pd.read_csv(io.BytesIO(data), **_exact_floats(pd))
    df.attrs["torn_tail_bytes"] = torn
    return meta, df


def load_events(path: str | Path):
    """Events DataFrame of a run directory (torn last line dropped)."""
    import pandas as pd

    data, torn = _read_complete_lines(Path(path) / "events.csv")
    if data.count(b"\n") <= 1:
        df = pd.DataFrame({c: pd.Series(dtype=object) for c in EVENT_COLUMNS})
    else:
        df = pd.read_csv(io.BytesIO(data), **_exact_floats(pd), keep_default_na=False,
                         na_values={"step": [""], "t_s": [""]})
    df.attrs["torn_tail_bytes"] = torn
    return df


#: meta.json fields of a finished run that do not depend on when, where or how fast it ran.
DIGEST_META: tuple[str, ...] = ("status", "end", "docked", "steps", "t_end_s", "dv_total_mps", "dv_l1_mps",
                                "dv_per_phase_mps", "time_per_phase_s", "final_range_to_port_m", "nav_resends",
                                "late_commands", "rejected_messages", "invalid_commands", "scenario", "seed",
                                "truth", "delay_model", "columns")


def record_digest(path: str | Path) -> str:
    """SHA-256 (hex) of what a run's record says about the run itself: steps.csv without the
    TIMING_COLUMNS, events without their wall time, and the DIGEST_META fields of meta.json. Two
    runs of the same scenario and settings without wall-clock-dependent ones give the same digest
    exactly when their records are bit-identical apart from clock readings."""
    run_dir = Path(path)
    meta = json.loads((run_dir / "meta.json").read_text(encoding="utf-8"))
    h = hashlib.sha256()
    h.update(json.dumps({k: meta.get(k) for k in DIGEST_META}, sort_keys=True).encode())
    for name, skip in (("steps.csv", TIMING_COLUMNS), ("events.csv", ("wall_time_utc",))):
        data, _ = _read_complete_lines(run_dir / name)
        rows = list(csv.reader(io.StringIO(data.decode("utf-8"))))
        if not rows:
            continue
        keep = [i for i, c in enumerate(rows[0]) if c not in skip]
        for row in rows:
            h.update(("\x1f".join(row[i] for i in keep if i < len(row)) + "\n").encode())
    return h.hexdigest()
