"""The mutation table of `make mutate` (tools/mutate.py) stays runnable: each
mutation's text occurs exactly once in the file it edits, and each names a
test that exists.  (A refactor that moves the text would otherwise leave the
table silently stale until the next `make mutate`.)"""
import os
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, 'tools'))

import mutate  # noqa: E402


@pytest.mark.parametrize("mutation", mutate.MUTATIONS, ids=lambda m: m.name)
def test_mutation_applies_once(mutation):
    with open(os.path.join(ROOT, mutation.path), encoding='utf-8') as handle:
        text = handle.read()
    assert text.count(mutation.find) == 1, f"{mutation.name}: its text occurs {text.count(mutation.find)} times"
    for node in mutation.tests:
        path, _, name = node.partition('::')
        with open(os.path.join(ROOT, path), encoding='utf-8') as handle:
            assert f"def {name.split('[')[0]}(" in handle.read(), node
