#!/usr/bin/env bash
# The main job on the bundled example models: ingest them into the default database (surfidx.db),
# query by example, retrieve a compressed asset at a lower rate, measure and render it.
# Outputs go to ./out/; running it again skips the models already stored.
set -euo pipefail
cd "$(dirname "$0")/.."
M=examples/models
DB=surfidx.db
mkdir -p out

surfidx ingest "$M" --db "$DB" --workers 2 --bits-per-surfel 8
surfidx ls --db "$DB"

# query by example: a rotated, rescaled copy of the armadillo finds the stored armadillo first
python - <<'PY'
import numpy as np
import surfidx
s = surfidx.read_surfels("examples/models/armadillo.obj")
q, _ = np.linalg.qr(np.random.default_rng(7).normal(size=(3, 3)))
surfidx.write_ply(s.transformed(rotation=q * np.sign(np.linalg.det(q)), translation=[1, 2, 3],
                                scale=3.0), "out/armadillo_moved.ply")
PY
surfidx query out/armadillo_moved.ply --db "$DB" -k 2 --sheet out/query.png

# retrieval: the stored 8 bits/surfel stream, truncated to 2 bits/surfel
surfidx get armadillo --db "$DB" --bits-per-surfel 2 -o out/armadillo_2bps.ply
surfidx get spot_triangulated --db "$DB" --bits-per-surfel 4 -o out/spot_4bps.glb   # for any viewer
surfidx eval "$M/armadillo.obj" out/armadillo_2bps.ply
surfidx render out/armadillo_2bps.ply -o out/armadillo_2bps.png
echo "demo finished: database $DB, outputs in ./out (query.png, armadillo_2bps.ply/.png, spot_4bps.glb)"
