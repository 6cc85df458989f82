"""Ember: a physically based path tracer for Blender.

This package is the Blender side: it registers the EMBER RenderEngine, its
settings and panels, exports the evaluated scene to ``engine.scene`` data and
writes the renderer's passes back into Blender.  Own modules are imported
relatively, so the same files work as the top-level package ``addon`` (tests),
as the legacy add-on ``ember`` and as the extension ``bl_ext.<repo>.ember``.
"""

bl_info = {
    "name": "Ember",
    "author": "Ember developers",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "Render Properties > Render Engine > Ember",
    "description": "Physically based path tracer written in Python",
    "category": "Render",
}

from . import engine, properties, ui  # noqa: E402

_modules = (properties, engine, ui)


def register():
    for module in _modules:
        module.register()


def unregister():
    for module in reversed(_modules):
        module.unregister()
