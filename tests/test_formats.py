"""Input formats (STL, glTF/GLB, PCD, XYZ, PTS), models in memory, and PLY/OBJ/GLB output."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from surfidx import FileFormatError, InputError, SurfelSet, TriangleMesh, read_surfels
from surfidx import io as sio
from surfidx.io import as_surfels, model_hash, output_format, write_model
from surfidx.render import principal_basis

from conftest import icosphere_mesh

trimesh = pytest.importorskip("trimesh")


def _sphere(level=2):
    v, f = icosphere_mesh(level)
    return trimesh.Trimesh(v, f, process=False)


def test_stl_is_merged_into_a_closed_mesh(tmp_path):
    path = tmp_path / "ball.stl"
    _sphere().export(path)                           # a triangle soup: 3 vertices per face
    s = read_surfels(path)
    assert (len(s), len(s.faces), s.has_color, s.name) == (162, 320, False, "ball")
    topo = TriangleMesh(s.positions, s.faces).topology()
    assert topo.closed and topo.genus == 0


def test_glb_vertex_colours_and_base_colour_texture(tmp_path):
    m = _sphere()
    m.visual.vertex_colors = np.tile([10, 200, 30, 255], (len(m.vertices), 1))
    m.export(tmp_path / "vc.glb")
    s = read_surfels(tmp_path / "vc.glb")
    assert len(s) == 162 and np.all(s.colors == [10, 200, 30])
    from PIL import Image

    v = np.asarray(m.vertices)
    uv = np.c_[np.arctan2(v[:, 1], v[:, 0]) / (2 * np.pi) + 0.5, v[:, 2] * 0.5 + 0.5]
    mat = trimesh.visual.material.PBRMaterial(
        baseColorTexture=Image.new("RGB", (8, 8), (40, 90, 160)),
        baseColorFactor=[255, 255, 255, 255])
    t = trimesh.Trimesh(v, m.faces, visual=trimesh.visual.TextureVisuals(uv=uv, material=mat),
                        process=False)
    t.export(tmp_path / "tex.glb")
    s = read_surfels(tmp_path / "tex.glb")
    assert len(s) == 162 and np.abs(s.colors.astype(int) - [40, 90, 160]).max() <= 1


def test_glb_point_cloud_and_empty_scene(tmp_path):
    v = np.asarray(_sphere().vertices)
    trimesh.PointCloud(v, colors=np.tile([0, 255, 0, 255], (len(v), 1))).export(tmp_path / "p.glb")
    s = read_surfels(tmp_path / "p.glb")
    assert len(s) == 162 and s.faces is None and np.all(s.colors == [0, 255, 0])
    with pytest.raises(FileFormatError, match="p.glb: the file holds points but no faces"):
        sio.read_mesh(tmp_path / "p.glb")
    (tmp_path / "bad.glb").write_bytes(b"glTF\x02\x00\x00\x00garbage")
    with pytest.raises(FileFormatError, match="bad.glb: not a readable GLB file"):
        read_surfels(tmp_path / "bad.glb")


def test_gltf_refers_outside_its_folder(tmp_path):
    (tmp_path / "m.gltf").write_text('{"asset": {"version": "2.0"}, "buffers": '
                                     '[{"uri": "../secret.bin", "byteLength": 4}]}')
    with pytest.raises(FileFormatError, match="refers to ../secret.bin outside the model's"):
        read_surfels(tmp_path / "m.gltf")


def _pcd_header(fields, sizes, types, n, data):
    return (f"# .PCD v0.7\nVERSION 0.7\nFIELDS {' '.join(fields)}\nSIZE {' '.join(sizes)}\n"
            f"TYPE {' '.join(types)}\nCOUNT {' '.join('1' * len(fields))}\nWIDTH {n}\nHEIGHT 1\n"
            f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n")


def test_pcd_ascii_and_binary(tmp_path):
    v = np.asarray(_sphere().vertices)
    n = len(v)
    packed = (np.uint32(200) << 16) | (np.uint32(100) << 8) | np.uint32(50)
    rgb = np.full(n, packed, "<u4").view("<f4")
    head = _pcd_header(["x", "y", "z", "rgb"], ["4"] * 4, ["F"] * 4, n, "ascii")
    body = "\n".join(f"{a:.7g} {b:.7g} {c:.7g} {d!r}" for (a, b, c), d in
                     zip(v.tolist(), rgb.astype(float).tolist()))
    (tmp_path / "a.pcd").write_text(head + body + "\n")
    s = read_surfels(tmp_path / "a.pcd")
    assert len(s) == n and np.all(s.colors == [200, 100, 50])
    fields = ["x", "y", "z", "normal_x", "normal_y", "normal_z"]
    head = _pcd_header(fields, ["4"] * 6, ["F"] * 6, n, "binary")
    data = np.hstack([v, v]).astype("<f4").tobytes()
    (tmp_path / "b.pcd").write_bytes(head.encode() + data)
    s = read_surfels(tmp_path / "b.pcd")
    assert len(s) == n and np.allclose(np.einsum("ij,ij->i", s.normals, v), 1, atol=1e-5)
    (tmp_path / "short.pcd").write_bytes(head.encode() + data[:100])
    with pytest.raises(FileFormatError, match="short.pcd: PCD header announces 162 points"):
        read_surfels(tmp_path / "short.pcd")
    (tmp_path / "c.pcd").write_text(head.replace("binary", "binary_compressed"))
    with pytest.raises(FileFormatError, match="binary_compressed is not supported"):
        read_surfels(tmp_path / "c.pcd")
    (tmp_path / "d.pcd").write_text("VERSION 0.7\nFIELDS x y\n")
    with pytest.raises(FileFormatError, match="no DATA line"):
        read_surfels(tmp_path / "d.pcd")
    (tmp_path / "e.pcd").write_text(_pcd_header(["x", "y", "q"], ["4"] * 3, ["F"] * 3, 1,
                                                "ascii") + "0 0 0\n")
    with pytest.raises(FileFormatError, match="lacks the fields x y z"):
        read_surfels(tmp_path / "e.pcd")


def test_xyz_and_pts(tmp_path):
    v = np.asarray(_sphere().vertices)
    np.savetxt(tmp_path / "c.xyz", np.c_[v, np.full((len(v), 3), 200)], fmt="%.8g")
    s = read_surfels(tmp_path / "c.xyz")
    assert len(s) == 162 and np.all(s.colors == 200)
    np.savetxt(tmp_path / "n.xyz", np.c_[v, v], fmt="%.8g")
    s = read_surfels(tmp_path / "n.xyz")
    assert s.colors is None and np.allclose(np.einsum("ij,ij->i", s.normals, v), 1, atol=1e-6)
    text = "\n".join(f"{a} {b} {c} 7 1 2 3" for a, b, c in v.tolist())
    (tmp_path / "s.pts").write_text(f"{len(v)}\n{text}\n")
    assert np.all(read_surfels(tmp_path / "s.pts").colors == [1, 2, 3])
    (tmp_path / "t.pts").write_text(f"{len(v) + 1}\n{text}\n")
    with pytest.raises(FileFormatError, match="announces 163 points and holds 162"):
        read_surfels(tmp_path / "t.pts")
    (tmp_path / "w.xyz").write_text("1 2 3 4\n5 6 7 8\n")
    with pytest.raises(FileFormatError, match="XYZ lines hold 4 numbers"):
        read_surfels(tmp_path / "w.xyz")
    (tmp_path / "r.xyz").write_text("1 2 3\n5 6\n")
    with pytest.raises(FileFormatError, match="malformed XYZ data"):
        read_surfels(tmp_path / "r.xyz")
    (tmp_path / "u.xyz").write_text("0 0 0 -5 300 2\n1 0 0 1 1 1\n")
    with pytest.raises(FileFormatError, match="neither unit normals nor colours"):
        read_surfels(tmp_path / "u.xyz")


def test_text_point_files_are_bounded(tmp_path, monkeypatch):
    import surfidx.io.limits as limits

    (tmp_path / "big.xyz").write_text("0 0 0\n" * 10)
    monkeypatch.setattr(limits, "MAX_TEXT_BYTES", 20)
    with pytest.raises(FileFormatError, match="big.xyz: text point file of 60 bytes exceeds"):
        read_surfels(tmp_path / "big.xyz")


def test_models_in_memory():
    v, f = icosphere_mesh(2)
    col = np.full((len(v), 3), 9, np.uint8)
    a = as_surfels((v, f))
    assert len(a) == 162 and len(a.faces) == 320
    assert np.all(read_surfels((v, f, col)).colors == 9)           # read_surfels takes them too
    assert as_surfels((v, None)).faces is None and len(as_surfels(v)) == 162
    t = as_surfels(trimesh.Trimesh(v, f, process=False), name="ball")
    assert t.name == "ball" and np.allclose(t.positions, a.positions)
    assert as_surfels(a) is a and model_hash(a) == model_hash(as_surfels((v, f)))
    assert as_surfels(a, name="x").name == "x"
    with pytest.raises(InputError, match="cannot read a model from a dict"):
        as_surfels({"v": v})
    with pytest.raises(InputError, match="a model tuple is"):
        as_surfels((v,))
    with pytest.raises(InputError, match="texture applies to OBJ files only"):
        as_surfels((v, f), texture="t.png")
    with pytest.raises(InputError, match="samples needs a mesh; a SurfelSet"):
        as_surfels(a, samples=10)
    with pytest.raises(InputError, match="samples needs a mesh; this model holds points"):
        as_surfels(v, samples=10)


def test_write_model_formats_open_in_trimesh(tmp_path):
    v, f = icosphere_mesh(2)
    s = as_surfels((v, f, np.tile([250, 20, 20], (len(v), 1)).astype(np.uint8)))
    for fmt in ("ply", "obj", "glb"):
        path = tmp_path / f"m.{fmt}"
        assert write_model(s, path) == fmt
        back = trimesh.load(path, force="mesh", process=False)
        if fmt == "ply":                       # surfels, no face element: points to trimesh
            back = trimesh.load(path, process=False)
            assert not hasattr(back, "faces") or not len(back.faces)
            assert len(read_surfels(path)) == 162
            continue
        assert len(back.faces) == 320, fmt
        assert np.allclose(np.sort(np.asarray(back.vertices), 0), np.sort(s.positions, 0),
                           atol=1e-5), fmt
        if fmt != "obj":
            assert np.all(np.asarray(back.visual.vertex_colors)[:, :3] == [250, 20, 20]), fmt
        assert len(read_surfels(path)) == 162, fmt
    points = SurfelSet(s.positions, s.normals, s.radii, s.colors)
    write_model(points, tmp_path / "p.glb")
    assert len(read_surfels(tmp_path / "p.glb")) == 162
    write_model(TriangleMesh(v, f), tmp_path / "mesh.obj", format="OBJ")
    assert len(trimesh.load(tmp_path / "mesh.obj", process=False).faces) == 320
    with pytest.raises(InputError, match="cannot tell the output format from the suffix .xyz"):
        write_model(s, tmp_path / "m.xyz")
    with pytest.raises(InputError, match="unknown output format 'stl'"):
        output_format(tmp_path / "m.ply", "stl")
    with pytest.raises(InputError, match="write_model needs a SurfelSet or TriangleMesh"):
        write_model(v, tmp_path / "m.ply")


def test_principal_view_looks_along_the_flat_axis():
    v, f = icosphere_mesh(2)
    flat = as_surfels((v * [3.0, 0.1, 1.5], f))
    basis = principal_basis(flat)
    assert abs(basis[2] @ [0, 1, 0]) > 0.999 and abs(basis[0] @ [1, 0, 0]) > 0.999
    assert np.allclose(basis @ basis.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(basis) > 0
    from surfidx.render import render

    img = render(flat, width=40, height=40, view="principal", supersample=1)
    assert (img.min(axis=2) < 250).mean() > 0.3              # the large silhouette fills it


def test_folder_without_supported_files(tmp_path):
    import ingest

    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "scan.fls").write_bytes(b"\0")
    with pytest.raises(InputError, match="holds no model file"):
        ingest.discover([tmp_path])
    from click.testing import CliRunner

    from surfidx.cli import cli

    r = CliRunner().invoke(cli, ["ingest", str(tmp_path), "--db", str(tmp_path / "x.db")])
    assert r.exit_code == 1 and "holds no model file (supported: .ply" in r.output
    assert not (tmp_path / "x.db").exists()
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "a.stl").write_bytes(struct.pack("<80sI", b"", 0))
    with pytest.warns(UserWarning, match="empty: holds no model file"):
        (tmp_path / "empty").mkdir()
        assert len(ingest.discover([tmp_path / "sub", tmp_path / "empty"])) == 1
