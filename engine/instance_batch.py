"""Many instances as arrays: the copies of a few template Instances that
differ only in their matrix and Object Info random number.

A geometry-nodes instancer's 10^6 copies were 10^6 engine.scene.Instance
objects, built by the export and read back field by field by the
preparation (issue 25: about 10 s of a 21 s start).  ``InstanceBatch`` keeps
them as a (N, 4, 4) matrix array, a (N,) random array and a (N,) template
index; ``scene.instances`` may be one.  It is a read-only sequence: an item
is its template with the row's matrix and random (made on demand), so code
that loops over the instances still works, slowly; the preparation's
stages read ``columns()`` (engine.instance_columns) instead, in NumPy.
"""
import dataclasses
from collections.abc import Sequence

import numpy as np


class InstanceBatch(Sequence):
    """templates: Instances; template (N,) int64 index into them; matrix
    (N, 4, 4) float64; random (N,) float64."""

    def __init__(self, templates, template, matrix, random):
        self.templates = list(templates)
        self.template = np.asarray(template, np.int64)
        self.matrix = np.asarray(matrix, np.float64).reshape(-1, 4, 4)
        self.random = np.asarray(random, np.float64)
        if not len(self.template) == len(self.matrix) == len(self.random):
            raise ValueError("InstanceBatch: template, matrix and random differ in length")

    def __len__(self):
        return len(self.template)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        i = int(index)
        if i < 0:
            i += len(self)
        if not 0 <= i < len(self):
            raise IndexError("instance index out of range")
        return dataclasses.replace(self.templates[self.template[i]], matrix=self.matrix[i].copy(),
                                   random=float(self.random[i]))

    def columns(self):
        """engine.instance_columns.InstanceColumns of every row, from the
        templates' columns (read once) and the batch's arrays."""
        from . import instance_columns
        t = instance_columns.read(self.templates)
        at = self.template
        return instance_columns.InstanceColumns(
            mesh=t.mesh[at], matrix=self.matrix, slot_sets=t.slot_sets, slot_set=t.slot_set[at],
            color=t.color[at], pass_index=t.pass_index[at], random=self.random, holdout=t.holdout[at],
            shadow_catcher=t.shadow_catcher[at], moving=t.moving[at], visibility=t.visibility[at])


def distinct(instances):
    """The instances whose fields other than matrix and random may differ:
    a batch's templates, else every instance (for checks by name or material)."""
    return instances.templates if isinstance(instances, InstanceBatch) else instances


def join(items):
    """One InstanceBatch of ``items``, in order: Instances, and runs
    (templates, which (M,) index into them, matrices (M, 4, 4), randoms
    (M,)); a plain list when there is no run."""
    if not any(isinstance(item, tuple) for item in items):
        return list(items)
    numbers, templates = {}, []

    def number(template):
        k = numbers.get(id(template))
        if k is None:
            k = numbers[id(template)] = len(templates)
            templates.append(template)
        return k
    index, matrices, randoms = [], [], []
    for item in items:
        if isinstance(item, tuple):
            some, which, matrix, random = item
            index.append(np.array([number(t) for t in some], np.int64)[np.asarray(which, np.int64)])
            matrices.append(np.asarray(matrix, np.float64).reshape(-1, 4, 4))
            randoms.append(np.asarray(random, np.float64).reshape(-1))
        else:
            index.append(np.array([number(item)], np.int64))
            matrices.append(np.asarray(item.matrix, np.float64).reshape(1, 4, 4))
            randoms.append(np.array([item.random], np.float64))
    return InstanceBatch(templates, np.concatenate(index), np.concatenate(matrices), np.concatenate(randoms))


def field_of_each(instances, name, default=None):
    """[getattr(inst, name)] for every instance; a batch's from its templates
    (no Instance made per row)."""
    if isinstance(instances, InstanceBatch):
        values = [getattr(t, name, default) for t in instances.templates]
        return [values[k] for k in instances.template.tolist()]
    return [getattr(inst, name, default) for inst in instances]


def meshes_of(instances):
    """(N,) int64 mesh index of every instance."""
    if isinstance(instances, InstanceBatch):
        return np.array([t.mesh for t in instances.templates], np.int64)[instances.template]
    return np.array([inst.mesh for inst in instances], np.int64)


def extended(instances, extra):
    """``instances`` followed by the Instances ``extra`` (a batch stays a
    batch: its rows are not made into Instances)."""
    if isinstance(instances, InstanceBatch):
        run = (instances.templates, instances.template, instances.matrix, instances.random)
        return join([run, *extra])
    return list(instances) + list(extra)
