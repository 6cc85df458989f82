"""Blender's dupli random_id (Object Info > Random of an instance), in NumPy.

Blender gives each instance a uint32 made in make_dupli
(blenkernel/intern/object_dupli.cc): the hash of the instanced object's
name, mixed with each used level of the instance's persistent id
(innermost level first; unused levels hold INT_MAX and are not mixed in
Blender 5.0 and 5.1, where 4.5 mixes all MAX_DUPLI_RECUR), and, when the instanced
object is not the scene-level instancer itself, xor-ed with the hash of that
instancer's name.  Reproduced here so that a geometry-nodes instancer's
copies can be read in bulk (instances.BulkInstances) without asking the
depsgraph for each copy's random_id; tests/addon/test_dupli_random.py checks
it bit for bit against ``depsgraph.object_instances`` for every kind of
instance.  No bpy here but its version (the hash is the engine's).
"""
import numpy as np

from .. import backend

MAX_DUPLI_RECUR = 8       # BKE_duplilist.hh
UNUSED_LEVEL = 2 ** 31 - 1  # INT_MAX: a persistent id's unused levels


def hash_string(name):
    """BLI_hash_string: h = h * 37 + c over the UTF-8 bytes (as unsigned
    bytes: measured bit-exact on non-ASCII names)."""
    h = 0
    for byte in name.encode('utf-8'):
        h = (h * 37 + byte) & 0xFFFFFFFF
    return h


def random_ids(object_name, persistent_ids, root_name=None, all_levels=None):
    """(N,) uint32 random_id of N instances of the object ``object_name``
    with ``persistent_ids`` (N, MAX_DUPLI_RECUR) ints (as
    DepsgraphObjectInstance.persistent_id); ``root_name``: the scene-level
    instancer's name when it is another object than the instanced one
    (None when they are the same object); ``all_levels``: mix unused
    levels too (Blender before 5.0; None: as this bpy)."""
    hash_uint = backend.engine().hash_uint   # lookup3 of 2 keys: BLI_hash_int_2d
    if all_levels is None:
        import bpy
        all_levels = mixes_all_levels(bpy.app.version)
    ids = np.asarray(persistent_ids, dtype=np.int64).reshape(-1, MAX_DUPLI_RECUR)
    h = np.full(len(ids), hash_string(object_name), np.uint32)
    used = ids[:, 0] != UNUSED_LEVEL
    levels = ids.astype(np.uint32)   # int -> uint, as C's uint() cast (two's complement)
    mixed = h.copy()
    for level in range(MAX_DUPLI_RECUR):
        here = np.ones(len(ids), bool) if all_levels else ids[:, level] != UNUSED_LEVEL
        if here.all():
            mixed = hash_uint(mixed, levels[:, level])
        elif here.any():
            mixed = np.where(here, hash_uint(mixed, levels[:, level]), mixed)
    h = np.where(used, mixed, hash_uint(h, np.uint32(0)))
    if root_name is not None:
        h ^= hash_uint(np.uint32(hash_string(root_name)), np.uint32(0))
    return h.astype(np.uint32)


def mixes_all_levels(version):
    """Whether Blender ``version`` mixes all MAX_DUPLI_RECUR levels into
    random_id (4.5 does, measured; 5.0 and 5.1 mix the used ones only)."""
    return tuple(version[:2]) < (5, 0)


def geometry_instance_ids(instance_ids, extra_level=None):
    """(N, MAX_DUPLI_RECUR) persistent ids of the mesh copies a top-level
    geometry-nodes instancer makes of geometry references: [0, id, ...]
    (the reference's mesh component is its first, index 0), with the index
    of the instancer's own non-mesh components' sub-context after the id
    when it has such components (``extra_level``)."""
    ids = np.full((len(instance_ids), MAX_DUPLI_RECUR), UNUSED_LEVEL, np.int64)
    ids[:, 0] = 0
    ids[:, 1] = instance_ids
    if extra_level is not None:
        ids[:, 2] = extra_level
    return ids


def object_instance_ids(instance_ids, extra_level=None):
    """(N, MAX_DUPLI_RECUR) persistent ids of a top-level geometry-nodes
    instancer's copies of an object reference: [id, ...]."""
    ids = np.full((len(instance_ids), MAX_DUPLI_RECUR), UNUSED_LEVEL, np.int64)
    ids[:, 0] = instance_ids
    if extra_level is not None:
        ids[:, 1] = extra_level
    return ids


def unit_float(rid):
    """Cycles' Object Info Random of uint32 random_ids: float32(rid) * 2^-32
    (float32 arithmetic), as float64."""
    return (np.asarray(rid, np.uint32).astype(np.float32) * np.float32(1.0 / 4294967296.0)).astype(np.float64)
