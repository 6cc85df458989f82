"""Missing prerequisites: skip on a developer machine, FAIL under CI=true
(shared by tests/addon, tests/engine and tests/farm; no bpy here)."""
import os

import pytest


def in_ci():
    return os.environ.get('CI', '').lower() == 'true'


def require(condition, reason):
    """Skip locally, fail in CI, when a prerequisite is missing."""
    if condition:
        return
    if in_ci():
        pytest.fail("missing prerequisite (CI=true): " + reason)
    pytest.skip(reason)
