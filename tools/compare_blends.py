"""Render .blend files with Ember and Cycles side by side and print a table.

    .venv/bin/python -P tools/compare_blends.py FOLDER_OR_FILE ... [--width 160]
        [--ember-samples 32] [--cycles-samples 128] [--timeout 600] [--json out.json]
        [--images DIR] [--markdown docs/real_scenes.md] [--jobs 1]

Per file: Cycles at --cycles-samples (the reference), Cycles at
--ember-samples with another seed (what Cycles' own noise at Ember's sample
count gives), Ember at --ember-samples.  Both engines get the file's bounce
limits, no denoising, no adaptive sampling, no clamping, and the same pixel
filter, so the table measures rendering, not settings.  Columns:

* mean: Ember's image mean / the reference's (Rec. 709 luminance);
* p90: the 90th percentile over 8x8 blocks of |block mean - reference| /
  (reference + 1% of the image mean);
* the same two for Cycles at Ember's samples (its noise floor);
* verdict: 'match' when Ember's mean is within max(5%, Cycles' own) and its
  p90 within max(15%, Cycles' own), as issue 23 defines it; 'blocks' when
  it passes that but its p90 is over 3x Cycles' own (and over 3%): a local
  difference the loose tolerances let through;
* Ember's time (export + render, seconds), Cycles' time at the reference
  samples, and Ember's warnings or error.

Every file renders in its own process (a crash or a hang costs one row).
"""
import argparse
import glob
import json
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BLOCK = 8


def parse_args(argv):
    parser = argparse.ArgumentParser(description="Ember against Cycles on a folder of .blend files.")
    parser.add_argument('paths', nargs='*', help=".blend files or folders (searched recursively)")
    parser.add_argument('--width', type=int, default=160)
    parser.add_argument('--ember-samples', type=int, default=32)
    parser.add_argument('--cycles-samples', type=int, default=128)
    parser.add_argument('--timeout', type=float, default=600.0, help="seconds per file")
    parser.add_argument('--json', help="also write the rows to this file")
    parser.add_argument('--jobs', type=int, default=1, help="files rendered at once (times then include "
                                                             "the others' contention)")
    parser.add_argument('--images', help="keep each file's images (Ember, Cycles' reference and its "
                                         "low-sample render) in DIR/<name>.npz for per-block looks")
    parser.add_argument('--markdown', help="also write the table as Markdown (date, commit, load) here")
    parser.add_argument('--one', help=argparse.SUPPRESS)       # internal: one file, JSON on stdout
    parser.add_argument('--out', help=argparse.SUPPRESS)
    return parser.parse_args(argv)


def blend_files(paths):
    found = []
    for path in paths:
        if os.path.isdir(path):
            found += sorted(glob.glob(os.path.join(path, '**', '*.blend'), recursive=True))
        elif path.endswith('.blend'):
            found.append(path)
    return found


# ----------------------------------------------------------------------------
# The child process: one file

def _luminance(rgba):
    import numpy as np
    return np.tensordot(rgba[..., :3], np.array([0.2126, 0.7152, 0.0722]), axes=1)


def _blocks(image):
    h, w = (image.shape[0] // BLOCK) * BLOCK, (image.shape[1] // BLOCK) * BLOCK
    return image[:h, :w].reshape(h // BLOCK, BLOCK, w // BLOCK, BLOCK).mean(axis=(1, 3))


def image_errors(image, reference):
    """(mean ratio, 90th percentile of relative block errors)."""
    import numpy as np
    img, ref = _luminance(image), _luminance(reference)
    ref_mean = float(ref.mean())
    if ref_mean <= 0:   # a black reference: equal only if Ember's is black too
        return (1.0 if float(img.mean()) <= 0 else float('inf')), 0.0
    ratio = float(img.mean()) / ref_mean
    if not image.shape[0] >= BLOCK <= image.shape[1]:
        return ratio, float('nan')
    bi, br = _blocks(img), _blocks(ref)
    rel = np.abs(bi - br) / (br + 0.01 * max(ref_mean, 1e-12))
    return ratio, float(np.percentile(rel, 90))


def _same_settings(scene, width):
    """Small, unclamped, undenoised, non-adaptive; Ember gets Cycles' limits."""
    render = scene.render
    aspect = (render.resolution_y * render.pixel_aspect_y) / max(render.resolution_x * render.pixel_aspect_x, 1)
    render.resolution_x, render.resolution_y = width, max(int(round(width * aspect)), 1)
    render.resolution_percentage = 100
    render.use_border = False
    cycles = scene.cycles
    cycles.device = 'CPU'
    cycles.use_denoising = False
    cycles.use_adaptive_sampling = False
    cycles.sample_clamp_direct = cycles.sample_clamp_indirect = 0.0
    cycles.use_animated_seed = False
    ember = scene.ember
    ember.use_denoising = False
    ember.use_adaptive_sampling = False
    ember.clamp = 0.0
    ember.time_limit = 0.0
    ember.max_bounces = cycles.max_bounces
    for name in ('transparent_max_bounces', 'diffuse_bounces', 'glossy_bounces', 'transmission_bounces'):
        setattr(ember, name, getattr(cycles, name))
    ember.filter_glossy = cycles.blur_glossy
    filt = getattr(cycles, 'pixel_filter_type', 'BLACKMAN_HARRIS')
    ember.filter_type = filt if filt in ('BLACKMAN_HARRIS', 'GAUSSIAN', 'BOX') else 'BLACKMAN_HARRIS'
    ember.filter_width = getattr(cycles, 'filter_width', 1.5)


def _frame_camera(bpy, scene):
    """The scene's first camera object, else a new one looking at its
    visible geometry (asset libraries and templates may set none); False
    when there is nothing to look at."""
    from mathutils import Vector
    cameras = [obj for obj in scene.objects if obj.type == 'CAMERA']
    if cameras:
        scene.camera = cameras[0]
        return True
    corners = [obj.matrix_world @ Vector(c) for obj in scene.objects
               if obj.type in ('MESH', 'CURVE', 'CURVES', 'POINTCLOUD', 'VOLUME', 'META', 'FONT', 'SURFACE')
               and obj.visible_get() and not obj.hide_render for c in obj.bound_box]
    if not corners:
        return False
    lo = Vector([min(c[i] for c in corners) for i in range(3)])
    hi = Vector([max(c[i] for c in corners) for i in range(3)])
    centre, radius = (lo + hi) / 2, max((hi - lo).length / 2, 1e-3)
    data = bpy.data.cameras.new("compare camera")
    data.lens = 50.0
    cam = bpy.data.objects.new("compare camera", data)
    scene.collection.objects.link(cam)
    # From the front-right and above, far enough for the bounding sphere to fit the 36 mm sensor.
    direction = Vector((0.6, -1.0, 0.5)).normalized()
    cam.location = centre + direction * (radius * 2.0 * data.lens / 36.0 + radius)
    cam.rotation_euler = (centre - cam.location).to_track_quat('-Z', 'Y').to_euler()
    data.clip_end = max(data.clip_end, 10.0 * radius * 4)
    scene.camera = cam
    return True


def _render(bpy, scene, folder, name):
    scene.render.image_settings.file_format = 'OPEN_EXR'
    scene.render.image_settings.color_depth = '32'
    started = time.perf_counter()
    bpy.ops.render.render()
    seconds = time.perf_counter() - started
    path = os.path.join(folder, name + '.exr')
    bpy.data.images['Render Result'].save_render(path)
    return _load(bpy, path), seconds


def _load(bpy, path):
    import numpy as np
    image = bpy.data.images.load(path)
    try:
        width, height = image.size
        pixels = np.empty(width * height * 4, np.float32)
        image.pixels.foreach_get(pixels)
    finally:
        bpy.data.images.remove(image)
    return pixels.reshape(height, width, 4)[::-1].astype(np.float64)


def compare_one(path, args):
    os.environ.setdefault('BLENDER_USER_RESOURCES', tempfile.mkdtemp(prefix='ember-compare-'))
    sys.path.insert(0, ROOT)
    import bpy
    import addon
    from addon import engine as ember_engine
    addon.register()
    bpy.ops.wm.open_mainfile(filepath=os.path.abspath(path))
    scene = bpy.context.scene
    if not any(layer.use for layer in scene.view_layers):
        return {'file': path, 'error': "no view layer is enabled for rendering (Blender renders nothing)"}
    framed = scene.camera is None
    if framed and not _frame_camera(bpy, scene):
        return {'file': path, 'error': "no camera and nothing to frame"}
    _same_settings(scene, args.width)
    folder = tempfile.mkdtemp(prefix='ember-compare-')
    scene.render.engine = 'CYCLES'
    scene.cycles.samples, scene.cycles.seed = args.cycles_samples, 0
    reference, cycles_seconds = _render(bpy, scene, folder, 'cycles_ref')
    scene.cycles.samples, scene.cycles.seed = args.ember_samples, 1
    cycles_low, _ = _render(bpy, scene, folder, 'cycles_low')
    scene.render.engine = 'EMBER'
    scene.ember.samples, scene.ember.seed = args.ember_samples, 1
    del ember_engine.RENDER_LOG[:]
    image, ember_seconds = _render(bpy, scene, folder, 'ember')
    log = ember_engine.RENDER_LOG[-1] if ember_engine.RENDER_LOG else {}
    if args.out:
        import numpy as np
        np.savez_compressed(args.out, ember=image, cycles=reference, cycles_low=cycles_low)
    ratio, p90 = image_errors(image, reference)
    c_ratio, c_p90 = image_errors(cycles_low, reference)
    warnings = sorted(set(log.get('warnings') or ()))
    if framed:
        warnings.insert(0, "(no scene camera: its first camera object or a new one framing the geometry)")
    return {'file': path, 'mean': ratio, 'p90': p90, 'cycles_mean': c_ratio, 'cycles_p90': c_p90,
            'ember_seconds': ember_seconds, 'cycles_seconds': cycles_seconds,
            'error': log.get('error'), 'warnings': warnings,
            'finite': bool(__import__('numpy').isfinite(image).all())}


# ----------------------------------------------------------------------------
# The parent: one child per file, then the table

def verdict(row):
    if row.get('error'):
        return 'error'
    if not row.get('finite', True):
        return 'non-finite'
    mean_tol = max(0.05, abs(row['cycles_mean'] - 1.0))
    p90_tol = max(0.15, row['cycles_p90'])
    ok = abs(row['mean'] - 1.0) <= mean_tol and row['p90'] <= p90_tol
    if not ok:
        return 'differs'
    # Within the issue's tolerances, yet blocks far off Cycles' own noise: a
    # local bias the image mean hides (a light missing from a tenth of the
    # image); 3x leaves room for Ember's own noise (0.3-1.05x Cycles' variance).
    if row['p90'] > max(3.0 * row['cycles_p90'], 0.03):
        return 'blocks'
    return 'match'


def run_child(path, args):
    cmd = [sys.executable, '-P', os.path.abspath(__file__), '--one', path,
           '--width', str(args.width), '--ember-samples', str(args.ember_samples),
           '--cycles-samples', str(args.cycles_samples)]
    if args.images:
        os.makedirs(args.images, exist_ok=True)
        cmd += ['--out', os.path.join(args.images, os.path.splitext(os.path.basename(path))[0] + '.npz')]
    env = dict(os.environ, PYTHONPATH=ROOT)
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout, env=env)
    except subprocess.TimeoutExpired:
        return {'file': path, 'error': f"timed out after {args.timeout:.0f} s"}
    for line in reversed(done.stdout.splitlines()):
        if line.startswith('EMBER-COMPARE '):
            return json.loads(line[len('EMBER-COMPARE '):])
    tail = (done.stderr or done.stdout).strip().splitlines()[-1:] or ["no output"]
    return {'file': path, 'error': f"exit {done.returncode}: {tail[0][:200]}"}


def label(path):
    """A short unique name: the last two folders' names for files of an
    installed Blender (bpy-5.0/... or debian/...), else the file's name."""
    import re
    match = re.search(r'site-packages/bpy/([0-9.]+)/(.*)$', path) or re.search(r'/usr/share/(blender)/(.*)$', path)
    if match:
        head = 'debian' if match.group(1) == 'blender' else 'bpy-' + match.group(1)
        return head + '/' + '/'.join(match.group(2).split('/')[-2:])
    return os.path.basename(path)


def print_table(rows):
    head = f"{'file':40s} {'mean':>6s} {'p90':>6s} {'cyc mean':>8s} {'cyc p90':>7s} {'verdict':>8s} " \
           f"{'ember s':>7s} {'cycles s':>8s}  warnings / error"
    print(head)
    print('-' * len(head))
    for row in rows:
        name = label(row['file'])[-40:]
        note = row.get('error') or '; '.join(row.get('warnings') or ())
        if 'mean' not in row:
            print(f"{name:40s} {'':>6s} {'':>6s} {'':>8s} {'':>7s} {'error':>8s} {'':>7s} {'':>8s}  {note}")
            continue
        print(f"{name:40s} {row['mean']:6.3f} {row['p90']:6.3f} {row['cycles_mean']:8.3f} "
              f"{row['cycles_p90']:7.3f} {verdict(row):>8s} {row['ember_seconds']:7.1f} "
              f"{row['cycles_seconds']:8.1f}  {note[:160]}")
    counts = {}
    for row in rows:
        counts[verdict(row)] = counts.get(verdict(row), 0) + 1
    print(', '.join(f"{k}: {v}" for k, v in sorted(counts.items())), f"(of {len(rows)})")


def _commit():
    try:
        done = subprocess.run(['git', '-C', ROOT, 'log', '-1', '--format=%h %cd', '--date=iso'],
                              capture_output=True, text=True, timeout=10)
        return done.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def write_markdown(path, rows, args, loads, started):
    """The table as Markdown: when, which commit, the machine's load."""
    lines = [f"Run {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime(started))} on commit {_commit()}; "
             f"load average (1 min) {loads[0]:.1f} at the start, {loads[1]:.1f} at the end (2 cores); "
             f"width {args.width}, Ember {args.ember_samples} spp, Cycles {args.cycles_samples} spp "
             f"(and {args.ember_samples} with another seed: its own noise).", "",
             "| file | mean | p90 | Cycles mean | Cycles p90 | verdict | Ember s | Cycles s | warnings / error |",
             "|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        name = label(row['file'])
        note = (row.get('error') or '; '.join(row.get('warnings') or ())).replace('|', '/')
        if 'mean' not in row:
            lines.append(f"| {name} | | | | | error | | | {note} |")
            continue
        lines.append(f"| {name} | {row['mean']:.3f} | {row['p90']:.3f} | {row['cycles_mean']:.3f} | "
                     f"{row['cycles_p90']:.3f} | {verdict(row)} | {row['ember_seconds']:.1f} | "
                     f"{row['cycles_seconds']:.1f} | {note} |")
    with open(path, 'w') as fh:
        fh.write('\n'.join(lines) + '\n')


def main(argv):
    args = parse_args(argv)
    if args.one:
        try:
            row = compare_one(args.one, args)
        except Exception as err:  # noqa: BLE001 - one row, not a dead table
            row = {'file': args.one, 'error': f"{type(err).__name__}: {err}"}
        print('EMBER-COMPARE ' + json.dumps(row))
        return 0
    files = blend_files(args.paths)
    if not files:
        print("no .blend files found", file=sys.stderr)
        return 1
    rows, started, load_start = [], time.time(), os.getloadavg()[0]
    from concurrent.futures import ThreadPoolExecutor

    def one(path):
        print(f"... {path}", file=sys.stderr, flush=True)
        return run_child(path, args)
    with ThreadPoolExecutor(max(args.jobs, 1)) as pool:   # threads only wait on the children
        rows = list(pool.map(one, files))
    print_table(rows)
    if args.json:
        with open(args.json, 'w') as fh:
            json.dump(rows, fh, indent=1)
    if args.markdown:
        write_markdown(args.markdown, rows, args, (load_start, os.getloadavg()[0]), started)
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
