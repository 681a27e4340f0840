"""docs/tutorial.md is executed: every ```python block, in order, in one namespace, from a scratch
folder (so its runs and studies land there). A tutorial that no longer runs fails here."""
from __future__ import annotations

import re
from pathlib import Path

TUTORIAL = Path(__file__).resolve().parent.parent / "docs" / "tutorial.md"


def test_tutorial_runs(tmp_path, monkeypatch, flight_exe):
    blocks = re.findall(r"^```python\n(.*?)^```", TUTORIAL.read_text(), flags=re.S | re.M)
    assert len(blocks) >= 5
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    for i, code in enumerate(blocks):
        exec(compile(code, f"{TUTORIAL.name} block {i + 1}", "exec"), namespace)  # noqa: S102
    assert (tmp_path / "runs" / "case1-ideal" / "meta.json").is_file()
