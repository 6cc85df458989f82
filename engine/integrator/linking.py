"""Light Linking and Shadow Linking (Blender 4.0+), as Cycles renders them.

A light's receiver set says which objects it lights: light sampling at a
vertex of another object gets nothing from it, and neither does a BSDF ray
from such a vertex that meets it, so both MIS strategies agree and the
estimate stays unbiased (the light tree still picks unlinked lights: those
samples bring nothing, as more noise, not bias).  A light's blocker set
says which objects cast its shadows: its shadow rays pass every other
object.  A BSDF ray cannot know which light it will meet before it is
blocked, so a shadow-linked light is found by light sampling alone (MIS
weight 1, and 0 for BSDF rays that meet it after a bounce), which is the
same light Cycles' dedicated shadow-linking rays add.

``LightLinks.build`` makes the per-render tables (None without links):
per emitter the row of its receiver and blocker masks (-1: every object),
the masks over the scene's instances, and each triangle's instance.
"""
from dataclasses import dataclass

import numpy as np

from .. import instance_batch
from ..lights import scene_lights_in_order


@dataclass(frozen=True)
class LightLinks:
    receiver_row: np.ndarray   # (E + 1,) row of ``receives`` per emitter, -1: lights every object
    blocker_row: np.ndarray    # (E + 1,) row of ``blocks`` per emitter, -1: every object blocks
    receives: np.ndarray       # (R, I + 1) objects each receiver set lights (last column: no object)
    blocks: np.ndarray         # (B, I + 1) objects each blocker set lets block
    instance: np.ndarray       # (T,) instance of each triangle

    @classmethod
    def build(cls, scene, lights, triangles):
        links = getattr(scene, "light_links", None) or {}
        if not links or lights.count == 0:
            return None
        names = instance_batch.field_of_each(scene.instances, "name")
        index = {id(light): i for i, light in enumerate(scene.lights)}
        ordered = scene_lights_in_order(scene.lights)
        receivers, blockers, recv_rows, block_rows = [], [], [], []
        for light in ordered:
            recv, block = links.get(index[id(light)], (None, None))
            recv_rows.append(_row(recv, names, receivers, True))
            block_rows.append(_row(block, names, blockers, False))
        if not receivers and not blockers:
            return None
        per_emitter = lights.per_emitter
        receiver_row = np.array(list(per_emitter(recv_rows, -1, np.full(len(scene.materials) + 1, -1))) + [-1])
        blocker_row = np.array(list(per_emitter(block_rows, -1, np.full(len(scene.materials) + 1, -1))) + [-1])
        owner = getattr(triangles.shading, "instance", None)
        instance = (np.asarray(owner, np.int64) if owner is not None
                    else np.full(len(triangles.material), len(names), np.int64))
        empty = np.zeros((0, len(names) + 1), bool)
        return cls(receiver_row.astype(np.int64), blocker_row.astype(np.int64),
                   np.array(receivers) if receivers else empty, np.array(blockers) if blockers else empty,
                   instance)

    @property
    def any_blockers(self):
        return bool(np.any(self.blocker_row >= 0))

    def lit(self, emitter, inst):
        """Whether ``emitter[i]`` lights instance ``inst[i]`` (-1: no object,
        a camera ray: every light)."""
        row = self.receiver_row[np.asarray(emitter, np.int64)]
        inst = np.where(inst < 0, self.receives.shape[1] - 1, inst)
        out = np.ones(len(row), bool)
        linked = row >= 0
        out[linked] = self.receives[row[linked], inst[linked]]
        return out

    def shadow_linked(self, emitter):
        """Whether ``emitter[i]`` has a blocker set (light sampling alone finds it)."""
        return self.blocker_row[np.asarray(emitter, np.int64)] >= 0

    def blocking(self, emitter, prim):
        """Whether triangle ``prim[i]`` may block the shadow rays of ``emitter[i]``."""
        row = self.blocker_row[np.asarray(emitter, np.int64)]
        out = np.ones(len(row), bool)
        linked = (row >= 0) & (prim >= 0)
        out[linked] = self.blocks[row[linked], self.instance[prim[linked]]]
        return out


def _row(linkset, names, table, no_object):
    """The row of ``linkset``'s mask over the instances in ``table`` (added
    when new), or -1 for None (every object)."""
    if linkset is None or not (linkset.include or linkset.exclude):
        return -1        # every object: no link
    mask = np.array([linkset.admits(n) for n in names] + [no_object], bool)
    table.append(mask)
    return len(table) - 1


def instance_of(ctx, prim):
    """Instance index of triangles ``prim`` (-1 for none)."""
    links = ctx.links
    return np.where(prim >= 0, links.instance[np.maximum(prim, 0)], -1)
