"""The same file gives the same record: byte-identical streams and identical descriptors on every
run, with the CPU kept busy, and with any worker count or executor.

Every iterative stage stops on counts, never on the clock; these tests fail if one stops on time
(under load it would stop elsewhere) or if the result depends on the process it runs in.
"""

import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

import surfidx
from surfidx.pipeline import process_model

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "models"
RATE = 4.0


@contextmanager
def _busy_cpu(n: int = 2):
    """``n`` processes spinning on the CPU while the block runs."""
    spinners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for p in spinners:
            p.kill()
        for p in spinners:
            p.wait()


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A limbed mesh (multilevel map: untangling and balancing at every level) and a textured
    point cloud (spot's vertices without faces: proxy mesh, its map, the repair of the surfels'
    own spherical triangulation)."""
    from helpers import limbs_surfels

    folder = tmp_path_factory.mktemp("inputs")
    surfidx.write_ply(limbs_surfels(4), folder / "limbs.ply")
    s = surfidx.read_surfels(EXAMPLES / "spot" / "spot_triangulated.obj",
                             texture=EXAMPLES / "spot" / "spot_texture.png")
    cloud = surfidx.SurfelSet(s.positions, s.normals, s.radii, s.colors, name="spot_points")
    surfidx.write_ply(cloud, folder / "spot_points.ply")
    return folder, [folder / "limbs.ply", folder / "spot_points.ply"]


@pytest.fixture(scope="module")
def reference(inputs):
    """Each input processed once in this process, on a machine left to itself."""
    _, files = inputs
    return {f.stem: process_model(f, bits_per_surfel=RATE) for f in files}


def _same(a, b):
    assert a.stream == b.stream, f"{a.name}: the streams differ"
    assert a.descriptors.keys() == b.descriptors.keys()
    for kind in a.descriptors:
        x, y = np.asarray(a.descriptors[kind]), np.asarray(b.descriptors[kind])
        if x.dtype != y.dtype:          # the database stores float32
            x, y = x.astype(np.float32), y.astype(np.float32)
        assert np.array_equal(x, y), f"{a.name}: the {kind} descriptors differ"


def test_the_map_runs_its_stages(inputs):
    """The inputs exercise the stages that stop on counts: kernel insertions and balancing on
    several levels, and a proxy mesh."""
    from surfidx.sphere import parameterize

    _, (limbs, cloud) = inputs
    m = parameterize(surfidx.read_surfels(limbs), stress=False)
    assert m.info["levels"] >= 3 and m.info["kernel_insertions"] > 0
    assert m.info["balance_steps"] > 0 and m.folded == 0
    c = parameterize(surfidx.read_surfels(cloud), stress=False)
    assert c.info["proxy_vertices"] > 0 and c.info["mesh_folds"] == 0


def test_same_bytes_with_the_cpu_busy(inputs, reference):
    _, files = inputs
    with _busy_cpu():
        busy = {f.stem: process_model(f, bits_per_surfel=RATE) for f in files}
    for name in reference:
        _same(reference[name], busy[name])


@pytest.mark.parametrize("how", ["pool", "dask"])
def test_same_record_with_two_workers(inputs, reference, tmp_path, how):
    """Ingest with two pool workers or a two-worker Dask LocalCluster stores exactly what one
    process computes."""
    from ingest import run

    if how == "dask":
        pytest.importorskip("distributed")
    folder, _ = inputs
    db = surfidx.Database(tmp_path / "two.db")
    summary = run([folder], db=db, workers=2, bits_per_surfel=RATE, progress=False,
                  scheduler="local" if how == "dask" else None)
    assert summary.stored == 2 and summary.failed == 0
    for rec in db.list_models():
        stored = db.load(rec["id"])
        _same(reference[stored.name], stored)
