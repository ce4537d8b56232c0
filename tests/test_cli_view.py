"""CLI: ``surfidx eval`` and ``surfidx render``, and their one-line error contract."""

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image
from plyfile import PlyData, PlyElement

from surfidx import SurfelSet, read_surfels, write_ply
from surfidx.cli import cli
from surfidx.geometry.metrics import evaluate


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.fixture
def pair(tmp_path, sphere_surfels):
    """A coloured sphere and a noisy copy (with different colours) as surfel PLYs."""
    rng = np.random.default_rng(2)
    s = sphere_surfels
    noisy = SurfelSet(s.positions + rng.normal(scale=0.01, size=s.positions.shape), s.normals,
                      s.radii, np.clip(s.colors.astype(int) + rng.integers(-9, 10, s.colors.shape),
                                       0, 255))
    a, b = tmp_path / "ref.ply", tmp_path / "test.ply"
    write_ply(s, a)
    write_ply(noisy, b)
    return a, b


def write_path_ply(path, points):
    data = np.empty(len(points), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                        ("dist", "<f8")])
    data["x"], data["y"], data["z"] = points.T
    data["dist"] = np.arange(len(points))
    PlyData([PlyElement.describe(data, "vertex")]).write(str(path))


def assert_one_line_error(r, fragment):
    assert r.exit_code != 0
    assert r.output.startswith("Error: ") and r.output.count("\n") == 1, r.output
    assert fragment in r.output, r.output
    assert "Traceback" not in r.output


# ---------------------------------------------------------------------- eval
def test_eval_json_agrees_with_library(pair):
    a, b = pair
    r = run("eval", a, b, "--json")
    assert r.exit_code == 0, r.output
    out = json.loads(r.output)
    lib = evaluate(read_surfels(a), read_surfels(b))
    assert set(out) == set(lib) == {"psnr_d1", "psnr_d2", "psnr_y", "hausdorff", "rmse_d1",
                                    "rmse_d2", "peak", "n_reference", "n_test"}
    for key, val in lib.items():
        assert out[key] == pytest.approx(val, rel=1e-12), key
    assert out["psnr_d2"] >= out["psnr_d1"] and out["psnr_y"] is not None


def test_eval_text_output(pair):
    a, b = pair
    r = run("eval", a, b)
    assert r.exit_code == 0, r.output
    lines = dict(line.split(None, 1) for line in r.output.strip().splitlines())
    lib = evaluate(read_surfels(a), read_surfels(b))
    assert float(lines["psnr_d1"]) == pytest.approx(lib["psnr_d1"], rel=1e-5)
    assert float(lines["hausdorff"]) == pytest.approx(lib["hausdorff"], rel=1e-5)
    assert lines["n_test"].strip() == str(len(read_surfels(b)))


def test_eval_identity_and_no_colour(tmp_path, pair, sphere_surfels):
    a, _ = pair
    r = run("eval", a, a)
    lines = dict(line.split(None, 1) for line in r.output.strip().splitlines())
    assert lines["psnr_d1"] == "inf" and lines["psnr_y"] == "inf"
    grey = tmp_path / "grey.ply"
    write_ply(sphere_surfels.without_color(), grey)
    out = json.loads(run("eval", a, grey, "--json").output)
    assert out["psnr_y"] is None and math.isinf(out["psnr_d1"])
    assert "psnr_y       -" in run("eval", a, grey).output


def test_eval_peak_option(pair):
    a, b = pair
    out = json.loads(run("eval", a, b, "--json", "--peak", "100").output)
    ref = evaluate(read_surfels(a), read_surfels(b), peak=100.0)
    assert out["psnr_d1"] == pytest.approx(ref["psnr_d1"]) and out["peak"] == 100.0


# ---------------------------------------------------------------------- render
def test_render_writes_png(tmp_path, pair):
    a, _ = pair
    out = tmp_path / "front.png"
    r = run("render", a, "-o", out, "--view", "front", "--size", "90x60")
    assert r.exit_code == 0, r.output
    with Image.open(out) as im:
        img = np.asarray(im.convert("RGB"))
    assert img.shape == (60, 90, 3)
    assert tuple(img[0, 0]) == (255, 255, 255) and tuple(img[30, 45]) != (255, 255, 255)
    # --azimuth/--elevation 0 0 is the front view
    out2 = tmp_path / "angles.png"
    assert run("render", a, "-o", out2, "--azimuth", "0", "--elevation", "0",
               "--size", "90x60").exit_code == 0
    with Image.open(out2) as im:
        assert np.array_equal(np.asarray(im.convert("RGB")), img)
    # another view gives another image
    out3 = tmp_path / "top.png"
    assert run("render", a, "-o", out3, "--view", "top", "--size", "90x60").exit_code == 0
    with Image.open(out3) as im:
        assert not np.array_equal(np.asarray(im.convert("RGB")), img)


def test_render_with_path_overlay(tmp_path, pair):
    a, _ = pair
    t = np.linspace(-1.4, 1.4, 40)
    path = tmp_path / "path.ply"
    write_path_ply(path, np.stack([np.sin(t), np.zeros_like(t), np.cos(t)], axis=1))
    plain, over = tmp_path / "plain.png", tmp_path / "over.png"
    assert run("render", a, "-o", plain, "--view", "front", "--size", "80").exit_code == 0
    r = run("render", a, "-o", over, "--view", "front", "--size", "80", "--path", path)
    assert r.exit_code == 0, r.output
    with Image.open(plain) as p, Image.open(over) as o:
        p, o = np.asarray(p.convert("RGB")), np.asarray(o.convert("RGB"))
    changed = np.any(p != o, axis=2)
    assert changed[40, 15:65].all()                       # along the equator
    assert not changed[:30].any() and not changed[50:].any()  # and nowhere else


def test_render_mesh_with_texture_and_samples(tmp_path, models):
    out = tmp_path / "spot.png"
    r = run("render", models / "spot" / "spot_triangulated.obj", "--texture",
            models / "spot" / "spot_texture.png", "--samples", "3000", "--size", "64", "-o", out)
    assert r.exit_code == 0, r.output
    with Image.open(out) as im:
        img = np.asarray(im.convert("RGB")).astype(int)
    assert (np.ptp(img, axis=2) > 30).any()  # coloured pixels, not only grey


# ---------------------------------------------------------------------- errors
def test_errors_are_one_line(tmp_path, pair):
    a, b = pair
    png = tmp_path / "o.png"
    truncated = tmp_path / "trunc.ply"
    truncated.write_bytes(a.read_bytes()[:300])
    nan = tmp_path / "nan.ply"
    nan.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                   "property float z\nproperty float nx\nproperty float ny\nproperty float nz\n"
                   "property float radius\nend_header\n0 0 0 0 0 1 1\nnan 0 0 0 0 1 1\n"
                   "1 1 0 0 0 1 1\n")
    cases = [
        (["eval", tmp_path / "missing.ply", b], "no such file"),
        (["eval", a, truncated], "truncated"),
        (["eval", nan, a], "NaN"),
        (["render", tmp_path / "missing.ply", "-o", png], "no such file"),
        (["render", truncated, "-o", png], "truncated"),
        (["render", a, "-o", png, "--size", "big"], "--size must be WIDTHxHEIGHT"),
        (["render", a, "-o", png, "--size", "0x10"], "between 1 and 8192"),
        (["render", a, "-o", png, "--view", "side"], "unknown view 'side'"),
        (["render", a, "-o", png, "--view", "top", "--azimuth", "3"], "not both"),
        (["render", a, "-o", png, "--up", "w"], "unknown up axis"),
        (["render", a, "-o", png, "--supersample", "0"], "supersample must be at least 1"),
        (["render", a, "-o", png, "--path", tmp_path / "nopath.ply"], "no such file"),
        (["render", a, "-o", png, "--path", truncated], "truncated"),
        (["render", a, "-o", tmp_path / "no" / "dir.png"], "cannot write the PNG"),
    ]
    for args, fragment in cases:
        assert_one_line_error(run(*args), fragment)
    assert not png.exists()


def test_path_file_errors(tmp_path, pair):
    a, _ = pair
    png = tmp_path / "o.png"
    noxyz = tmp_path / "noxyz.ply"
    data = np.zeros(3, dtype=[("u", "<f4"), ("v", "<f4")])
    PlyData([PlyElement.describe(data, "vertex")]).write(str(noxyz))
    assert_one_line_error(run("render", a, "-o", png, "--path", noxyz), "lacks x y z")
    nanpath = tmp_path / "nanpath.ply"
    write_path_ply(nanpath, np.array([[0.0, 0, 1], [np.nan, 0, 1]]))
    assert_one_line_error(run("render", a, "-o", png, "--path", nanpath), "NaN")
    obj = tmp_path / "path.obj"
    obj.write_text("v 0 0 0\n")
    assert_one_line_error(run("render", a, "-o", png, "--path", obj), "must be a PLY")
    empty = tmp_path / "empty.ply"
    PlyData([PlyElement.describe(np.zeros(0, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")]),
                                 "vertex")]).write(str(empty))
    assert_one_line_error(run("render", a, "-o", png, "--path", empty), "no vertices")
    faces_only = tmp_path / "faces.ply"
    PlyData([PlyElement.describe(np.zeros(1, dtype=[("k", "i4")]), "face")]).write(
        str(faces_only))
    assert_one_line_error(run("render", a, "-o", png, "--path", faces_only), "no 'vertex'")


def test_render_names_the_output_on_one_line(tmp_path, pair):
    """A file name with control characters is printed escaped (#30)."""
    a, _ = pair
    out = tmp_path / "evil\x1b[2J\nname.png"
    r = run("render", a, "-o", out, "--size", "20x20", "--supersample", 1)
    assert r.exit_code == 0, r.output
    assert out.exists() and "\x1b" not in r.output and r.output.count("\n") == 1
    assert "evil\\x1b[2J\\nname.png: 20x20" in r.output
