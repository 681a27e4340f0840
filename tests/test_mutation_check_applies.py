"""The mutation check (rvd_pil/bench/mutation_check.py) edits the source text: each of its deliberate
defects must still find its line, exactly once, in the tree as it is now. Code that moves on under a
mutation would otherwise leave the check reporting "does not apply" instead of testing the suite."""
import pytest

from rvd_pil import paths
from rvd_pil.bench import mutation_check


@pytest.mark.parametrize("mutation", mutation_check.MUTATIONS, ids=lambda m: m.name)
def test_each_mutation_applies_exactly_once(mutation):
    root = paths.require_checkout("the mutation check")
    text = (root / mutation.path).read_text()
    assert text.count(mutation.old) == 1, f"{mutation.path}: the text mutation {mutation.name} edits occurs {text.count(mutation.old)} times"
    assert mutation.new != mutation.old
    for test in mutation.pytest:
        assert (root / test).is_file(), f"mutation {mutation.name} runs {test}, which does not exist"
