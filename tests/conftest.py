"""Shared by tests/engine and tests/addon: the statistics module
(tests/ember_stats.py) on sys.path, and the suite's false-alarm budget
checked at the end of the session (docs/testing.md)."""
import os
import sys

TESTS = os.path.dirname(os.path.abspath(__file__))
if TESTS not in sys.path:
    sys.path.insert(0, TESTS)

import ember_stats  # noqa: E402
import pytest  # noqa: E402


@pytest.fixture(scope='session')
def legacy_addon(tmp_path_factory):
    """(zip path, BLENDER_USER_SCRIPTS folder) of the legacy zip, built and
    unpacked once for every Blender 3.4 binary test (tests/blender34.py)."""
    import blender34
    folder = tmp_path_factory.mktemp('legacy34')
    zip_path = blender34.build_legacy_zip(folder)
    return zip_path, blender34.unpack_addon(zip_path, folder / 'user')


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    used = ember_stats.families_used()
    if not used:
        return
    line = (f"statistical families: {len(used)} of a budget of {ember_stats.FAMILIES} "
            f"(suite false-alarm rate <= {len(used) * ember_stats.FAMILY_ALPHA:.2%})")
    terminalreporter.write_line(line)


def pytest_sessionfinish(session, exitstatus):
    used = ember_stats.families_used()
    if len(used) > ember_stats.FAMILIES:
        print(f"\nthe suite ran {len(used)} statistical families, more than its budget of "
              f"{ember_stats.FAMILIES}: raise FAMILIES in tests/ember_stats.py (docs/testing.md)")
        session.exitstatus = 1
