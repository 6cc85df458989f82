"""The shader-node registry: one entry per Blender node Ember evaluates.

An entry (``NodeDef``) declares the node's Blender id, its input sockets
(Blender identifiers, with kinds 'float', 'color' or 'vector'), its outputs,
the node properties the exporter copies (name and default for Blenders that
lack it), an optional ``translate`` for data a property copy cannot carry
(a colour ramp's baked table), the coordinates an unlinked Vector input
stands for, a vectorized ``evaluate(ctx, inputs, props) -> {output: array}``
over a ``ShadingContext``, and a ``bounds`` giving each output's value range
(None: unbounded).  The exporter, the compiler, validation and the tests all
iterate over ``REGISTRY``: adding a node is adding one entry.

Arrays: floats are (N,), colours and vectors (N, 3).
"""
from dataclasses import dataclass, field
from typing import Callable, Optional

REGISTRY = {}
KINDS = ("float", "color", "vector")


@dataclass
class NodeDef:
    idname: str
    inputs: tuple                  # ((identifier, kind), ...)
    outputs: tuple                 # ((identifier, kind), ...)
    evaluate: Callable
    props: tuple = ()              # ((bpy property, default), ...)
    translate: Optional[Callable] = None   # bpy node -> dict of extra props
    coords: Optional[str] = None   # what an unlinked 'Vector' input reads: 'generated', 'uv', 'position', 'incoming'
    bounds: Optional[Callable] = None      # (props) -> {output: (lo, hi)}
    unsupported_outputs: tuple = ()
    # Extra absolute error allowed against Cycles: chains of float32
    # trigonometry (Magic) amplify last-bit differences between libms.
    tolerance: float = 0.0
    # (props) -> None, or why these properties are not evaluated (the
    # exporter then falls back with a warning; validation rejects them).
    accepts: Optional[Callable] = None
    # Values of inputs older Blenders lack (e.g. Noise Lacunarity before 4.0),
    # as those versions behaved; other absent inputs read as zero.
    input_defaults: dict = field(default_factory=dict)
    # Property combinations the parity tests render (each a dict of props
    # and input values); the first entry's defaults when empty.
    cases: list = field(default_factory=list)

    def input_kind(self, name):
        return dict(self.inputs)[name]

    def output_kind(self, name):
        return dict(self.outputs)[name]


def node(idname, inputs=(), outputs=(), props=(), translate=None, coords=None, bounds=None,
         unsupported_outputs=(), cases=(), tolerance=0.0, accepts=None, input_defaults=None):
    """Decorator registering an evaluate function as a node."""
    def register(fn):
        for _, kind in tuple(inputs) + tuple(outputs):
            assert kind in KINDS, (idname, kind)
        REGISTRY[idname] = NodeDef(idname, tuple(inputs), tuple(outputs), fn, tuple(props), translate,
                                   coords, bounds, tuple(unsupported_outputs), tolerance, accepts,
                                   dict(input_defaults or {}), list(cases))
        return fn
    return register


def one_of(**allowed):
    """An ``accepts`` check: each named property must be one of its values."""
    def check(props):
        for name, values in allowed.items():
            if props.get(name, values[0]) not in values:
                return f"{name} {props.get(name)!r} is not rendered yet"
        return None
    return check


def wanted(props, output):
    """Whether an output of a node call is read by anyone: the exporter lists
    the outputs it linked in ``props['_outputs']``; without that list (tests,
    probes) every output is computed."""
    used = props.get("_outputs")
    return used is None or output in used


def lookup(idname):
    return REGISTRY.get(idname)
