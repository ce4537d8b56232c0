"""CLI: parameterize and resample, and their one-line errors."""

import json

import numpy as np
from click.testing import CliRunner

from surfidx import read_surfels
from surfidx.cli import cli


def test_parameterize_writes_sphere_positions(tmp_path, models):
    out = tmp_path / "spot_sphere.ply"
    r = CliRunner().invoke(cli, ["parameterize", str(models / "spot" / "spot_triangulated.obj"),
                                 "-o", str(out), "--json"])
    assert r.exit_code == 0, r.output
    fig = json.loads(r.stdout)
    assert fig["method"] == "tutte" and fig["surfels"] == 2930 and fig["mesh_folds"] == 0
    from plyfile import PlyData

    v = PlyData.read(str(out))["vertex"]
    sp = np.column_stack([v["sx"], v["sy"], v["sz"]])
    np.testing.assert_allclose(np.linalg.norm(sp, axis=1), 1.0, atol=1e-9)
    r = CliRunner().invoke(cli, ["parameterize", str(models / "spot" / "spot_triangulated.obj"),
                                 "-o", str(out)])
    assert r.exit_code == 0 and "folded triangles" in r.output


def test_resample_writes_grid(tmp_path, models):
    out = tmp_path / "grid.ply"
    r = CliRunner().invoke(cli, ["resample", str(models / "spot" / "spot_triangulated.obj"),
                                 "-o", str(out), "--level", "4"])
    assert r.exit_code == 0, r.output
    assert len(read_surfels(out)) == 10 * 4 ** 4 + 2
    r = CliRunner().invoke(cli, ["resample", str(models / "spot" / "spot_triangulated.obj"),
                                 "-o", str(out), "--level", "3", "--mesh", "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["grid_vertices"] == 642


def test_genus_error_is_one_line(tmp_path, models):
    r = CliRunner().invoke(cli, ["parameterize", str(models / "rocker-arm.obj"),
                                 "-o", str(tmp_path / "x.ply")])
    assert r.exit_code != 0
    assert "genus 1" in r.output and "Traceback" not in r.output
    assert "rocker-arm.obj: " in r.output          # the message names the file
    assert len(r.output.strip().splitlines()) == 1
