"""Mutation table: does the suite see small, realistic errors?

    PYTHONPATH=. .venv/bin/python tools/mutate.py            # every mutation (make mutate)
    PYTHONPATH=. .venv/bin/python tools/mutate.py --list     # what they are
    PYTHONPATH=. .venv/bin/python tools/mutate.py fresnel rr # some of them (name prefixes)

Each mutation is one edit of the engine's source (a light's power x 0.99, a
pdf x 1.01, ...), applied to a copy of the working tree in a temporary
folder (the checkout itself is never touched), followed by the tests that
should catch it, run in that copy with EMBER_JIT=0 (the NumPy form of the
kernels, which is what the edit changes; no numba compile).  A mutation is
*killed* when one of its tests fails on an assertion; the table shows which
test and the statistic it reported.  A mutation that survives means the
suite lacks power there: the tool exits with status 1.

The unmutated tree must pass the same tests (the normal suite checks that);
``--baseline`` runs them once on an unmutated copy first.
"""
import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
COPY_IGNORE = shutil.ignore_patterns('.git', 'out', 'dist', '__pycache__', '.pytest_cache', '*.pyc',
                                     '.venv', 'build')
# The environments are linked, not copied: no mutation edits them, and a copy
# of .venv (over 1 GiB) per mutation was most of a run's time.
SHARED_DIRS = ('.venv', 'build')


@dataclass
class Mutation:
    name: str
    what: str          # the table's description
    path: str          # file in the tree
    find: str          # exact text, found once
    replace: str
    tests: tuple       # pytest node ids (relative to the tree), tried in order


MUTATIONS = [
    Mutation('light_power', "a light's power x 0.99 (point and spot lights)", 'engine/lights/point.py',
             'pw = np.array([l.power for l in lights], float).reshape(-1, 3)',
             'pw = 0.99 * np.array([l.power for l in lights], float).reshape(-1, 3)',
             ('tests/engine/test_render_api.py::test_max_bounces_zero_is_direct_light',
              'tests/engine/test_render_api.py::test_spot_cone_and_blend')),
    Mutation('pdf', "a BSDF sample's pdf x 1.01 (the weight f cos / pdf of multi-lobe materials)", 'engine/bsdf.py',
             'fs * (np.abs(wi[:, 2]) / np.where(ok, ps, 1.0))[:, None], 0.0)',
             'fs * (np.abs(wi[:, 2]) / np.where(ok, 1.01 * ps, 1.0))[:, None], 0.0)',
             ('tests/engine/test_integrator.py::test_mixed_lobes_furnace',
              'tests/engine/test_materials.py::test_lobe_sampling')),
    Mutation('fresnel', "the dielectric Fresnel term 1 % high", 'engine/microfacet.py',
             '        f = 0.5 * (rs * rs + rp * rp)\n    f = np.where(tir',
             '        f = 0.505 * (rs * rs + rp * rp)\n    f = np.where(tir',
             ('tests/engine/test_materials.py::test_smooth_dielectric_layer_weight_is_textbook_fresnel',
              'tests/engine/test_materials.py::test_smooth_glass_branches_are_fresnel',
              'tests/engine/test_materials.py::test_smooth_glass_plane_renders_fresnel')),
    Mutation('mis_squared', "NEE's MIS weight squared", 'engine/nee.py',
             'w[:] = np.where(delta, 1.0, power_heuristic(p_mis * light_pdf, pdf_b)) if mis else 1.0',
             'w[:] = np.where(delta, 1.0, power_heuristic(p_mis * light_pdf, pdf_b) ** 2) if mis else 1.0',
             ('tests/engine/test_integrator.py::test_disk_light_irradiance',)),
    Mutation('cosine', "the receiver's cosine dropped at the NEE vertex", 'engine/nee.py',
             'cos = np.abs(wi_l[:, 2])\n', 'cos = np.where(wi_l[:, 2] != 0, 1.0, 0.0)\n',
             ('tests/engine/test_render_api.py::test_max_bounces_zero_is_direct_light',
              'tests/engine/test_integrator.py::test_disk_light_irradiance')),
    Mutation('rr', "Russian roulette's survival weight off by 2 %", 'engine/throughput.py',
             'b = b / np.where(survive, np.maximum(q, 1e-30), 1.0)[:, None]',
             'b = b / np.where(survive, np.maximum(q, 1e-30) * 1.02, 1.0)[:, None]',
             ('tests/engine/test_integrator.py::test_russian_roulette_is_unbiased',)),
    Mutation('colour_space', "an sRGB image's decoding to linear skipped", 'engine/textures.py',
             '            rgba[:, :3] = srgb_to_linear(rgba[:, :3])\n        return rgba',
             '            pass\n        return rgba',
             ('tests/engine/test_textures.py::test_srgb_images_filter_encoded_and_decode_after',)),
    Mutation('hash', "the node hash's seed off by one bit (lookup3's 0xdeadbeef)", 'engine/nodes/hashing.py',
             'init = U32((0xDEADBEEF + (n << 2) + 13) & 0xFFFFFFFF)',
             'init = U32((0xDEADBEEE + (n << 2) + 13) & 0xFFFFFFFF)',
             ('tests/engine/test_nodes.py::test_lookup3_matches_its_reference_values',)),
    Mutation('phase', "a phase function's value (= its pdf) x 1.02 where light samples read it",
             'engine/media/phase.py',
             '        f[two] = (1.0 - w[two]) * f[two] + w[two] * _lobe_eval(k2[two], a2[two], b2[two], cos[two])\n'
             '    return f\n',
             '        f[two] = (1.0 - w[two]) * f[two] + w[two] * _lobe_eval(k2[two], a2[two], b2[two], cos[two])\n'
             '    return 1.02 * f\n',
             ('tests/engine/test_media_field.py::test_phase_functions_integrate_to_one',
              'tests/engine/test_media.py::test_volume_strategies_agree')),
    Mutation('glass_shadowing', "rough glass refraction's Smith term uncorrelated (f only: its pdf and "
             "sampling stay right)", 'engine/lobes/glass.py',
             'trans * (common / ((1.0 + lo + li) * -wi[t, 2]))',
             'trans * (common / ((1.0 + lo) * (1.0 + li) * -wi[t, 2]))',
             ('tests/engine/test_glass_albedo_truth.py::test_single_scatter_glass_albedo_is_cycles_table',)),
]
# The mutations edit the
# NumPy forms (what EMBER_JIT=0 runs); the compiled twins in bsdf_loops.py,
# nee.py's and throughput.py's row loops are held to them by
# tests/engine/test_kernels.py with the JIT on.


def copy_tree(folder):
    target = os.path.join(folder, 'tree')
    shutil.copytree(ROOT, target, symlinks=True, ignore=COPY_IGNORE)
    for name in SHARED_DIRS:
        source = os.path.join(ROOT, name)
        if os.path.exists(source):
            os.symlink(os.path.realpath(source), os.path.join(target, name))
    return target


def apply(tree, mutation):
    path = os.path.join(tree, mutation.path)
    with open(path, encoding='utf-8') as handle:
        text = handle.read()
    count = text.count(mutation.find)
    if count != 1:
        raise SystemExit(f"{mutation.name}: the text to mutate occurs {count} times in {mutation.path} "
                         f"(the source moved on: update tools/mutate.py)")
    with open(path, 'w', encoding='utf-8') as handle:
        handle.write(text.replace(mutation.find, mutation.replace))


def run_test(tree, node):
    """(passed, the failure's statistic or error line, seconds)."""
    env = dict(os.environ, EMBER_JIT='0', PYTHONPATH=tree, PYTHONDONTWRITEBYTECODE='1')
    env.pop('CI', None)
    start = time.perf_counter()
    proc = subprocess.run([os.path.join(tree, '.venv', 'bin', 'python'), '-m', 'pytest', node, '-x', '-q', '-s',
                           '-p', 'no:cacheprovider', '--tb=short'], cwd=tree, env=env, capture_output=True,
                          text=True)
    seconds = time.perf_counter() - start
    out = proc.stdout + proc.stderr
    if proc.returncode == 0:
        return True, '', seconds
    if proc.returncode != 1 or 'AssertionError' not in out and 'assert' not in out:
        # Not a failed assertion (an import error, a crash): the mutation broke the code, which
        # proves nothing about the test's power.
        raise SystemExit(f"{node}: pytest ended with status {proc.returncode}, not a failed assertion:\n"
                         f"{out[-3000:]}")
    return False, statistic(out), seconds


def statistic(out):
    """The failing test's most telling line: its assertion message, else the
    last line it printed with a z, t or relative error."""
    lines = out.splitlines()
    errors = [line[1:].strip() for line in lines if line.startswith('E ') and line[1:].strip()]
    message = next((e for e in errors if re.search(r'AssertionError|Mismatched|max|z |t=|differ|off', e)), None)
    message = message or (errors[0] if errors else '')
    printed = [re.sub(r'^E\s+', '', line.strip()) for line in lines if re.search(r'\bz [-+]?\d|\bz=|t=|max \|z\||relative', line)]
    bare = re.fullmatch(r'assert (?:abs\()?([-+0-9.e]+)\)? < ([-+0-9.e]+)', message)
    if bare and printed:        # "assert 5.0 < 4.06": the test's printed line says what was compared
        text = f"{printed[-1]} (limit {float(bare.group(2)):.2f})"
    else:
        text = message if len(message) > 20 or not printed else printed[-1]
    text = text.replace('AssertionError: ', '').replace('|', '/')
    return text if len(text) <= 160 else text[:157] + '...'


def run_mutation(mutation, folder):
    tree = copy_tree(folder)
    try:
        apply(tree, mutation)
        for node in mutation.tests:
            passed, stat, seconds = run_test(tree, node)
            if not passed:
                return node, stat, seconds
        return None, '', 0.0
    finally:
        shutil.rmtree(tree, ignore_errors=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('names', nargs='*', help='mutation name prefixes (default: all)')
    ap.add_argument('--list', action='store_true')
    ap.add_argument('--baseline', action='store_true', help='run the tests on an unmutated copy first')
    args = ap.parse_args(argv)
    chosen = [m for m in MUTATIONS if not args.names or any(m.name.startswith(n) for n in args.names)]
    if args.list:
        for m in chosen:
            print(f"{m.name:14} {m.what}\n{'':14} {m.path}: {m.find.strip()!r} -> {m.replace.strip()!r}\n"
                  f"{'':14} tests: {', '.join(m.tests)}")
        return 0
    start = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory(prefix='ember-mutate-') as folder:
        if args.baseline:
            tree = copy_tree(folder)
            for node in sorted({n for m in chosen for n in m.tests}):
                passed, stat, _ = run_test(tree, node)
                if not passed:
                    raise SystemExit(f"the unmutated tree fails {node}: {stat}")
            shutil.rmtree(tree)
            print("baseline: every targeted test passes unmutated", flush=True)
        for m in chosen:
            killer, stat, seconds = run_mutation(m, folder)
            rows.append((m, killer, stat, seconds))
            print(f"{m.name}: {'killed by ' + killer if killer else 'SURVIVED'} ({seconds:.0f} s) {stat}",
                  flush=True)
    print(f"\n| mutation | killed by | statistic |\n|---|---|---|")
    for m, killer, stat, _ in rows:
        test = killer.split('::', 1)[1] if killer else '**survived**'
        print(f"| {m.what} (`{m.path}`) | `{os.path.basename(killer.split('::')[0]) if killer else ''}` "
              f"{test} | {stat} |")
    survivors = [m.name for m, killer, _, _ in rows if killer is None]
    print(f"\n{len(rows) - len(survivors)} of {len(rows)} killed in {time.perf_counter() - start:.0f} s"
          + (f"; SURVIVED: {', '.join(survivors)}" if survivors else ''))
    return 1 if survivors else 0


if __name__ == '__main__':
    sys.exit(main())
