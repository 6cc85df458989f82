"""tests/prerequisites.py: a missing prerequisite fails the run unless the
person opts out by name (EMBER_ALLOW_SKIPS=1), and CI=true stays strict."""
import pytest

import prerequisites


@pytest.mark.parametrize("env,outcome", [
    ({}, pytest.fail.Exception),
    ({"EMBER_ALLOW_SKIPS": "1"}, pytest.skip.Exception),
    ({"EMBER_ALLOW_SKIPS": "1", "CI": "true"}, pytest.fail.Exception),
    ({"EMBER_ALLOW_SKIPS": "yes"}, pytest.fail.Exception),     # only the exact opt-out
    ({"CI": "true"}, pytest.fail.Exception),
])
def test_missing_prerequisite(monkeypatch, env, outcome):
    monkeypatch.delenv("CI", raising=False)
    monkeypatch.delenv("EMBER_ALLOW_SKIPS", raising=False)
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    with pytest.raises(outcome):
        prerequisites.require(False, "something missing")
    prerequisites.require(True, "present")      # a present prerequisite never stops a test
