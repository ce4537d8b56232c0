"""Make ``geodesic_bunny_hr.json``: exact polyhedral geodesic distances on bunny_hr.obj.

Exact MMP distances (``pygeodesic``, a benchmark-only dependency: ``pip install pygeodesic``)
from 3 random surfels to 30 random surfels of ``../shared/data/models/bunny_hr.obj`` (surfel
indices = the mesh's vertex order), frozen for ``tests/test_geodesics.py``.

Run: ``python tests/data/make_geodesic_reference.py``.
"""

import json
from pathlib import Path

import numpy as np
import pygeodesic.geodesic as pg

from surfidx import read_surfels

HERE = Path(__file__).resolve().parent
MODEL = HERE.parents[2] / "shared" / "data" / "models" / "bunny_hr.obj"


def main():
    s = read_surfels(MODEL)
    rng = np.random.default_rng(2024)
    sources = rng.choice(len(s), 3, replace=False)
    targets = rng.choice(len(s), 30, replace=False)
    geo = pg.PyGeodesicAlgorithmExact(s.positions, s.faces)
    exact = [geo.geodesicDistances(np.array([a]), targets)[0].tolist() for a in sources]
    out = {"model": "bunny_hr.obj", "surfels": len(s), "method": "pygeodesic exact (MMP)",
           "sources": sources.tolist(), "targets": targets.tolist(), "distances": exact}
    (HERE / "geodesic_bunny_hr.json").write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
