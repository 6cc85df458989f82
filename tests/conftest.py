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
    scripts = blender34.unpack_addon(zip_path, folder / 'user')
    print(f"\nBlender 3.4: {blender34.compile_kernels(scripts)}")
    return zip_path, scripts


def pytest_configure(config):
    config.ember_worker_families = []
    config.addinivalue_line("markers", "xdist_group(name): pytest-xdist runs a group on one worker")


def pytest_collection_modifyitems(config, items):
    """Under pytest-xdist (``-n 2 --dist loadgroup``) each test file runs
    whole on one worker, so its module fixtures (references, renders) are
    built once; every test of Debian's 3.4 binary shares one worker, so the
    session's legacy install compiles its kernels once."""
    for item in items:
        group = 'blender34' if 'legacy_addon' in item.fixturenames else item.nodeid.split('::')[0]
        item.add_marker(pytest.mark.xdist_group(group))


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    """pytest-xdist: a worker's statistical families join the controller's."""
    node.config.ember_worker_families.extend(getattr(node, 'workeroutput', {}).get('ember_families', []))


def _families(config):
    return ember_stats.families_used() + list(getattr(config, 'ember_worker_families', []))


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    used = _families(config)
    if not used:
        return
    line = (f"statistical families: {len(used)} of a budget of {ember_stats.FAMILIES} "
            f"(suite false-alarm rate <= {len(used) * ember_stats.FAMILY_ALPHA:.2%})")
    terminalreporter.write_line(line)


def pytest_sessionfinish(session, exitstatus):
    if hasattr(session.config, 'workeroutput'):   # an xdist worker: the controller counts
        session.config.workeroutput['ember_families'] = ember_stats.families_used()
        return
    used = _families(session.config)
    if len(used) > ember_stats.FAMILIES:
        print(f"\nthe suite ran {len(used)} statistical families, more than its budget of "
              f"{ember_stats.FAMILIES}: raise FAMILIES in tests/ember_stats.py (docs/testing.md)")
        session.exitstatus = 1
