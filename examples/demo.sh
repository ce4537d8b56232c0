#!/usr/bin/env bash
# The main job on the bundled example models; writes into ./out/.
set -euo pipefail
cd "$(dirname "$0")/.."
M=examples/models
mkdir -p out
surfidx info "$M/armadillo.obj"
surfidx convert "$M/spot/spot_triangulated.obj" --texture "$M/spot/spot_texture.png" -o out/spot.ply
surfidx convert "$M/armadillo.obj" -o out/armadillo.ply
surfidx info out/spot.ply
echo "demo finished: outputs in ./out"
