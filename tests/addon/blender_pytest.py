"""Runs pytest inside a real Blender binary:

    blender -b --factory-startup --python-exit-code 1 --python tests/addon/blender_pytest.py -- ARGS

EMBER_PYTEST_PATH names a folder holding pytest and its dependencies (the
calling test links them from its own interpreter), appended to sys.path so
Blender's own numpy stays first.
"""
import os
import sys

extra = os.environ.get('EMBER_PYTEST_PATH')
if extra:
    sys.path.append(extra)

import pytest  # noqa: E402

args = sys.argv[sys.argv.index('--') + 1:] if '--' in sys.argv else []
sys.exit(int(pytest.main(args)))
