"""Which statistical tests do not print their power?  (issue 27, item 3)

    PYTHONPATH=. .venv/bin/python tools/power_audit.py        # list them (exit 1 if any)

A test is *statistical* when it draws on the suite's false-alarm budget
(tests/ember_stats.py: ``family_level``, ``family_z``, the block and
region comparisons, ``FAMILY_ALPHA``), itself or through what it calls: the
functions of its own module (helpers, fixtures it names) and of the helper
modules of tests/ (ember_testlib, analytic, chi2, ...), followed by name.
Such a test must print its power: somewhere on that path a ``print`` and a
mention of the power (``detectable``, ``power_line``, a ``...detects`` value
or a text with "detect"), or ``report_mean_tests``, which prints both.

Read from the source (ast), so it costs nothing to run; names are matched
without types, so a helper of the same name in two modules links both (an
over-approximation: it can hide a missing print, never invent one).
tests/engine/test_power_printed.py runs it.
"""
import ast
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TESTS = os.path.join(ROOT, 'tests')
STATS = 'ember_stats'
BUDGET = {'family_level', 'family_z', 'failing_blocks', 'failing_blocks_var', 'failing_single',
          'region_mean_tests', 'region_mean_tests_var', 'FAMILY_ALPHA'}
POWER = {'detectable', 'power_line', 'report_mean_tests'}
PRINTS = {'print', 'report_mean_tests'}
# Tests that draw on the budget but are no comparison whose power means
# anything: each with its reason (a node id or a whole file).
EXEMPT = {
    'tests/engine/test_stats.py': "tests of ember_stats itself on synthetic data (they assert what it detects)",
    'tests/engine/test_sampling_chi2.py::test_chi2_helpers': "checks the chi-square helpers and the file's level",
    'tests/addon/test_viewport.py::test_moving_an_object_restarts_without_exporting_meshes':
        "asserts a difference (|z| above 10 x the family threshold), printed: no agreement test",
}


class Facts:
    """What one function (or module body) does by itself, and whom it calls."""

    def __init__(self):
        self.budget = self.power = self.prints = False
        self.calls = set()        # names called or referenced (helpers, fixtures, constants)


def _is_power_name(name):
    return name in POWER or 'detect' in name.lower()


def _scan(node, facts, skip_defs=True):
    for sub in ast.walk(node) if not skip_defs else _walk_no_defs(node):
        if isinstance(sub, ast.Name):
            facts.calls.add(sub.id)
            facts.budget |= sub.id in BUDGET
            facts.power |= _is_power_name(sub.id)
        elif isinstance(sub, ast.Attribute):
            facts.calls.add(sub.attr)
            facts.budget |= sub.attr in BUDGET
            facts.power |= _is_power_name(sub.attr)
        elif isinstance(sub, ast.Constant) and isinstance(sub.value, str):
            facts.power |= 'detect' in sub.value.lower()
        elif isinstance(sub, ast.Call):
            func = sub.func
            name = func.id if isinstance(func, ast.Name) else func.attr if isinstance(func, ast.Attribute) else ''
            facts.prints |= name in PRINTS
        elif isinstance(sub, ast.arg):
            facts.calls.add(sub.arg)            # a fixture named by a parameter
    return facts


def _walk_no_defs(node):
    """ast.walk, but a nested def or class is a function of its own."""
    todo = list(ast.iter_child_nodes(node))
    if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
        todo = list(node.args.args) + list(node.args.kwonlyargs) + node.body + node.decorator_list
    while todo:
        sub = todo.pop()
        yield sub
        if not isinstance(sub, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef, ast.Lambda)):
            todo.extend(ast.iter_child_nodes(sub))


def _module_facts(path):
    """{name: [Facts]} of every def and class in a file (a class: its body
    and methods together), plus the module-level names assigned from the
    budget (LEVEL = family_level(...)) as facts of their own."""
    with open(path, encoding='utf-8') as handle:
        tree = ast.parse(handle.read(), path)
    table = {}
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            table.setdefault(node.name, []).append(_scan(node, Facts()))
        elif isinstance(node, ast.ClassDef):
            table.setdefault(node.name, []).append(_scan(node, Facts(), skip_defs=False))
    for node in tree.body:
        if isinstance(node, (ast.Assign, ast.AnnAssign)):
            facts = _scan(node.value, Facts(), skip_defs=False) if node.value is not None else Facts()
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                for name in ast.walk(target):
                    if isinstance(name, ast.Name):
                        table.setdefault(name.id, []).append(facts)
    return tree, table


def _test_functions(tree):
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name.startswith('test'):
            yield node.name, node
        elif isinstance(node, ast.ClassDef) and node.name.startswith('Test'):
            for sub in node.body:
                if isinstance(sub, (ast.FunctionDef, ast.AsyncFunctionDef)) and sub.name.startswith('test'):
                    yield f"{node.name}::{sub.name}", sub


def _python_files(tests):
    for folder, dirs, files in os.walk(tests):
        dirs[:] = sorted(d for d in dirs if d not in ('data', '__pycache__'))
        for name in sorted(files):
            if name.endswith('.py'):
                yield os.path.join(folder, name)


def _imported(tree, parsed):
    """{name: [Facts]} of what a module imports by name from another file
    of tests/ (``from test_media_field import assert_image_mean``)."""
    tables = {os.path.splitext(os.path.basename(path))[0]: table for path, (_, table) in parsed.items()}
    out = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module in tables and node.module != STATS:
            for alias in node.names:
                out.setdefault(alias.asname or alias.name, []).extend(tables[node.module].get(alias.name, []))
    return out


def _closure(start, tables):
    """Union of the facts reachable from ``start`` by name, looked up in
    ``tables`` in order (this module, what it imports, the helper modules;
    never into ember_stats itself: its functions are the leaves the sets
    above name)."""
    seen, todo, out = set(), [start], Facts()
    while todo:
        facts = todo.pop()
        out.budget |= facts.budget
        out.power |= facts.power
        out.prints |= facts.prints
        for name in facts.calls - seen:
            seen.add(name)
            todo.extend(next((table[name] for table in tables if table.get(name)), []))
    return out


def audit(tests=TESTS):
    """[(test node id, what is missing)] of the statistical tests under
    ``tests`` that do not print their power, and the number of statistical
    tests found."""
    parsed = {path: _module_facts(path) for path in _python_files(tests)}
    helpers = {}
    for path, (_, table) in parsed.items():
        base = os.path.basename(path)
        if not base.startswith('test_') and base not in (f'{STATS}.py', 'conftest.py'):
            for name, facts in table.items():
                helpers.setdefault(name, []).extend(facts)
    missing, statistical = [], 0
    for path, (tree, table) in parsed.items():
        if not os.path.basename(path).startswith('test_'):
            continue
        for name, node in _test_functions(tree):
            facts = _closure(_scan(node, Facts()), (table, _imported(tree, parsed), helpers))
            if not facts.budget:
                continue
            statistical += 1
            node_id = f"{os.path.relpath(path, ROOT)}::{name}"
            if node_id in EXEMPT or os.path.relpath(path, ROOT) in EXEMPT:
                continue
            if not (facts.power and facts.prints):
                lack = 'no print' if facts.power else 'no power' if facts.prints else 'no print, no power'
                missing.append((node_id, lack))
    return missing, statistical


def main():
    missing, statistical = audit()
    for node, lack in missing:
        print(f"{node}: {lack}")
    print(f"{statistical} statistical tests, {len(missing)} without their power printed")
    return 1 if missing else 0


if __name__ == '__main__':
    sys.exit(main())
