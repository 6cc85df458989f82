"""The start of a script that drives a real Blender with a window
(viewport_gui.py, previews_gui.py):

    blender --factory-startup -p 0 0 W H [FILE] -P SCRIPT -- OUT SITE

Importing this puts the repository first and SITE (the wheels the renderer
needs) last on sys.path; ``register()`` registers the add-on from the
repository."""
import os
import sys

ARGS = sys.argv[sys.argv.index('--') + 1:]
OUT, SITE = ARGS[0], ARGS[1]
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, ROOT)
sys.path.append(SITE)


def register():
    import addon
    addon.register()
    return addon
