"""Shared by the QEMU user-mode tests: the counting plugin and a cross target, or a skip that says
which command fixes it (`make test` installs and fetches both, so none is skipped)."""
import os
import shutil

import pytest

from rvd_pil.qemu import plugin, targets


def counting_plugin_or_skip():
    """The instruction-counting plugin's library, built against Debian's qemu-plugin.h."""
    lib = plugin.build(download=os.environ.get("RVD_QEMU_FETCH") == "1")
    if lib is None:
        pytest.skip("counting plugin not built: run `python -m rvd_pil.qemu prepare` (or set RVD_QEMU_FETCH=1)")
    return lib


def cross_target_or_skip(name: str):
    """The target of rvd_pil/qemu/targets.toml, when its cross compiler is installed."""
    target = targets.load(name)
    if not shutil.which(target.compiler):
        pytest.skip(f"{target.compiler} missing: run tools/install-deps pil")
    return target
