"""CLI: convert and info, plus the error contract (one line, non-zero exit)."""

import json

from click.testing import CliRunner

from surfidx import read_surfels
from surfidx.cli import cli


def test_convert_and_info(tmp_path, models):
    """homer.obj's 6,002 vertices, plus 242 where its longest edges are bisected."""
    out = tmp_path / "homer.ply"
    r = CliRunner().invoke(cli, ["convert", str(models / "homer.obj"), "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert "6244 surfels" in r.output
    assert len(read_surfels(out)) == 6244
    r = CliRunner().invoke(cli, ["info", str(models / "homer.obj"), "--json"])
    info = json.loads(r.output)
    assert info["surfels"] == 6244 and info["closed"] and info["genus"] == 0
    r = CliRunner().invoke(cli, ["info", str(out)])
    assert r.exit_code == 0 and "6244" in r.output


def test_convert_with_texture_and_samples(tmp_path, models):
    out = tmp_path / "spot.ply"
    r = CliRunner().invoke(cli, ["convert", str(models / "spot" / "spot_triangulated.obj"),
                                 "--texture", str(models / "spot" / "spot_texture.png"),
                                 "--samples", "5000", "-o", str(out)])
    assert r.exit_code == 0, r.output
    s = read_surfels(out)
    assert len(s) == 5000 and s.has_color


def test_errors_are_one_line(tmp_path):
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 100\nproperty float x\n"
                    b"property float y\nproperty float z\nend_header\n\x00\x01")
    for args in (["info", str(bad)], ["convert", str(bad), "-o", str(tmp_path / "o.ply")],
                 ["info", str(tmp_path / "missing.obj")]):
        r = CliRunner().invoke(cli, args)
        assert r.exit_code == 1
        assert r.output.startswith("Error: ") and r.output.count("\n") == 1, r.output
        assert "Traceback" not in r.output


def test_python_m_entry_point():
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "surfidx", "--version"], capture_output=True, text=True)
    assert r.returncode == 0 and "surfidx" in r.stdout


# ---------------------------------------------------------------------- hostile input (issue 28)
def _icosphere_obj(tmp_path, name="m.obj", extra="", mtl=None):
    from conftest import icosphere_mesh

    v, f = icosphere_mesh(3)
    head = f"mtllib {name}.mtl\n" if mtl else ""
    uv = "".join(f"vt {0.5 + 0.4 * a} {0.5 + 0.4 * b}\n" for a, b, c in v) if mtl else ""
    corner = "{0}/{0}" if mtl else "{0}"
    faces = "".join("f " + " ".join(corner.format(i + 1) for i in t) + "\n" for t in f)
    p = tmp_path / name
    p.write_text(head + "".join(f"v {a} {b} {c}\n" for a, b, c in v) + uv + faces + extra)
    if mtl:
        (tmp_path / f"{name}.mtl").write_text(f"newmtl m\nmap_Kd {mtl}\n")
    return p


def _one_line_error(r, needle):
    assert r.exit_code == 1, r.output
    assert r.output.startswith("Error: ") and needle in r.output, r.output
    assert r.output.count("\n") == 1 and "Traceback" not in r.output


def test_repeated_corners_no_longer_hang(tmp_path):
    p = _icosphere_obj(tmp_path, extra="f 1 1 2\nf 5 5 9\n")
    for args in (["info", str(p), "--json"], ["convert", str(p), "-o", str(tmp_path / "o.ply")]):
        r = CliRunner().invoke(cli, args)
        assert r.exit_code == 0, r.output
        assert "warning: 2 degenerate faces" in r.stderr
    info = json.loads(CliRunner().invoke(cli, ["info", str(p), "--json"]).stdout)
    assert info["surfels"] == 642 and info["closed"] and info["genus"] == 0


def test_texture_bomb_and_outside_textures(tmp_path):
    from helpers import write_bomb_png, write_png

    write_bomb_png(tmp_path / "bomb.png")
    p = _icosphere_obj(tmp_path, "b.obj", mtl="bomb.png")
    for args in (["info", str(p)], ["convert", str(p), "-o", str(tmp_path / "o.ply")],
                 ["encode", str(p), "-o", str(tmp_path / "o.sfz"), "--bits-per-surfel", "4"]):
        _one_line_error(CliRunner().invoke(cli, args), "bomb.png: texture image exceeds the limit")
    inner = tmp_path / "inner"
    inner.mkdir()
    write_png(tmp_path / "secret.png")
    p = _icosphere_obj(inner, "s.obj", mtl="../secret.png")
    r = CliRunner().invoke(cli, ["info", str(p), "--json"])
    assert r.exit_code == 0 and "lies outside the model's folder; skipped" in r.stderr
    assert json.loads(r.stdout)["color"] is False
    r = CliRunner().invoke(cli, ["info", str(p), "--json",
                                                  "--allow-outside-textures"])
    assert r.exit_code == 0 and json.loads(r.stdout)["color"] is True
    out = tmp_path / "o.ply"
    r = CliRunner().invoke(cli, ["convert", str(p), "-o", str(out), "--allow-outside-textures"])
    assert r.exit_code == 0 and "with colour" in r.output


def test_collinear_points_and_off_variants(tmp_path):
    line = tmp_path / "line.ply"
    line.write_text("ply\nformat ascii 1.0\nelement vertex 50\nproperty float x\nproperty float y"
                    "\nproperty float z\nend_header\n"
                    + "".join(f"{0.1 * i} {0.2 * i} {0.3 * i}\n" for i in range(50)))
    for args in (["info", str(line)], ["convert", str(line), "-o", str(tmp_path / "o.ply")]):
        _one_line_error(CliRunner().invoke(cli, args), "line.ply: the 50 points are collinear")
    from helpers import off_sphere

    off = tmp_path / "s.off"
    off.write_text(off_sphere("OFF {nv} {nf} 0"))
    r = CliRunner().invoke(cli, ["info", str(off), "--json"])
    assert r.exit_code == 0 and json.loads(r.output)["genus"] == 0
    off.write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n1000000 0 1 2\n")
    _one_line_error(CliRunner().invoke(cli, ["info", str(off)]),
                    "s.off: OFF face 0 declares 1,000,000 corners")


def test_unreadable_input_is_one_line(tmp_path, monkeypatch):
    import builtins

    import surfidx.io.limits

    p = _icosphere_obj(tmp_path)
    real_open = builtins.open

    def refusing_open(file, *args, **kwargs):
        if str(file) == str(p):
            raise PermissionError(13, "Permission denied", str(file))
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr(surfidx.io.limits, "open", refusing_open, raising=False)
    for args in (["info", str(p)], ["convert", str(p), "-o", str(tmp_path / "o.ply")]):
        _one_line_error(CliRunner().invoke(cli, args), "m.obj: cannot read (Permission denied)")


def test_zero_surfel_stream_info_is_a_clean_error(tmp_path):
    import struct
    import zlib

    from surfidx.codec.container import Header, pack

    import numpy as np

    h = Header(n_surfels=5, level=2, color=False, lifted=True, mean=np.zeros(3),
               basis=np.eye(3), weights=np.ones(3), coder=bytes(8))
    d = bytearray(pack(h, bytes(16)))
    struct.pack_into("<I", d, 8, 0)
    tail = len(d) - 16 - 12
    struct.pack_into("<I", d, tail + 4, zlib.crc32(bytes(d[:tail + 4])))
    sfz = tmp_path / "zero.sfz"
    sfz.write_bytes(bytes(d))
    _one_line_error(CliRunner().invoke(cli, ["info", str(sfz)]),
                    "zero.sfz: corrupt header (0 input surfels)")


def test_every_command_pairs_the_texture_beside_an_obj(tmp_path):
    """An OBJ with UVs whose MTL names no image takes the PNG beside it in every command, not only
    ingest, and the command says which it paired; --texture still chooses another."""
    from pathlib import Path

    spot = Path(__file__).resolve().parents[1] / "examples/models/spot/spot_triangulated.obj"
    r = CliRunner().invoke(cli, ["info", str(spot), "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["color"] is True
    assert "using spot_texture.png beside it" in r.stderr
    r = CliRunner().invoke(cli, ["encode", str(spot), "-o", str(tmp_path / "s.sfz"),
                                 "--bits-per-surfel", "2", "--json"])
    assert r.exit_code == 0, r.output
    assert "using spot_texture.png beside it" in r.stderr
    assert json.loads(r.stdout)["color"] is True or "color" not in json.loads(r.stdout)
    r = CliRunner().invoke(cli, ["info", str(spot), "--texture", str(spot.parent / "spot_texture.png")])
    assert r.exit_code == 0 and "beside it" not in r.stderr


def test_pair_texture_says_what_it_paired(tmp_path):
    from pathlib import Path

    import pytest

    from surfidx.io import pair_texture

    spot = Path(__file__).resolve().parents[1] / "examples/models/spot/spot_triangulated.obj"
    with pytest.warns(UserWarning, match="using spot_texture.png beside it"):
        assert pair_texture(spot) == spot.parent / "spot_texture.png"
    (tmp_path / "plain.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert pair_texture(tmp_path / "plain.obj") is None                # no UVs: nothing paired
    assert pair_texture(tmp_path / "missing.obj") is None              # left to the reader
