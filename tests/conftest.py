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


def group_of(nodeid):
    """The worker group of a test: every test of Debian's 3.4 binary shares
    one worker (the session's legacy install compiles its kernels once, some
    four minutes), every other test file runs whole on one worker (its module
    fixtures, references and renders, are built once)."""
    path, _, name = nodeid.partition('::')
    return 'blender34' if 'blender_34' in name else path


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(config, items):
    """The 3.4 group is found by name, so a test that takes the legacy
    install must say so in its name."""
    for item in items:
        uses_legacy = 'legacy_addon' in getattr(item, 'fixturenames', ())
        assert uses_legacy <= (group_of(item.nodeid) == 'blender34'), (
            f"{item.nodeid} uses legacy_addon: put 'blender_34' in its name (tests/conftest.py group_of)")


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """pytest-xdist (``-n 2 --dist loadgroup``) with our groups.  xdist 3.8
    names a test's xdist_group by suffixing its node id, which pytest 9.2's
    node ids no longer take (every test was scheduled alone, so module
    fixtures were built on both workers): its scope scheduler with
    ``group_of`` as the scope instead."""
    if config.getvalue('dist') not in ('loadgroup', 'loadscope'):
        return None
    from xdist.scheduler import LoadScopeScheduling

    class Groups(LoadScopeScheduling):
        def _split_scope(self, nodeid):
            return group_of(nodeid)

    return Groups(config, log)


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
