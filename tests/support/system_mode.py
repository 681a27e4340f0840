"""Shared by the QEMU system-mode tests: the target and its image, or a skip that says which
command fixes it."""
import os
import shutil

import pytest

from rvd_pil.qemu import system, targets


def system_mode_or_skip(name: str):
    """(target, system-mode image) for QEMU system mode; skips, saying which command fixes it, when
    the tools or the images are missing (`make test` installs and fetches both, so none is skipped)."""
    target = targets.load(name)
    if not shutil.which(target.compiler) or not shutil.which(target.qemu_system):
        pytest.skip(f"{target.compiler} or {target.qemu_system} missing: run tools/install-deps pil")
    img = system.image(target, download=os.environ.get("RVD_QEMU_FETCH") == "1")
    if img is None:
        pytest.skip("system-mode image not built: run `python -m rvd_pil.qemu prepare` (or set RVD_QEMU_FETCH=1)")
    return target, img
