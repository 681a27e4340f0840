"""A study's output folder, owned by that study and grid.

    OUT/study.json       owner: study name, quick or full, grid fingerprint (hash of every run key)
    OUT/study.toml       the study file as it was run
    OUT/runs/<key>/      one finished run record each (meta.json, steps.csv, events.csv,
                         flight_sw.log, metrics.json); a folder appears here only complete
    OUT/.incoming/       records being written (cleared on start: a killed writer leaves only here)
    OUT/ledger.jsonl     one line per run stored (or failed), appended with one write each
    OUT/.lock            held by the rvd-study working in the folder (one at a time)
    OUT/report/          report.html, figures, runs.csv/.parquet, summary tables

A run folder is written under .incoming and renamed into runs/ in one step, so a SIGKILL at any
moment leaves either the whole record or nothing of it; a resumed study computes exactly the runs
not yet in runs/. A folder that belongs to another study or another grid is refused, never merged.
"""
from __future__ import annotations

import datetime as _dt
import fcntl
import json
import os
import shutil
import time
from pathlib import Path

OWNER = "study.json"
FORMAT = "rvd-study output 1"


class OwnershipError(RuntimeError):
    """The output folder holds another study's or another grid's runs."""


def _utc() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


class Store:
    def __init__(self, out: str | Path):
        self.out = Path(out)
        self.runs = self.out / "runs"
        self.incoming = self.out / ".incoming"
        self.ledger = self.out / "ledger.jsonl"

    def check(self, owner: dict, grid: bool = True) -> None:
        """Raises OwnershipError unless the folder is new, empty, or already this study's and grid's
        (grid=False: the study and size only, before the grid is known)."""
        if not self.out.exists():
            return
        if not self.out.is_dir():
            raise OwnershipError(f"{self.out} exists and is not a folder")
        path = self.out / OWNER
        if not path.is_file():
            if any(self.out.iterdir()):
                raise OwnershipError(f"{self.out} is not empty and holds no study (no {OWNER}): "
                                     "choose an empty or new --out")
            return
        try:
            have = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise OwnershipError(f"{path} is unreadable ({exc})") from None
        for field, what in (("study", "study"), ("quick", "size (--quick or full)"), ("grid", "grid")):
            if field == "grid" and not grid:
                continue
            if have.get(field) != owner.get(field):
                raise OwnershipError(
                    f"{self.out} belongs to study {have.get('study')!r}"
                    f"{' (quick)' if have.get('quick') else ''} with grid {str(have.get('grid'))[:12]} "
                    f"({have.get('runs')} runs); this is {owner['study']!r}{' (quick)' if owner['quick'] else ''}"
                    + (f" with grid {owner['grid'][:12]} ({owner['runs']} runs)" if grid else "")
                    + f": another {what}. "
                    "Choose another --out (results of different grids are never merged)")

    def claim(self, owner: dict, study_file: Path) -> None:
        """Takes the folder for this process (refused while another rvd-study works in it)."""
        self.check(owner)
        self.runs.mkdir(parents=True, exist_ok=True)
        self._lock = open(self.out / ".lock", "a+")
        try:
            fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._lock.close()
            self._lock = None
            raise OwnershipError(f"{self.out} is in use by another rvd-study right now") from None
        if not (self.out / OWNER).is_file():
            tmp = self.out / f".{OWNER}.tmp"
            tmp.write_text(json.dumps({"format": FORMAT, **owner, "created_utc": _utc()}, indent=1) + "\n")
            os.replace(tmp, self.out / OWNER)
            shutil.copyfile(study_file, self.out / "study.toml")
        shutil.rmtree(self.incoming, ignore_errors=True)

    def release(self) -> None:
        lock = getattr(self, "_lock", None)
        if lock is not None:
            lock.close()  # closing drops the lock (so does the process's death)
            self._lock = None

    def finished(self) -> set[str]:
        """Keys of the runs stored complete."""
        if not self.runs.is_dir():
            return set()
        done = set()
        for d in self.runs.iterdir():
            meta = d / "meta.json"
            if not meta.is_file():
                continue
            try:
                m = json.loads(meta.read_text())
            except (OSError, json.JSONDecodeError):
                continue
            if m.get("status") == "finished" and (m.get("study_run") or {}).get("key") == d.name:
                done.add(d.name)
        return done

    def commit(self, result: dict) -> Path:
        """Writes one run's files (from a worker) and moves the folder into runs/ in one rename."""
        key = result["key"]
        final = self.runs / key
        if final.exists():  # the same content computed twice (e.g. a task re-run after a lost worker)
            self._log({"key": key, "event": "duplicate", "worker": result.get("worker")})
            return final
        tmp = self.incoming / f"{key}.{os.getpid()}"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        for name, data in result["files"].items():
            if "/" in name or name.startswith("."):
                raise ValueError(f"refusing a record file named {name!r}")
            (tmp / name).write_bytes(data)
        os.rename(tmp, final)
        self._log({"key": key, "event": "stored", "wall_s": round(result.get("wall_s", 0.0), 3),
                   "cpu_s": round(result.get("cpu_s", 0.0), 3), "worker": result.get("worker")})
        return final

    def failed(self, key: str, error: str) -> None:
        self._log({"key": key, "event": "failed", "error": error[:500]})

    def _log(self, entry: dict) -> None:
        line = (json.dumps({"utc": _utc(), "t": round(time.time(), 3), **entry}) + "\n").encode()
        fd = os.open(self.ledger, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        try:
            os.write(fd, line)
        finally:
            os.close(fd)

    def ledger_entries(self) -> list[dict]:
        if not self.ledger.is_file():
            return []
        out = []
        for line in self.ledger.read_text().splitlines():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                continue  # a torn last line after a kill
        return out
