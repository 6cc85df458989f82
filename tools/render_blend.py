"""Render a .blend with Ember from the command line, using the bpy module.

    .venv/bin/python -P tools/render_blend.py                        # the Cornell box
    .venv/bin/python -P tools/render_blend.py scene.blend -o out/scene --samples 128
    .venv/bin/python -P tools/render_blend.py scene.blend --frames 1-24

Writes OUT.png (view transform applied, as Blender saves it) and OUT.exr
(scene-linear float) per frame, with a progress bar on stderr.  Exits with
status 1 and Ember's message when the render fails.  (-P keeps the script's
folder off sys.path.)
"""
import argparse
import os
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEFAULT_SCENE = os.path.join(ROOT, 'blend_scenes', 'cornell.blend')


def parse_args(argv):
    parser = argparse.ArgumentParser(description="Render a .blend file with Ember (bpy module).")
    parser.add_argument('blend', nargs='?', default=DEFAULT_SCENE, help="scene to render (default: Cornell box)")
    parser.add_argument('-o', '--output', help="output path without extension (default out/<scene name>)")
    parser.add_argument('--samples', type=int, help="samples per pixel (default: the scene's setting)")
    parser.add_argument('--percentage', type=int, help="resolution percentage")
    parser.add_argument('--frames', help="frame or range, e.g. 1 or 1-24 (default: current frame)")
    parser.add_argument('--seed', type=int, help="random seed")
    parser.add_argument('--no-progress', action='store_true', help="no progress bar")
    return parser.parse_args(argv)


def frame_list(text, current):
    if not text:
        return [current]
    first, _, last = text.partition('-')
    return list(range(int(first), int(last or first) + 1))


def save(scene, image, path, file_format):
    settings = scene.render.image_settings
    if hasattr(settings, 'media_type'):
        settings.media_type = 'IMAGE'  # Blender 5.0 refuses EXR for other media types
    settings.file_format = file_format
    if file_format == 'OPEN_EXR':
        settings.color_depth = '32'
    image.save_render(path, scene=scene)
    return path


def render(args):
    os.environ.setdefault('BLENDER_USER_RESOURCES', tempfile.mkdtemp(prefix='ember-cli-'))
    if ROOT not in sys.path:
        sys.path.insert(0, ROOT)
    import bpy
    import addon
    from addon import engine as ember_engine
    from addon import output

    addon.register()
    bpy.ops.wm.open_mainfile(filepath=os.path.abspath(args.blend))
    scene = bpy.context.scene
    scene.render.engine = 'EMBER'
    if args.samples:
        scene.ember.samples = args.samples
    if args.seed is not None:
        scene.ember.seed = args.seed
    if args.percentage:
        scene.render.resolution_percentage = args.percentage
    if not args.no_progress:
        output.progress_listeners.append(output.text_progress_bar())
    base = args.output or os.path.join(ROOT, 'out', os.path.splitext(os.path.basename(args.blend))[0])
    os.makedirs(os.path.dirname(os.path.abspath(base)), exist_ok=True)
    frames = frame_list(args.frames, scene.frame_current)
    for frame in frames:
        scene.frame_set(frame)
        del ember_engine.RENDER_LOG[:]
        try:
            bpy.ops.render.render()
        except RuntimeError as err:
            print(f"render failed: {err}".strip(), file=sys.stderr)
            return 1
        errors = [entry['error'] for entry in ember_engine.RENDER_LOG if entry['error']]
        if errors:
            print("render failed: " + "; ".join(errors), file=sys.stderr)
            return 1
        name = base if len(frames) == 1 else f"{base}_{frame:04d}"
        image = bpy.data.images['Render Result']
        for path in (save(scene, image, name + '.png', 'PNG'), save(scene, image, name + '.exr', 'OPEN_EXR')):
            print("saved", path)
        for entry in ember_engine.RENDER_LOG:
            for warning in entry['warnings']:
                print("warning:", warning, file=sys.stderr)
            print(f"layer {entry['layer']}: {entry.get('samples')} samples in {entry['seconds']:.2f} s "
                  f"(export {entry.get('export_seconds', 0):.3f} s, first pass after "
                  f"{entry.get('first_pass_seconds') or 0:.2f} s)")
    return 0


if __name__ == '__main__':
    sys.exit(render(parse_args(sys.argv[1:])))
