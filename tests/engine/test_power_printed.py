"""Every statistical test prints its power (issue 27, item 3): the test
that draws on the suite's false-alarm budget (family_level, family_z, the
ember_stats block and region comparisons), itself or through its helpers,
prints the bias it detects with probability 1/2 (``detectable``,
``power_line``, a ``...detects`` value).  Read from the source by
tools/power_audit.py (ast, no test is run; well under a second)."""
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, 'tools'))

import power_audit  # noqa: E402


def test_every_statistical_test_prints_its_power():
    missing, statistical = power_audit.audit()
    print(f"{statistical} statistical tests found")
    assert statistical > 150, "the audit no longer finds the suite's statistical tests"
    assert not missing, "statistical tests without their power printed:\n" + "\n".join(
        f"  {node}: {lack}" for node, lack in missing)


def test_the_audit_sees_a_missing_power_line(tmp_path):
    """A test that spends a family and prints no power (or computes it and
    prints nothing) is reported, also through a helper; printing
    ``detectable`` clears it (the check can fail)."""
    (tmp_path / 'test_quiet.py').write_text(
        "from ember_stats import detectable, family_z\n\n"
        "def limit():\n    return family_z('x', 1)\n\n"
        "def test_no_power():\n    print(limit())\n\n"
        "def test_no_print():\n    assert detectable(0.01, limit()) < 1\n")
    (tmp_path / 'test_loud.py').write_text(
        "from ember_stats import detectable, family_level\n\n"
        "def test_loud():\n    level = family_level('x')\n    print(detectable(0.01, level))\n")
    missing, statistical = power_audit.audit(str(tmp_path))
    assert statistical == 3
    assert sorted((node.rsplit('::', 1)[1], lack) for node, lack in missing) == [
        ('test_no_power', 'no power'), ('test_no_print', 'no print')]
