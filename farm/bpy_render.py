"""Blender's ``-b FILE -o PATTERN -F FORMAT --python-expr CODE -f FRAMES`` for
the bpy module, with the repository's Ember add-on registered.  Run by farm
tasks when no Blender binary is given:

    python -P farm/bpy_render.py scene.blend -o out/frame_#### -F OPEN_EXR --python-expr CODE -f 1..4

Exits with status 1 and Ember's message if a render fails.
"""
import argparse
import os
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def parse(argv):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('blend')
    parser.add_argument('-o', '--render-output', dest='pattern', required=True)
    parser.add_argument('-F', '--render-format', dest='format', default='OPEN_EXR')
    parser.add_argument('--python-expr', dest='code', default='')
    parser.add_argument('-f', '--render-frame', dest='frames', required=True)
    # Accepted for Blender's command line (Flamenco passes them): background
    # mode is the only mode here, the engine is set by the code.
    parser.add_argument('-b', '--background', action='store_true')
    parser.add_argument('-y', '--enable-autoexec', action='store_true')
    parser.add_argument('-E', '--engine', default='EMBER')
    return parser.parse_args(argv)


def frames_of(text):
    out = []
    for part in text.split(','):
        first, _, last = part.partition('..')
        out += range(int(first), int(last or first) + 1)
    return out


def frame_path(pattern, frame):
    hashes = pattern.count('#')
    if hashes:
        run = '#' * hashes
        return pattern.replace(run, f"{frame:0{hashes}d}", 1) + '.exr'
    return f"{pattern}{frame:04d}.exr"


def main(argv):
    args = parse(argv)
    with tempfile.TemporaryDirectory(prefix='ember-farm-') as user:
        os.environ.setdefault('BLENDER_USER_RESOURCES', user)
        return render(args)


def render(args):
    sys.path.insert(0, ROOT)
    import bpy
    import addon
    from addon import engine as ember_engine
    addon.register()
    bpy.ops.wm.open_mainfile(filepath=os.path.abspath(args.blend))
    scene = bpy.context.scene
    scene.render.engine = 'EMBER'
    if args.code:
        exec(compile(args.code, '<python-expr>', 'exec'), {'__name__': '__farm__'})
    for handler in list(bpy.app.handlers.render_post):  # the binary's error check: done below
        if getattr(handler, '__name__', '') == '_ember_farm_check':
            bpy.app.handlers.render_post.remove(handler)
    for frame in frames_of(args.frames):
        scene.frame_set(frame)
        del ember_engine.RENDER_LOG[:]
        bpy.ops.render.render()
        errors = [entry['error'] for entry in ember_engine.RENDER_LOG if entry['error']]
        if errors or not ember_engine.RENDER_LOG:
            print("EMBER-FARM-ERROR:", "; ".join(errors) or "nothing rendered", file=sys.stderr)
            return 1
        path = frame_path(bpy.path.abspath(args.pattern), frame)
        bpy.data.images['Render Result'].save_render(path, scene=scene)
        print("Saved:", path, flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
