"""Missing prerequisites FAIL the run unless the person opts out by name:
EMBER_ALLOW_SKIPS=1 turns them into skips (a developer machine without
Blender 3.4, say).  CI=true is strict whatever EMBER_ALLOW_SKIPS says, so a
runner cannot skip by accident.  Shared by tests/addon, tests/engine and
tests/farm; no bpy here."""
import os

import pytest


def in_ci():
    return os.environ.get('CI', '').lower() == 'true'


def skips_allowed():
    """True only when the person asked for skips by name and this is not CI."""
    return os.environ.get('EMBER_ALLOW_SKIPS', '') == '1' and not in_ci()


def require(condition, reason):
    """Fail when a prerequisite is missing; skip instead only when skips are
    allowed (EMBER_ALLOW_SKIPS=1, not CI)."""
    if condition:
        return
    if not skips_allowed():
        pytest.fail("missing prerequisite (set EMBER_ALLOW_SKIPS=1 to skip it outside CI): " + reason)
    pytest.skip(reason)
