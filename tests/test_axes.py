"""A model's up axis: its spellings, the rotation that stands it up, each format's convention."""

import numpy as np
import pytest

from surfidx import InputError
from surfidx.geometry.axes import MESH_UP, SCANNER_UP, UP_AXES, check_up, up_rotation
from surfidx.io import up_axis
from surfidx.io.registry import MESH_READERS, POINT_READERS


def test_check_up_takes_what_users_type():
    for text, want in (("+z", "+z"), ("z", "+z"), ("Z", "+z"), (" +Y ", "+y"), ("-X", "-x"),
                       ("-y", "-y")):
        assert check_up(text) == want
    assert set(UP_AXES) == {"+x", "-x", "+y", "-y", "+z", "-z"}
    assert all(check_up(a) == a for a in UP_AXES)


@pytest.mark.parametrize("bad", ["w", "+w", "", "zz", "--z", "up", 3, None, ("+", "z")])
def test_check_up_refuses_anything_else(bad):
    with pytest.raises(InputError, match=r"unknown up axis .*; use one of \+y, \+z, \+x"):
        check_up(bad)


def test_up_rotation_turns_the_up_axis_to_plus_y():
    for up in UP_AXES:
        r = up_rotation(up)
        assert np.allclose(r @ r.T, np.eye(3)) and np.isclose(np.linalg.det(r), 1.0), up
        axis = np.zeros(3)
        axis["xyz".index(up[1])] = 1.0 if up[0] == "+" else -1.0
        assert np.allclose(r @ axis, [0, 1, 0]), up
    # +z up: the front view's camera sits on -y (turned to +z), +x stays to the right
    assert np.allclose(up_rotation("z") @ [0, -1, 0], [0, 0, 1])
    assert np.allclose(up_rotation("z") @ [1, 0, 0], [1, 0, 0])
    with pytest.raises(InputError, match=r"unknown up axis 'y\+'"):
        up_rotation("y+")


def test_each_format_says_which_axis_is_up():
    """Meshes are +y up (glTF's rule, most modellers'), scanners' point clouds +z up; a new
    reader's line must say so (a point-cloud format left at the mesh default fails here)."""
    assert MESH_UP == "+y" and SCANNER_UP == "+z"
    assert {r.up for r in MESH_READERS.values()} == {MESH_UP}
    assert {s: r.up for s, r in POINT_READERS.items()} == dict.fromkeys(POINT_READERS,
                                                                         SCANNER_UP)
    for name, want in (("a.obj", "+y"), ("b.GLB", "+y"), ("c.gltf", "+y"), ("d.ply", "+y"),
                       ("e.off", "+y"), ("f.stl", "+y"), ("g.xyz", "+z"), ("h.PTS", "+z"),
                       ("i.pcd", "+z"), ("j.unknown", "+y")):
        assert up_axis(name) == want, name
    assert up_axis(np.zeros((4, 3))) == MESH_UP   # a model in memory: trimesh's convention
