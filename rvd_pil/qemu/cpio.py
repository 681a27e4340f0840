"""A minimal writer of the cpio "newc" format the Linux initramfs loader reads.

Written here rather than calling cpio(1) so an initramfs can hold device nodes (/dev/console)
without root, and so archives are byte-identical from run to run (fixed owners and times).
The kernel accepts several archives concatenated: a cached base image plus a small archive with
the program under test.
"""
from __future__ import annotations

import stat
from pathlib import Path


class CpioWriter:
    def __init__(self) -> None:
        self._out = bytearray()
        self._ino = 1

    def _entry(self, name: str, mode: int, data: bytes = b"", rdev: tuple[int, int] = (0, 0)) -> None:
        name_bytes = name.lstrip("/").encode() + b"\0"
        fields = [self._ino, mode, 0, 0, 1, 0, len(data), 0, 0, rdev[0], rdev[1], len(name_bytes), 0]
        self._ino += 1
        self._out += b"070701" + b"".join(b"%08X" % f for f in fields) + name_bytes
        self._out += b"\0" * (-len(self._out) % 4)
        self._out += data
        self._out += b"\0" * (-len(self._out) % 4)

    def directory(self, name: str) -> None:
        self._entry(name, stat.S_IFDIR | 0o755)

    def file(self, name: str, data: bytes, executable: bool = False) -> None:
        self._entry(name, stat.S_IFREG | (0o755 if executable else 0o644), data)

    def symlink(self, name: str, target: str) -> None:
        self._entry(name, stat.S_IFLNK | 0o777, target.encode())

    def char_device(self, name: str, major: int, minor: int) -> None:
        self._entry(name, stat.S_IFCHR | 0o600, rdev=(major, minor))

    def finish(self) -> bytes:
        self._entry("TRAILER!!!", 0)
        return bytes(self._out)

    def write(self, path: Path) -> Path:
        path.write_bytes(self.finish())
        return path
