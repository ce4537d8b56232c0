"""The options tree: round trip, files, validation, and its way from the CLI to the map."""

import json
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from surfidx import InputError, TriangleMesh
from surfidx.codec import CodecOptions, Encoder, code, decode, prepare, with_level_hints
from surfidx.codec.container import unpack
from surfidx.describe import DescribeOptions
from surfidx.options import ProcessOptions
from surfidx.sphere import MapOptions


def test_defaults_round_trip_through_json():
    o = ProcessOptions()
    d = json.loads(json.dumps(o.to_dict(), allow_nan=False))    # strict JSON (no Infinity)
    assert ProcessOptions.from_dict(d) == o
    assert d["codec"]["bits_per_surfel"] == 8.0 and d["thumbnail_size"] == 192
    assert d["describe"]["lmax"] == 24 and d["map"]["method"] == "tutte"


def test_changed_tree_round_trips():
    o = ProcessOptions(map=MapOptions(iterations=7, settle_energy=2e5),
                       codec=CodecOptions(bits_per_surfel=3.0, tangent_weight=None),
                       describe=DescribeOptions(lmax=12), samples=500, up="+z")
    assert ProcessOptions.from_dict(json.loads(json.dumps(o.to_dict()))) == o


def test_partial_dict_keeps_defaults():
    o = ProcessOptions.from_dict({"map": {"gamma": 0.3}})
    assert o.map.gamma == 0.3 and o.codec == CodecOptions()


def test_load_json_and_toml(tmp_path):
    j = tmp_path / "o.json"
    j.write_text(json.dumps({"codec": {"bits_per_surfel": 4.0}, "map": {"iterations": 9}}))
    t = tmp_path / "o.toml"
    t.write_text("samples = 800\n[codec]\nbits_per_surfel = 4.0\n[map]\niterations = 9\n"
                 "settle_energy = 2e5\n")
    a, b = ProcessOptions.load(j), ProcessOptions.load(t)
    assert a.codec.bits_per_surfel == b.codec.bits_per_surfel == 4.0
    assert a.map.iterations == b.map.iterations == 9 and b.samples == 800
    assert b.map.settle_energy == 2e5


@pytest.mark.parametrize("text, match", [
    ('{"codec": {"bits_per_surfel": -1}}', r"o\.json.*bits_per_surfel"),
    ('{"map": {"gamma": 3}}', r"o\.json.*MapOptions\.gamma must be at most 2, got 3"),
    ('{"mapp": {}}', r"o\.json: unknown option 'mapp'"),
    ('{"map": {"nope": 1}}', r"o\.json: unknown option 'map\.nope'"),
    ('{"map": 3}', r"o\.json: option 'map' must be a table"),
    ('{"describe": {"lmax": 0}}', r"DescribeOptions\.lmax must be at least 1, got 0"),
    ('{"map": {"method": "magic"}}', r"MapOptions\.method must be one of 'tutte', 'mds'"),
    ('{"codec": {"tangent_weight": 2}}', r"CodecOptions\.tangent_weight must be at most 1"),
    ('{"samples": 2}', r"ProcessOptions\.samples must be at least 4, got 2"),
    ('{"up": "z"}', r"ProcessOptions\.up must be one of '\+y', '\+z', '\+x', '-y', '-z', "
                    r"'-x', got 'z'"),
    ('{"codec": {"level": "x"}}', r"CodecOptions\.level must be an integer >= 0 or None"),
    ('[1, 2]', r"o\.json: options must be a table of settings"),
    ('{"codec": ', r"o\.json: not valid JSON"),
])
def test_bad_files_name_the_file_and_key(tmp_path, text, match):
    p = tmp_path / "o.json"
    p.write_text(text)
    with pytest.raises(InputError, match=match):
        ProcessOptions.load(p)


def test_bad_toml_and_suffix(tmp_path):
    p = tmp_path / "o.toml"
    p.write_text("[codec\n")
    with pytest.raises(InputError, match=r"o\.toml: not valid TOML"):
        ProcessOptions.load(p)
    with pytest.raises(InputError, match=r"o\.yaml: an options file must end in \.json or "):
        ProcessOptions.load(tmp_path / "o.yaml")
    with pytest.raises(InputError, match=r"missing\.json: cannot read options"):
        ProcessOptions.load(tmp_path / "missing.json")


def test_parts_validate_themselves():
    with pytest.raises(InputError, match=r"CodecOptions\.bits_per_surfel must be above 0"):
        CodecOptions(bits_per_surfel=0.0)
    with pytest.raises(InputError, match=r"CodecOptions\.color_weight must be at most 1000"):
        CodecOptions(color_weight=2e3)
    with pytest.raises(InputError, match=r"ProcessOptions\.map must be a MapOptions"):
        ProcessOptions(map={})
    with pytest.raises(InputError, match=r"ProcessOptions\.thumbnail_size must be at most 8192"):
        ProcessOptions(thumbnail_size=10_000)


def test_resolve_keywords_override():
    o = ProcessOptions.resolve(ProcessOptions(codec=CodecOptions(bits_per_surfel=2.0)),
                               bits_per_surfel=None, level=4, method="mds", lmax=8)
    assert (o.codec.bits_per_surfel, o.codec.level, o.map.method, o.describe.lmax) == \
        (2.0, 4, "mds", 8)
    with pytest.raises(InputError, match="method must be one of tutte, mds, got 'x'"):
        ProcessOptions.resolve(None, method="x")


@pytest.fixture(scope="module")
def ball():
    from conftest import icosphere_mesh

    v, f = icosphere_mesh(3)
    return TriangleMesh(v * [1.0, 1.2, 0.9], f, name="ball").to_surfels()


def test_encoder_steps_give_the_encoders_stream(ball):
    p = prepare(ball, CodecOptions(level=3, level_hints=True))
    assert p.level == 3 and p.grid.shape == (642, 3) and p.coeffs.shape[0] == 642
    assert p.report()["grid_level"] == 3 and p.report()["map_method"] == "tutte"
    a = with_level_hints(code(p, 4.0), ball)   # the output-level codes measured on the input
    assert a == Encoder(ball, level=3, options=CodecOptions(level_hints=True)).encode(4.0)
    assert unpack(code(p, 4.0))[1] == unpack(a)[1]
    with pytest.raises(InputError, match="no output-level section"):
        with_level_hints(code(replace(p, level_hints=False), 4.0), ball)
    assert len(a) <= int(np.ceil(4.0 * len(ball) / 8))
    assert len(decode(a).positions) > 0
    # the map's options reach parameterize (a sphere_map given skips it)
    q = prepare(ball, CodecOptions(level=3, level_hints=True), sphere_map=p.sphere_map)
    assert with_level_hints(code(q, 4.0), ball) == a


def test_code_refuses_a_rate_below_the_header(ball):
    p = prepare(ball, CodecOptions(level=3))
    with pytest.raises(InputError, match="cannot hold the header"):
        code(p, 0.01)


def test_cli_options_file_reaches_the_map_and_the_stored_params(tmp_path, ball):
    from surfidx.cli import cli
    from surfidx.database import Database
    from surfidx.io import write_model

    mesh = tmp_path / "ball.ply"
    write_model(TriangleMesh(ball.positions, ball.faces), mesh)
    opts = tmp_path / "opts.toml"
    opts.write_text("[map]\niterations = 7\n[codec]\nbits_per_surfel = 6.0\n"
                    "[describe]\nlmax = 12\n")
    db = tmp_path / "m.db"
    r = CliRunner().invoke(cli, ["ingest", str(mesh), "--db", str(db), "--workers", "1",
                                 "--options", str(opts), "--bits-per-surfel", "5",
                                 "--no-progress"], obj={})
    assert r.exit_code == 0, r.output
    with Database(db) as d:
        params = d.get_model(1)["params"]
    assert params["map"]["iterations"] == 7                 # from the file
    assert params["codec"]["bits_per_surfel"] == 5.0        # the flag wins
    assert params["describe"]["lmax"] == 12 and params["descriptors"]["lmax"] == 12
    assert params["grid_level"] >= 0 and params["map_method"] == "tutte"
    assert set(params["provenance"]) >= {"surfidx", "numpy", "scipy", "numba",
                                         "numerics_profile"}


def test_up_reaches_the_thumbnail_and_the_stored_params(tmp_path):
    """A +z-up scan (an XYZ file) of a standing figure is stored with an upright thumbnail;
    ``--up`` overrides the format's axis, which changes the thumbnail and nothing else."""
    import io

    from PIL import Image

    from conftest import icosphere_mesh
    from surfidx.cli import cli
    from surfidx.database import Database
    from surfidx.pipeline import describe_model

    v, _ = icosphere_mesh(3)
    scan = tmp_path / "pole.xyz"
    np.savetxt(scan, v * [0.5, 0.35, 2.0], fmt="%.6f")      # taller along z than wide

    def ingest(db, *flags):
        r = CliRunner().invoke(cli, ["ingest", str(scan), "--db", str(db), "--workers", "1",
                                     "--no-progress", *flags], obj={})
        assert r.exit_code == 0, r.output
        with Database(db) as d:
            png = d.get_thumbnail(1)
            return d.get_model(1)["params"], d.get_stream(1), d.get_descriptors(1), png

    def extent(png):
        img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
        cov = np.any(img != 255, axis=2)
        rows, cols = np.flatnonzero(cov.any(axis=1)), np.flatnonzero(cov.any(axis=0))
        return rows[-1] - rows[0] + 1, cols[-1] - cols[0] + 1

    params, stream, desc, png = ingest(tmp_path / "a.db")
    assert params["up"] == "+z"                             # the XYZ format's
    h, w = extent(png)
    assert h > 2 * w
    # a query's example is drawn the same way (its contact sheet's first picture)
    h, w = extent(describe_model(scan, level=3, thumbnail_size=64).thumbnail)
    assert h > 2 * w
    params_x, stream_x, desc_x, png_x = ingest(tmp_path / "b.db", "--up", "X")
    assert params_x["up"] == "+x"
    h, w = extent(png_x)
    assert w > 1.3 * h                                      # told +x is up: it lies
    assert stream_x == stream and desc_x.keys() == desc.keys()
    assert all(np.array_equal(desc_x[k], desc[k]) for k in desc)
    # a bad axis is a one-line error before anything is written
    r = CliRunner().invoke(cli, ["ingest", str(scan), "--db", str(tmp_path / "c.db"),
                                 "--up", "sideways"], obj={})
    assert r.exit_code != 0 and "unknown up axis 'sideways'; use one of +y" in r.output
    assert "Traceback" not in r.output and not (tmp_path / "c.db").exists()
