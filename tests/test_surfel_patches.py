"""SurfelSet's virtual-patch labels (topology repair's additions, carried to the codec)."""

import numpy as np
import pytest

from surfidx import InputError, SurfelSet


def _set(n=6, **kw):
    rng = np.random.default_rng(0)
    p = rng.normal(size=(n, 3))
    return SurfelSet(p, p / np.linalg.norm(p, axis=1, keepdims=True), np.full(n, 0.1), **kw)


def test_default_is_all_real():
    s = _set()
    assert s.patch is None and s.patch_cut is None
    assert not s.virtual.any()


def test_labels_carried_by_derived_sets():
    s = _set(patch=[-1, -1, 0, 0, 1, 2], patch_cut=[-1, 0, 0])
    assert s.virtual.tolist() == [False, False, True, True, True, True]
    assert s.patch.dtype == np.int32 and s.patch_cut.tolist() == [-1, 0, 0]
    t = s.transformed(scale=2.0)
    assert np.array_equal(t.patch, s.patch) and np.array_equal(t.patch_cut, s.patch_cut)
    assert np.array_equal(s.without_color().patch, s.patch)
    sub = s.subset([0, 2, 5])
    assert sub.patch.tolist() == [-1, 0, 2] and sub.patch_cut.tolist() == [-1, 0, 0]


def test_patch_cut_defaults_to_holes():
    assert _set(patch=[-1, 0, 1, 1, -1, -1]).patch_cut.tolist() == [-1, -1]


@pytest.mark.parametrize("kw, match", [
    (dict(patch=[-2, 0, 0, 0, 0, 0]), "patch labels must be -1"),
    (dict(patch=[-1, 0, 1, 1, 1, 1], patch_cut=[-1]), "patch_cut has 1 entries but the surfels "
                                                      "name 2 patches"),
    (dict(patch=[-1, 0, 1, 2, 2, 2], patch_cut=[0, 0, 0]), "exactly two patches"),
    (dict(patch_cut=[0, 0]), "patch_cut was given without patch"),
    (dict(patch=[0, 0, 0]), "patch must have shape"),
])
def test_bad_labels(kw, match):
    with pytest.raises(InputError, match=match):
        _set(**kw)
