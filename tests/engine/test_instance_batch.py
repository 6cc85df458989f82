"""engine.instance_batch: many instances as arrays (issue 25).  A batch
reads as the list of Instances it stands for: same columns, same items, same
render."""
import dataclasses
import pickle

import numpy as np
import pytest

from engine import instance_batch, instance_columns
from engine.instance_batch import InstanceBatch
from engine.scene import Instance, RenderSettings
from engine.testscenes import cornell_spheres


def _batch_of(instances, templates_every=7):
    """A batch of ``instances`` whose templates are every 7th instance
    (the rows between share the fields, not the matrix and random)."""
    rows = []
    for k, inst in enumerate(instances):
        template = instances[k - k % templates_every]
        rows.append(dataclasses.replace(template, matrix=inst.matrix, random=inst.random))
    items = []
    for lo in range(0, len(rows), templates_every):
        some = rows[lo:lo + templates_every]
        items.append(([some[0]], np.zeros(len(some), np.int64), np.stack([r.matrix for r in some]),
                      np.array([r.random for r in some])))
    return rows, instance_batch.join(items)


def _instances(count, seed=4):
    rng = np.random.default_rng(seed)
    out = []
    for k in range(count):
        m = np.eye(4)
        m[:3, 3] = rng.uniform(-1, 1, 3)
        out.append(Instance(mesh=k % 2, matrix=m, materials=(k % 3,), name=f"o{k}", random=float(rng.uniform()),
                            visible_shadow=bool(k % 2), pass_index=k % 5, color=(0.1 * (k % 4), 0.5, 1.0)))
    return out


def test_batch_columns_and_items_equal_the_list():
    rows, batch = _batch_of(_instances(50))
    a, b = instance_columns.read(rows), instance_columns.read(batch)
    for field in ("mesh", "matrix", "color", "pass_index", "random", "holdout", "shadow_catcher", "moving",
                  "visibility"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)
    assert [a.slot_sets[k] for k in a.slot_set] == [b.slot_sets[k] for k in b.slot_set]
    assert len(batch) == 50 and batch[-1].name == rows[-1].name and batch[3:5][1].random == rows[4].random
    np.testing.assert_array_equal(batch[12].matrix, rows[12].matrix)
    assert instance_batch.field_of_each(batch, "name") == [r.name for r in rows]
    assert instance_batch.meshes_of(batch).tolist() == [r.mesh for r in rows]
    with pytest.raises(IndexError):
        batch[50]
    again = pickle.loads(pickle.dumps(batch))   # the farm pickles scenes
    np.testing.assert_array_equal(instance_columns.read(again).matrix, a.matrix)


def test_hostile_batches():
    empty = instance_batch.join([([Instance(mesh=0)], np.zeros(0, np.int64), np.zeros((0, 4, 4)), np.zeros(0))])
    assert len(empty) == 0 and len(instance_columns.read(empty)) == 0
    with pytest.raises(ValueError, match="differ in length"):
        InstanceBatch([Instance(mesh=0)], [0, 0], np.zeros((1, 4, 4)), [0.0, 0.0])
    single = Instance(mesh=0)
    plain = instance_batch.join([single])
    assert type(plain) is list and plain[0] is single   # no run: the list itself


def test_a_batch_renders_the_list_image():
    """The instanced Cornell scene with its spheres as a batch: the same
    image, bit for bit (the stages read the same columns)."""
    from engine.render import render
    scene = cornell_spheres(24, 18, grid=4, segments=12, rings=6)
    settings = RenderSettings(samples=2, max_bounces=3, seed=5, threads=1)
    listed = render(scene, settings).image
    scene.instances = instance_batch.join([([i], [0], np.asarray(i.matrix).reshape(1, 4, 4), [i.random])
                                           for i in scene.instances])
    assert isinstance(scene.instances, InstanceBatch)
    np.testing.assert_array_equal(render(scene, settings).image, listed)
