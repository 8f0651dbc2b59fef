"""The mutation harness's own list (benchmarks/mutants.py): every mutant's original text
occurs exactly once in its file, differs from its replacement, and names tests that exist.
Runs no mutant (that is `python -m benchmarks.mutation`, minutes to an hour)."""

from pathlib import Path

import pytest

from benchmarks.mutants import MUTANTS
from benchmarks.mutation import MutantError, check


ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("mutant", MUTANTS, ids=[m.name for m in MUTANTS])
def test_mutant_applies_exactly_once(mutant):
    mutated = check(mutant)
    assert mutated.count(mutant.replacement) >= 1
    for node in mutant.tests:
        path, _, name = node.partition("::")
        assert (ROOT / path).is_file(), node
        if name:
            assert f"def {name.partition('[')[0]}(" in (ROOT / path).read_text(), node


def test_names_unique_and_enough():
    names = [m.name for m in MUTANTS]
    assert len(names) == len(set(names))
    assert len(MUTANTS) >= 60


def test_check_rejects_ambiguous_and_missing_text(tmp_path):
    m = MUTANTS[0]
    (tmp_path / m.file).parent.mkdir(parents=True)
    text = (ROOT / m.file).read_text()
    (tmp_path / m.file).write_text(text + "\n# " + m.original + "\n")
    with pytest.raises(MutantError, match="occurs 2 times"):
        check(m, tmp_path)
    (tmp_path / m.file).write_text(text.replace(m.original, ""))
    with pytest.raises(MutantError, match="occurs 0 times"):
        check(m, tmp_path)


def test_equivalent_mutants_are_off_the_list():
    from benchmarks.mutants import EQUIVALENT

    assert not set(EQUIVALENT) & {m.name for m in MUTANTS}
    for file, _, reason in EQUIVALENT.values():
        assert (ROOT / file).is_file() and reason
