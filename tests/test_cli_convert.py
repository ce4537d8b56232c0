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
