"""Shader nodes evaluated per shading point, as Cycles' SVM does.

``REGISTRY`` (registry.py) maps a Blender node id to its entry; importing
this package registers every node module.  ``ShadingContext`` (context.py)
is what the nodes read.  engine.textures compiles ``scene.NodeOutput``
expressions through the registry.
"""
from . import converter_nodes, input_nodes, ray_nodes, sky, texture_nodes  # noqa: F401  (registration)
# Registered last: the node parity scene places quads in registry order, and
# its Camera-coordinate quad must stay where its values are positive.
from . import gabor  # noqa: F401,E402
from . import ies  # noqa: F401,E402  (after gabor: the parity scene's quad order)
from . import hair_random  # noqa: F401,E402  (no Blender node: the parity scene skips it)
from .context import SceneShading, ShadingContext, as_context
from .rays import NodeRays
from .registry import REGISTRY, NodeDef, lookup

__all__ = ["REGISTRY", "NodeDef", "lookup", "ShadingContext", "SceneShading", "as_context", "NodeRays"]
