"""Filter Glossy on the Principled Hair lobes (engine/bsdf.blur ->
engine/lobes/hair.blur, bsdf._blur_hair): Cycles' bsdf_hair_chiang_blur
raises the closure's mapped v, s and m0 to the blur roughness, and
bsdf_hair_huang_blur its roughness.  The parity test with Cycles is
tests/addon/test_hair_filter_glossy_parity.py."""
import numpy as np

from engine import bsdf
from engine.lobe_ids import DIFFUSE
from engine.lobes import hair
from engine.lobes.hair import HAIR_CHIANG
from engine.lobes.hair_huang import HAIR_HUANG
from engine.scene import Lobe, Material


def _lobes(rows):
    mats = bsdf.MaterialTable([Material("m", (
        Lobe("diffuse"), Lobe("hair_chiang", roughness=0.3, radial_roughness=0.2, coat=0.4),
        Lobe("hair_huang", roughness=0.3), Lobe("hair_chiang", roughness=0.9, radial_roughness=0.8)))])
    return mats.gather(np.zeros(rows, np.int64))


def _mapped(lobes, k):
    return np.array(hair.setup(np.sqrt(lobes.alpha[:, k]), lobes.radial_roughness[:, k], lobes.coat[:, k]))


def test_chiang_blur_raises_mapped_variances_as_cycles():
    """v, s, m0 after the blur are max(blur, each) (Cycles' blur compares
    the mapped values, not the node's roughnesses); rows not blurred and
    values above the blur stay as they were; other lobes untouched."""
    lobes = _lobes(4)
    assert list(lobes.kind[0]) == [DIFFUSE, HAIR_CHIANG, HAIR_HUANG, HAIR_CHIANG]
    before = [_mapped(lobes, k) for k in (1, 3)]
    alpha = lobes.alpha.copy()
    rows, blur = np.array([0, 1, 3]), np.array([0.5, 0.1, 0.02])
    bsdf.blur(lobes, rows, blur)
    for k, old in zip((1, 3), before):
        new = _mapped(lobes, k)
        expect = old.copy()
        expect[:, rows] = np.maximum(old[:, rows], blur[None, :])
        np.testing.assert_allclose(new, expect, rtol=1e-9, atol=1e-12)
    # Row 2 was not blurred, nor row 3's slot 3 (its own v, s, m0 exceed 0.02).
    np.testing.assert_array_equal(lobes.alpha[2], alpha[2])
    np.testing.assert_array_equal(lobes.alpha[3, 3], alpha[3, 3])
    assert lobes.alpha[0, 0] == alpha[0, 0]
    # Slot 1's coat: m0 (from (1 - coat) r) blurred apart from v.
    assert 0.0 <= lobes.coat[1, 1] <= 0.4


def test_huang_blur_raises_roughness():
    lobes = _lobes(2)
    bsdf.blur(lobes, np.array([0]), np.array([0.45]))
    np.testing.assert_allclose(np.sqrt(lobes.alpha[:, 2]), [0.45, 0.3])
