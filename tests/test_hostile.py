"""Hostile inputs (issue 55): damaged GLB accessors, textures dropped without a word, PCD/PTS
values refused like XYZ's, MTL libraries outside the model's folder, level-9 streams decoded at
level 2 in bounded memory, damaged databases."""

from __future__ import annotations

import base64
import io
import json
import os
import struct
import warnings

import numpy as np
import pytest
from click.testing import CliRunner

from surfidx import FileFormatError, InputError, read_surfels
from surfidx import io as sio
from surfidx.cli import cli
from surfidx import Database

from helpers import tiny_png, write_bomb_png

TET = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32)
TET_FACES = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], np.uint32)


def glb(positions=TET, faces=TET_FACES, *, image=None, image_uri=None, edit=None) -> bytes:
    """A GLB of one triangle primitive (positions, indices, UVs), optionally with a base-colour
    texture (``image`` bytes in the binary chunk, or ``image_uri``); ``edit(doc)`` changes the
    JSON before it is written."""
    pos = np.asarray(positions, "<f4").tobytes()
    idx = np.asarray(faces, "<u4").tobytes()
    uv = np.asarray(positions, "<f4")[:, :2].tobytes()
    blob = pos + idx + uv
    n = len(positions)
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
           "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
           "buffers": [{"byteLength": 0}],
           "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(pos)},
                           {"buffer": 0, "byteOffset": len(pos), "byteLength": len(idx)},
                           {"buffer": 0, "byteOffset": len(pos) + len(idx),
                            "byteLength": len(uv)}],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": n, "type": "VEC3"},
                         {"bufferView": 1, "componentType": 5125, "count": np.size(faces),
                          "type": "SCALAR"},
                         {"bufferView": 2, "componentType": 5126, "count": n, "type": "VEC2"}]}
    if image is not None or image_uri is not None:
        prim = doc["meshes"][0]["primitives"][0]
        prim["attributes"]["TEXCOORD_0"] = 2
        prim["material"] = 0
        doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
        doc["textures"] = [{"source": 0}]
        if image_uri is not None:
            doc["images"] = [{"uri": image_uri}]
        else:
            blob += b"\0" * (-len(blob) % 4)
            doc["bufferViews"].append({"buffer": 0, "byteOffset": len(blob),
                                       "byteLength": len(image)})
            doc["images"] = [{"bufferView": 3, "mimeType": "image/png"}]
            blob += image
    blob += b"\0" * (-len(blob) % 4)
    doc["buffers"][0]["byteLength"] = len(blob)
    if edit is not None:
        edit(doc)
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    body = struct.pack("<II", len(js), 0x4E4F534A) + js + \
        struct.pack("<II", len(blob), 0x004E4942) + blob
    return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body


def one_line_error(args, *parts):
    """Run the command; it fails with one ``Error:`` line holding every part, no traceback."""
    r = CliRunner().invoke(cli, [str(a) for a in args])
    assert r.exit_code != 0, r.output
    assert r.output.startswith("Error: ") and r.output.count("\n") == 1, r.output
    assert all(p in r.output for p in parts), r.output
    return r.output


# -- GLB accessors --------------------------------------------------------------------------------

def test_glb_as_written_reads(tmp_path):
    (tmp_path / "ok.glb").write_bytes(glb())
    assert sio.read_mesh(tmp_path / "ok.glb").faces.shape == (4, 3)


def test_glb_index_past_the_vertices(tmp_path):
    faces = TET_FACES.copy()
    faces[0, 0] = 1000
    path = tmp_path / "bad.glb"
    path.write_bytes(glb(faces=faces))
    with pytest.raises(FileFormatError, match=r"bad.glb: .*indices \(accessor 1\) refer to "
                                              r"vertex 1,000, the positions .* hold 4"):
        read_surfels(path)
    db = tmp_path / "s.db"
    Database(db).close()
    for args in (["info", path], ["convert", path, "-o", tmp_path / "o.ply"],
                 ["encode", path, "-o", tmp_path / "o.sfz", "--bits-per-surfel", "8"],
                 ["query", path, "--db", db]):
        one_line_error(args, "bad.glb", "refer to vertex 1,000")


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["accessors"][1].update(count=999), r"accessor 1 reads 999 elements of 4 bytes "
                                                   r"every 4 from byte 0 of bufferView 1"),
    (lambda d: d["accessors"][0].update(byteOffset=40), r"accessor 0 reads 4 elements .* from "
                                                        r"byte 40 of bufferView 0, which holds 48"),
    (lambda d: d["bufferViews"][0].update(byteStride=64), r"accessor 0 reads 4 elements of 12 "
                                                          r"bytes every 64"),
    (lambda d: d["bufferViews"][2].update(byteOffset=10 ** 6), r"bufferView 2 spans bytes "
                                                               r"1,000,000 to"),
    (lambda d: d["buffers"][0].update(byteLength=10 ** 6), r"buffer 0 announces 1,000,000 bytes"),
    (lambda d: d["accessors"][1].update(bufferView=7), r"accessor 1 bufferView is 7, the file "
                                                       r"has 3"),
    (lambda d: d["accessors"][0].update(count=-1), r"accessor 0 count is -1, not an integer"),
    (lambda d: d["accessors"][2].update(count=3), r"attribute TEXCOORD_0 \(accessor 2\) holds "
                                                  r"3 elements, POSITION holds 4"),
    (lambda d: d["accessors"][1].update(count=5), r"5 indices do not make whole triangles"),
    (lambda d: d["accessors"].append({"componentType": 5126, "count": 10 ** 9, "type": "MAT4"}),
     r"accessor 3 announces 1,000,000,000 elements with no data"),
    (lambda d: d["accessors"][0].pop("bufferView"), r"positions \(accessor 0\) have no data"),
    (lambda d: d["accessors"][0].update(type=[1]), r"accessor 0 has an unknown componentType"),
])
def test_glb_accessors_out_of_bounds(tmp_path, edit, message):
    if "TEXCOORD" in message:
        def edit(d, _edit=edit):                      # a primitive with UVs of 3 elements
            d["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = 2
            _edit(d)
    path = tmp_path / "bad.glb"
    path.write_bytes(glb(edit=edit))
    with pytest.raises(FileFormatError, match="bad.glb: glTF .*" + message):
        read_surfels(path)


def test_glb_header_and_chunks(tmp_path):
    path = tmp_path / "cut.glb"
    path.write_bytes(glb()[:60])
    with pytest.raises(FileFormatError, match="cut.glb: not a readable GLB file .* it may be "
                                              "truncated"):
        read_surfels(path)
    data = bytearray(glb())
    data[4:8] = struct.pack("<I", 1)
    path.write_bytes(bytes(data))
    with pytest.raises(FileFormatError, match=r"version 1; only glTF 2"):
        read_surfels(path)
    data = glb()
    path.write_bytes(data[:-8])
    with pytest.raises(FileFormatError, match="binary chunk announces .* it may be truncated"):
        read_surfels(path)


def test_glb_skipped_primitive_is_named(tmp_path):
    def fan(d):
        prims = d["meshes"][0]["primitives"]
        prims.append(dict(prims[0], mode=6))
    path = tmp_path / "fan.glb"
    path.write_bytes(glb(edit=fan))
    with pytest.warns(UserWarning, match=r"fan.glb: mesh 0, primitive 1 draws triangle fan, "
                                         r"which is not read; skipped"):
        assert len(sio.read_mesh(path).faces) == 4


def test_gltf_buffer_names_a_missing_file(tmp_path):
    (tmp_path / "m.gltf").write_text('{"asset": {"version": "2.0"}, "buffers": '
                                     '[{"uri": "gone.bin", "byteLength": 4}]}')
    with pytest.raises(FileFormatError, match="buffer 0 names gone.bin, which is not a file"):
        read_surfels(tmp_path / "m.gltf")
    (tmp_path / "n.gltf").write_text('{"asset": {"version": "2.0"}, "buffers": '
                                     '[{"byteLength": 4}]}')
    with pytest.raises(FileFormatError, match="buffer 0 has no uri"):
        read_surfels(tmp_path / "n.gltf")
    (tmp_path / "j.gltf").write_text('[1, 2]')
    with pytest.raises(FileFormatError, match="its JSON is not an object"):
        read_surfels(tmp_path / "j.gltf")


# -- GLB textures: refused like an OBJ's, or skipped with a warning -------------------------------

def test_glb_texture_too_large_is_refused(tmp_path):
    bomb = write_bomb_png(tmp_path / "bomb.png", side=50000).read_bytes()
    (tmp_path / "big.glb").write_bytes(glb(image=bomb))
    with pytest.raises(FileFormatError, match=r"big.glb: texture image exceeds the limit of "
                                              r"134,217,728 pixels \(it declares 2,500,000,000\) "
                                              r"\(image 0\)"):
        read_surfels(tmp_path / "big.glb")
    uri = "data:image/png;base64," + base64.b64encode(bomb).decode()
    (tmp_path / "uri.glb").write_bytes(glb(image_uri=uri))
    with pytest.raises(FileFormatError, match=r"uri.glb: texture image exceeds the limit"):
        read_surfels(tmp_path / "uri.glb")
    bomb = write_bomb_png(tmp_path / "bomb.png", side=12000).read_bytes()   # under Pillow's own
    (tmp_path / "mid.glb").write_bytes(glb(image=bomb))
    with pytest.raises(FileFormatError, match=r"mid.glb: texture image of 12000 × 12000 pixels "
                                              r"exceeds the limit"):
        read_surfels(tmp_path / "mid.glb")


def test_glb_truncated_texture_names_the_file(tmp_path):
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.random.default_rng(0).integers(0, 255, (64, 64, 3), np.uint8)).save(
        buf, "PNG")
    (tmp_path / "cut.glb").write_bytes(glb(image=buf.getvalue()[:-200]))
    with pytest.raises(FileFormatError, match=r"cut.glb: cannot read the texture image "
                                              r"\(image file is truncated"):
        read_surfels(tmp_path / "cut.glb")
    one_line_error(["info", tmp_path / "cut.glb"], "cut.glb", "image file is truncated")
    (tmp_path / "junk.glb").write_bytes(glb(image=b"not an image at all"))
    with pytest.raises(FileFormatError, match=r"junk.glb: cannot read the texture image .*"
                                              r"\(image 0\)"):
        read_surfels(tmp_path / "junk.glb")


def test_glb_texture_outside_the_folder(tmp_path):
    (tmp_path / "outside.png").write_bytes(tiny_png(size=4))
    folder = tmp_path / "m"
    folder.mkdir()
    (folder / "outside.png").write_bytes(tiny_png(seed=3, size=4))   # never read instead
    (folder / "m.glb").write_bytes(glb(image_uri="../outside.png"))
    with pytest.warns(UserWarning, match=r"m.glb: texture ../outside.png \(image 0\) lies "
                                         r"outside the model's folder; skipped"):
        assert sio.read_mesh(folder / "m.glb").texture is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mesh = sio.read_mesh(folder / "m.glb", allow_outside_textures=True)
    from PIL import Image

    expected = np.asarray(Image.open(io.BytesIO(tiny_png(size=4))).convert("RGB"))
    assert np.array_equal(mesh.texture, expected)
    (folder / "gone.glb").write_bytes(glb(image_uri="gone.png"))
    with pytest.raises(FileFormatError, match=r"gone.glb: texture image gone.png not found"):
        read_surfels(folder / "gone.glb")
    os.mkfifo(folder / "fifo.png")                        # never opened: it would block
    (folder / "fifo.glb").write_bytes(glb(image_uri="fifo.png"))
    with pytest.raises(FileFormatError, match=r"fifo.glb: texture image fifo.png is not a "
                                              r"regular file"):
        read_surfels(folder / "fifo.glb")


def test_glb_ktx2_texture_is_named(tmp_path):
    def ktx(d):
        d["images"][0]["mimeType"] = "image/ktx2"
    (tmp_path / "k.glb").write_bytes(glb(image=tiny_png(), edit=ktx))
    with pytest.warns(UserWarning, match=r"k.glb: texture image 0 is KTX2, which is not read"):
        assert sio.read_mesh(tmp_path / "k.glb").texture is None


def test_glb_texture_inside_reads(tmp_path):
    (tmp_path / "t.png").write_bytes(tiny_png(size=4))
    (tmp_path / "in.glb").write_bytes(glb(image_uri="t.png"))
    (tmp_path / "bv.glb").write_bytes(glb(image=tiny_png(size=4)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name in ("in.glb", "bv.glb"):
            assert sio.read_mesh(tmp_path / name).texture.shape == (4, 4, 3)


# -- point files: refused like XYZ and PTS refuse them, not read in part --------------------------

def pcd(fields, rows, *, data="binary", points=None, width=None, types=None):
    """A PCD file of float fields (or ``types``) and its rows; ``points``/``width`` override
    the header's counts."""
    rows = np.asarray(rows, np.float64)
    n = len(rows)
    types = types or ["F"] * len(fields)
    head = (f"VERSION 0.7\nFIELDS {' '.join(fields)}\nSIZE {' '.join(['4'] * len(fields))}\n"
            f"TYPE {' '.join(types)}\nCOUNT {' '.join(['1'] * len(fields))}\n"
            f"WIDTH {n if width is None else width}\nHEIGHT 1\n"
            f"POINTS {n if points is None else points}\nDATA {data}\n").encode()
    if data == "ascii":
        return head + "".join(" ".join(f"{x:g}" for x in r) + "\n" for r in rows).encode()
    dt = [(f, "<f4" if t == "F" else "<u4") for f, t in zip(fields, types)]
    return head + np.array([tuple(r) for r in rows], dtype=dt).tobytes()


def _cloud(n=50):
    rng = np.random.default_rng(1)
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_pcd_nan_point_is_refused(tmp_path):
    v = _cloud()
    v[7, 1] = np.nan
    v[9, 0] = np.nan
    for data in ("binary", "ascii"):
        path = tmp_path / f"{data}.pcd"
        path.write_bytes(pcd("x y z".split(), v, data=data))
        with pytest.raises(InputError, match=rf"{data}.pcd: PCD point 7 has NaN or infinite "
                                             r"coordinates \(2 points so"):
            read_surfels(path)
    one_line_error(["info", tmp_path / "binary.pcd"], "binary.pcd: PCD point 7 has NaN")


def test_pcd_nan_normals_are_named(tmp_path):
    v = _cloud()
    nrm = v.copy()
    nrm[3] = np.nan
    path = tmp_path / "n.pcd"
    path.write_bytes(pcd("x y z normal_x normal_y normal_z".split(), np.c_[v, nrm]))
    with pytest.warns(UserWarning, match=r"n.pcd: 1 PCD normals have NaN or infinite values; the "
                                         r"normals are dropped"):
        assert len(read_surfels(path)) == 50


def test_pcd_header_count_below_its_data(tmp_path):
    v = _cloud()
    path = tmp_path / "few.pcd"
    path.write_bytes(pcd("x y z".split(), v, points=40, width=40))
    with pytest.raises(FileFormatError, match=r"few.pcd: PCD header announces 40 points, the data "
                                              r"holds 50 of 12 bytes"):
        read_surfels(path)
    path.write_bytes(pcd("x y z".split(), v, data="ascii", points=40, width=40))
    with pytest.raises(FileFormatError, match=r"few.pcd: PCD header announces 40 points of 3 "
                                              r"numbers, the data holds 50"):
        read_surfels(path)
    path.write_bytes(pcd("x y z".split(), v, points=40))
    with pytest.raises(FileFormatError, match=r"few.pcd: PCD header announces 40 points "
                                              r"\(POINTS\) and a grid of 50"):
        read_surfels(path)
    path.write_bytes(pcd("x y z".split(), v) + b"\n")         # a trailing newline is not a point
    assert len(read_surfels(path)) == 50


def test_colours_outside_0_255_are_refused(tmp_path):
    v = _cloud(6)
    rows = [f"{a} {b} {c} 9 10 20 30" for a, b, c in v]
    rows[2] = rows[2].replace("10 20 30", "300 20 30")
    rows[4] = rows[4].replace("10 20 30", "-5 20 30")
    (tmp_path / "c.pts").write_text("6\n# scanner export\n" + "\n".join(rows) + "\n")
    with pytest.raises(FileFormatError, match=r"c.pts: PTS colour 300 20 30 on line 5 is outside "
                                              r"0..255 \(2 points so\)"):
        read_surfels(tmp_path / "c.pts")
    one_line_error(["info", tmp_path / "c.pts"], "c.pts: PTS colour 300 20 30 on line 5")
    (tmp_path / "c.xyz").write_text("".join(f"{a} {b} {c} {a} {b} {c} 1 2 -5\n" for a, b, c in v))
    with pytest.raises(FileFormatError, match=r"c.xyz: XYZ colour 1 2 -5 on line 1 is outside"):
        read_surfels(tmp_path / "c.xyz")
    rgb = np.c_[v, np.tile([10, 20, 256], (6, 1))]
    (tmp_path / "c.pcd").write_bytes(pcd("x y z r g b".split(), rgb))
    with pytest.raises(FileFormatError, match=r"c.pcd: PCD colour 10 20 256 on point 0 is "
                                              r"outside 0..255 \(6 points so\)"):
        read_surfels(tmp_path / "c.pcd")


# -- OBJ material libraries -----------------------------------------------------------------------

def _textured_obj(folder, mtllib):
    from conftest import icosphere_mesh

    v, f = icosphere_mesh(2)
    uv = "".join(f"vt {0.5 + 0.4 * a} {0.5 + 0.4 * b}\n" for a, b, c in v)
    faces = "".join("f " + " ".join(f"{i + 1}/{i + 1}" for i in t) + "\n" for t in f)
    path = folder / "m.obj"
    path.write_text(f"mtllib {mtllib}\n" + "".join(f"v {a} {b} {c}\n" for a, b, c in v)
                    + uv + faces)
    return path


def test_mtllib_must_be_an_mtl_file_inside_the_folder(tmp_path):
    folder = tmp_path / "a" / "b"
    folder.mkdir(parents=True)
    (tmp_path / "passwd").write_text("root:x:0:0:root:/root:/bin/bash\nmap_Kd ../../t.png\n")
    path = _textured_obj(folder, "../../passwd")
    with pytest.warns(UserWarning, match=r"m.obj: material library ../../passwd is not an .mtl "
                                         r"file; skipped, no texture from it"):
        assert sio.read_mesh(path).texture is None
    (tmp_path / "t.png").write_bytes(tiny_png(size=4))
    (tmp_path / "out.mtl").write_text("newmtl m\nmap_Kd t.png\n")
    path = _textured_obj(folder, "../../out.mtl")
    with pytest.warns(UserWarning, match=r"m.obj: material library ../../out.mtl lies outside "
                                         r"the model's folder \(allow it with "
                                         r"allow_outside_textures=True"):
        assert sio.read_mesh(path).texture is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert sio.read_mesh(path, allow_outside_textures=True).texture.shape == (4, 4, 3)
    r = CliRunner().invoke(cli, ["info", str(path)])
    assert r.exit_code == 0 and "material library ../../out.mtl lies outside" in r.stderr
    path = _textured_obj(folder, "gone.mtl")
    with pytest.warns(UserWarning, match=r"m.obj: material library gone.mtl not found"):
        assert sio.read_mesh(path).texture is None


def test_ingest_texture_search_reads_no_foreign_mtllib(tmp_path):
    from surfidx.io.files import find_texture

    (tmp_path / "passwd").write_text("map_Kd x.png\n")
    folder = tmp_path / "m"
    folder.mkdir()
    path = _textured_obj(folder, "../passwd")
    (folder / "m.png").write_bytes(tiny_png(size=4))
    assert find_texture(path) == folder / "m.png"      # passwd is not read as its MTL


# -- decoding at a coarser level: time and memory follow the level asked -------------------------

def _bumpy_ball():
    from conftest import icosphere_mesh

    v, f = icosphere_mesh(3)
    return sio.as_surfels((v * (1 + 0.1 * np.sin(3 * v[:, :1])), f))


@pytest.fixture(scope="module")
def level7_stream():
    from surfidx.codec import encode

    return encode(_bumpy_ball(), bits_per_surfel=16.0, level=7)


def forged_level9(data: bytes) -> bytes:
    """A small stream with its header's grid level raised to 9 (frame anchors extended, the
    stream padded to the smallest level-9 file): it decodes, to a surface of its own."""
    from surfidx.codec import container

    h, stream = container.unpack(data)
    h.anchors = tuple(h.anchors) + (h.anchors[-1],) * (9 - len(h.anchors))
    h.level = 9
    return container.pack(h, stream + bytes(container.min_file_bytes(9) + 2000))


def test_read_level():
    from surfidx.codec import read_level

    assert [read_level(lv, 9) for lv in range(10)] == [6, 6, 6, 6, 6, 7, 8, 9, 9, 9]
    assert [read_level(lv, 5) for lv in range(6)] == [5] * 6


def test_coarser_decoding_reads_a_coarser_grid(level7_stream):
    from surfidx.codec import decode
    from surfidx.geometry.icosphere import vertex_count

    full = decode(level7_stream)
    size = np.linalg.norm(np.ptp(full.positions, axis=0))
    for level in (5, 6):                                  # reads level 7: the whole stream
        s = decode(level7_stream, level=level)
        np.testing.assert_array_equal(s.positions, full.positions[:vertex_count(level)])
    for level in (0, 2, 4):                               # reads level 6 only
        s = decode(level7_stream, level=level)
        assert len(s) == vertex_count(level)
        assert np.abs(s.positions - full.positions[:len(s)]).max() < 1e-3 * size


def test_level_2_decoding_of_a_level_9_stream_is_bounded(tmp_path):
    """A 3.9 kB stream claiming the level-9 grid (2,621,442 vertices) decodes at level 2 in
    less than 100 MB more than a level-3 stream does (peak RSS of a fresh process, where the
    zerotree coder's own arrays count too, and the Python allocations traced)."""
    import subprocess
    import sys

    from surfidx.codec import encode

    small = encode(_bumpy_ball(), bits_per_surfel=8.0, level=3)
    (tmp_path / "small.sfz").write_bytes(small)
    (tmp_path / "big.sfz").write_bytes(forged_level9(small))
    script = (
        "import resource, sys, tracemalloc\n"
        "from surfidx.numerics import use_portable_profile\n"
        "use_portable_profile()\n"
        "from surfidx.codec import decode\n"
        "small, big = (open(p, 'rb').read() for p in sys.argv[1:])\n"
        "assert len(decode(small, level=2)) == 162\n"
        "before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
        "tracemalloc.start()\n"
        "assert len(decode(big, level=2)) == 162\n"
        "peak = tracemalloc.get_traced_memory()[1]\n"
        "after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
        "print((after - before) * 1024, peak)\n")
    r = subprocess.run([sys.executable, "-c", script, str(tmp_path / "small.sfz"),
                        str(tmp_path / "big.sfz")], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    rss, traced = map(int, r.stdout.split())
    assert rss < 100e6 and traced < 100e6, (rss, traced)


def test_grid_level_beyond_the_format(tmp_path):
    from surfidx import BitstreamError, InputError
    from surfidx.codec import container, decode, encode

    data = bytearray(encode(_bumpy_ball(), bits_per_surfel=8.0, level=3))
    data[6] = 12
    with pytest.raises(BitstreamError, match=r"big.sfz: corrupt header \(grid level 12; format "
                                             r"version 3 allows 0 … 9\)"):
        decode(bytes(data), path="big.sfz")
    (tmp_path / "big.sfz").write_bytes(bytes(data))
    one_line_error(["decode", tmp_path / "big.sfz", "-o", tmp_path / "o.ply"],
                   "big.sfz: corrupt header (grid level 12")
    h, stream = container.unpack(encode(_bumpy_ball(), bits_per_surfel=8.0, level=3))
    h.level = 10
    with pytest.raises(InputError, match=r"grid level must be 0..9, got 10"):
        container.pack(h, stream)


def test_coarser_decoding_keeps_holes_and_handles(monkeypatch):
    from conftest import torus_mesh

    from surfidx import InputError
    from surfidx.codec import Encoder, decode
    from surfidx.codec import encoder as codec_encoder
    from surfidx.codec.restore import closed_surfels
    from surfidx.topology import analyse, close_surface

    s, fp = closed_surfels(close_surface(*torus_mesh(nu=64, nv=24)))
    data = Encoder(s, face_patch=fp, level=7).encode(4.0)
    for level in (3, 4):                                  # reads level 6 of the level-7 grid
        m = decode(data, level=level, mesh=True)
        assert analyse(m.vertices, m.faces).genus == (1,)
    monkeypatch.setattr(codec_encoder, "READ_LEVEL_MIN", 0)
    monkeypatch.setattr(codec_encoder, "READ_BELOW", 0)
    with pytest.raises(InputError, match=r"m.sfz: the stream's 2 virtual regions .* make \d+ on "
                                         r"the level-0 grid .* decode at level 7"):
        decode(data, level=0, path="m.sfz")


# -- damaged databases: ingest refuses them, lookups say "damaged" -------------------------------

def _stored_model(i):
    import hashlib

    from surfidx.pipeline import ProcessedModel

    rng = np.random.default_rng(i)
    return ProcessedModel(
        name=f"model{i}", source=f"/data/model{i}.ply",
        content_hash=hashlib.sha256(f"model {i}".encode()).hexdigest(), n_surfels=1000,
        has_color=False, bbox=np.array([[0.0, 0, 0], [1, 1, 1]]),
        stream=rng.integers(0, 256, 100, dtype=np.uint8).tobytes(), format_version=1, rate=0.8,
        quality={"psnr_d1": 50.0, "psnr_d2": 60.0, "psnr_y": None},
        descriptors={"shape": rng.standard_normal(16).astype(np.float32)},
        thumbnail=tiny_png(i), params={}, timings={})


def misorder_rowids(path):
    """Set the first divider key of the ``models`` table's root (interior) page to 0: a lookup of
    id 1 then descends into the wrong child and finds nothing, while a scan still reads it."""
    import sqlite3

    conn = sqlite3.connect(path)
    conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    size = conn.execute("PRAGMA page_size").fetchone()[0]
    root = conn.execute("SELECT rootpage FROM sqlite_master WHERE name = 'models'").fetchone()[0]
    conn.close()
    with open(path, "r+b") as fh:
        fh.seek((root - 1) * size)
        page = bytearray(fh.read(size))
        assert page[0] == 5                               # an interior table page
        cell = struct.unpack(">H", page[12:14])[0]        # child pointer (4 bytes), rowid varint
        page[cell + 4] = 0
        fh.seek((root - 1) * size)
        fh.write(bytes(page))


@pytest.fixture
def damaged_db(tmp_path):
    path = tmp_path / "bad.db"
    with Database(path) as db, db.transaction():
        for i in range(500):
            db.add(_stored_model(i))
    misorder_rowids(path)
    return path


def test_lookups_in_a_damaged_database_say_damaged(damaged_db, tmp_path):
    from surfidx import DatabaseError

    damaged = r"bad.db: the database file is damaged \(PRAGMA quick_check: .*Rowid \d+ out of order"
    with Database(damaged_db, readonly=True) as db:
        assert [m["id"] for m in db.list_models()][:2] == [1, 2]     # a scan reads the rows
        assert "out of order" in db.damage()
        for lookup in (lambda: db.get_model(1), lambda: db.get_model("model1"),
                       lambda: db.get_stream(1), lambda: db.resolve(1)):
            with pytest.raises(DatabaseError, match=damaged):
                lookup()
        with pytest.raises(DatabaseError, match=damaged):
            db.check_intact()
    for args in (["show", "1"], ["show", "model1"], ["get", "1", "-o", tmp_path / "x.ply"],
                 ["query", "id:1"], ["query", "model1"], ["query", "nosuch"]):
        one_line_error(args + ["--db", damaged_db], "bad.db: the database file is damaged "
                                                    "(PRAGMA quick_check:")


def test_ingest_refuses_a_damaged_database(damaged_db, tmp_path):
    import ingest
    from surfidx import DatabaseError

    from helpers import fake_processor, make_tree

    root = make_tree(tmp_path / "data", 2)
    before = damaged_db.read_bytes()
    with pytest.raises(DatabaseError, match=r"bad.db: the database file is damaged \(PRAGMA "
                                            r"quick_check: .*\); restore it from a backup"):
        ingest.run([root], db=damaged_db, processor=fake_processor, workers=1, progress=False)
    one_line_error(["ingest", root, "--db", damaged_db, "--no-progress"],
                   "bad.db: the database file is damaged")
    assert damaged_db.read_bytes() == before
    with Database(damaged_db, readonly=True) as db:
        assert db.runs() == []


def test_intact_database_passes_and_missing_ids_stay_missing(tmp_path):
    from surfidx import DatabaseError

    with Database(tmp_path / "ok.db") as db:
        db.add(_stored_model(0))
        assert db.damage() is None
        db.check_intact()
        with pytest.raises(DatabaseError, match=r"ok.db: no model with id 7$"):
            db.get_model(7)
        with pytest.raises(DatabaseError, match=r"ok.db: no model named 'nope'"):
            db.resolve("nope")


# -- data past the header's counts, intensity as grey ---------------------------------------------

def _ply_tet(tmp_path, name, *, ascii, extra):
    from plyfile import PlyData, PlyElement
    v = np.array([tuple(p) for p in TET], dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    f = np.array([(list(t),) for t in TET_FACES], dtype=[("vertex_indices", "i4", (3,))])
    path = tmp_path / name
    PlyData([PlyElement.describe(v, "vertex"), PlyElement.describe(f, "face")],
            text=ascii).write(str(path))
    with open(path, "ab") as fh:
        fh.write(extra)
    return path


@pytest.mark.parametrize("ascii, extra, message", [
    (False, b"\x03" + np.array([0, 1, 2], "<i4").tobytes(),
     r"t.ply: 13 bytes after the elements the PLY header counts are ignored"),
    (True, b"3 0 1 2\n3 1 2 3\n", r"t.ply: 2 lines after the 8 rows the PLY header counts are "
                                   r"ignored"),
])
def test_ply_data_past_the_header_counts_is_named(tmp_path, ascii, extra, message):
    path = _ply_tet(tmp_path, "t.ply", ascii=ascii, extra=extra)
    with pytest.warns(UserWarning, match=message):
        m = sio.read_mesh(path)
    assert len(m.faces) == len(TET_FACES)


@pytest.mark.parametrize("ascii", [False, True])
def test_ply_as_counted_reads_without_a_warning(tmp_path, ascii):
    path = _ply_tet(tmp_path, "t.ply", ascii=ascii, extra=b"")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(sio.read_mesh(path).faces) == len(TET_FACES)


def test_pts_intensity_becomes_grey(tmp_path):
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(60, 3))
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    intensity = np.linspace(-2048, 2047, 60)
    (tmp_path / "i.pts").write_text(f"60\n" + "\n".join(
        f"{a:.6f} {b:.6f} {c:.6f} {i:.0f}" for (a, b, c), i in zip(pts, intensity)) + "\n")
    s = read_surfels(tmp_path / "i.pts")
    grey = s.colors[np.argsort(intensity)]
    assert np.all(grey[:, 0] == grey[:, 1]) and np.all(grey[:, 1] == grey[:, 2])
    assert grey[0, 0] == 0 and grey[-1, 0] == 255 and np.all(np.diff(grey[:, 0].astype(int)) >= 0)
