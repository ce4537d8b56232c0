"""Zerotree (SPIHT + adaptive arithmetic coding) benchmark: rate vs MSE, embedded prefixes vs direct
encoding, and encode/decode times on the icosahedral zerotree forest.

Signal: a bumpy star-shaped surface ``x(u) = r(u) u`` sampled on the level-L grid (3 layers), plus
an optional colour-like layer set, transformed by the normalised lifted butterfly wavelets, so
coefficient-domain MSE is the grid-domain MSE per layer.

Run: ``python benchmarks/zerotree.py [--levels 5 6 7 8] [--bits 0.5 1 2 4 8]``.
"""

from __future__ import annotations

import argparse
import time

from surfidx.numerics import use_portable_profile  # noqa: E402

use_portable_profile()   # before numpy loads: the bytes the surfidx command makes
import numpy as np

from surfidx.codec import wavelets, zerotree
from surfidx.geometry.icosphere import icosphere

from _markdown import Report, add_markdown_option


def surface(level: int, seed: int = 0) -> np.ndarray:
    """(n, 3) float64: a star-shaped surface with bumps of several sizes and a little noise."""
    ico = icosphere(level)
    u = ico.vertices
    rng = np.random.default_rng(seed)
    r = np.ones(len(u))
    for width, count, amp in ((0.6, 6, 0.15), (0.25, 20, 0.05), (0.08, 80, 0.01)):
        centres = rng.standard_normal((count, 3))
        centres /= np.linalg.norm(centres, axis=1)[:, None]
        for c in centres:
            r += amp * rng.uniform(-1, 1) * np.exp(-(1 - u @ c) / width ** 2)
    r += 2e-4 * rng.standard_normal(len(u))
    return r[:, None] * u


def psnr(mse: float, peak: float = 2.0) -> float:
    return 10 * np.log10(peak ** 2 / mse) if mse > 0 else float("inf")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--levels", type=int, nargs="+", default=[5, 6, 7, 8])
    ap.add_argument("--bits", type=float, nargs="+", default=[0.25, 0.5, 1, 2, 4, 8],
                    help="rates in bits per grid node (all layers together)")
    ap.add_argument("--step", type=float, default=1e-5)
    add_markdown_option(ap, "zerotree")
    args = ap.parse_args()
    report = Report("zerotree", "Zerotree coder: rate against MSE, embedded prefixes",
                    args.markdown,
                    note="A synthetic bumpy star-shaped surface on the level-L grid, "
                         "transformed by the normalised lifted butterfly wavelets and coded by "
                         "the zerotree coder alone. `prefix==direct`: decoding the first bytes "
                         "of the stream at the highest rate gives the same as a stream encoded "
                         "at the lower rate (the stream is embedded). Times are wall seconds.")
    for level in args.levels:
        ico = icosphere(level)
        n = ico.n_vertices
        tree = (ico.tree_parent, ico.children_indptr, ico.children_indices)
        c = wavelets.forward(surface(level), level, lifted=True, normalized=True)
        k = c.shape[1]
        zerotree.encode(c[:100 * 0 + 12], np.full(12, -1), np.zeros(13, np.int64),
                        np.zeros(0, np.int64))  # warm the numba cache
        top_bytes = int(np.ceil(max(args.bits) * n / 8))
        t = time.perf_counter()
        full, header = zerotree.encode(c, *tree, step=args.step, max_bytes=top_bytes)
        t_enc_full = time.perf_counter() - t
        report.heading(f"Level {level}")
        report.text(f"n = {n} nodes x k = {k} layers; step {args.step:g}; stream at "
                    f"{max(args.bits):g} b/node = {len(full)} B, encoded in {t_enc_full:.2f} s")
        rows = []
        for b in args.bits:
            budget = int(np.ceil(b * n / 8))
            t = time.perf_counter()
            direct, _ = zerotree.encode(c, *tree, step=args.step, max_bytes=budget)
            t_enc = time.perf_counter() - t
            t = time.perf_counter()
            rec = zerotree.decode(direct, n, k, *tree, header=header)
            t_dec = time.perf_counter() - t
            pre = zerotree.decode(full[:budget], n, k, *tree, header=header)
            mse = float(np.mean((rec - c) ** 2))
            same = np.array_equal(rec, pre)
            rows.append([f"{b:.2f}", len(direct), f"{mse:.4e}", f"{psnr(mse):.2f}", same,
                         f"{t_enc:.2f}", f"{t_dec:.2f}"])
        report.table(["b/node", "bytes", "MSE", "PSNR dB", "prefix==direct", "enc s", "dec s"],
                     rows)
    report.finish()


if __name__ == "__main__":
    main()
