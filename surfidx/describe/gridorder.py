"""The nested-dissection orders of the icosahedral grids' Laplacians, computed once and shipped.

The *spectral* and *heat* parts of the shape descriptor factor the cotangent Laplacian of the
grid mesh of level ``min(level, SPECTRAL_LEVEL)`` (beyond 700 vertices; smaller grids are solved
densely). Its sparsity pattern is the grid's own, every edge and the diagonal, whatever the
model, so METIS orders it the same way for every model: that order
(:func:`surfidx.geometry.sparse.nested_dissection` of :func:`grid_pattern`) is stored in the
package's ``data`` folder, one ``grid_order_<level>.npy`` per level of :data:`ORDER_LEVELS`,
and a query or an ingest reads it instead of asking METIS again (:func:`grid_solver`). A
matrix with another pattern (a cotangent weight that sums to exactly zero drops its entry) is
ordered for itself, as before, so the factors are the same either way.

``python -m surfidx.describe.gridorder`` writes the files; ``tests/test_descriptors.py``
checks them against METIS.
"""

from __future__ import annotations

import functools
import os

import numpy as np

__all__ = ["ORDER_LEVELS", "grid_pattern", "grid_order", "stored_grid_order", "grid_solver",
           "write_grid_orders"]

#: Grid levels whose Laplacian order is stored: those of more than 700 vertices up to the
#: spectral part's level (``SPECTRAL_LEVEL`` of :mod:`surfidx.describe.descriptors`).
ORDER_LEVELS = (4, 5)

_DATA = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data")


def _path(level: int, folder: str = _DATA) -> str:
    return os.path.join(folder, f"grid_order_{int(level)}.npy")


def grid_pattern(level: int) -> tuple[np.ndarray, np.ndarray]:
    """``(indptr, indices)`` of the level-``level`` grid Laplacian's sparsity pattern (CSR,
    sorted indices): every edge of the icosphere and the diagonal, as
    :meth:`surfidx.geometry.sparse.SPDSolver.factor` sees a grid Laplacian none of whose
    entries is zero."""
    import scipy.sparse as sp

    from ..geometry.icosphere import icosphere, vertex_count
    from ..geometry.mesh import cotangent_laplacian

    f = icosphere(level).faces
    n = vertex_count(level)
    a = sp.csr_matrix(cotangent_laplacian(f, np.ones(f.shape), n) + sp.identity(n))
    a.sort_indices()
    return a.indptr, a.indices


def grid_order(level: int) -> np.ndarray:
    """(n_grid,) int64 METIS's nested-dissection order of :func:`grid_pattern` (computed)."""
    import scipy.sparse as sp

    from ..geometry.sparse import nested_dissection

    indptr, indices = grid_pattern(level)
    n = len(indptr) - 1
    return nested_dissection(sp.csr_matrix((np.ones(len(indices)), indices, indptr),
                                           shape=(n, n)))


def stored_grid_order(level: int) -> np.ndarray | None:
    """(n_grid,) int64 the stored :func:`grid_order` of a level, or None when none is stored."""
    path = _path(level)
    if not os.path.isfile(path):
        return None
    return np.load(path, allow_pickle=False).astype(np.int64)


@functools.lru_cache(maxsize=4)
def grid_solver(level: int):
    """The :class:`surfidx.geometry.sparse.SPDSolver` of the level-``level`` grid's
    Laplacians (one per level and process): it knows the grid pattern's stored order, and
    orders any other pattern itself."""
    from ..geometry.sparse import SPDSolver

    order = stored_grid_order(level)
    if order is None:
        return SPDSolver()
    return SPDSolver(pattern=grid_pattern(level), order=order)


def write_grid_orders(folder: str = _DATA) -> list[str]:
    """Compute :func:`grid_order` of each level of :data:`ORDER_LEVELS` and write it to
    ``folder/grid_order_<level>.npy`` (uint16); returns the paths."""
    out = []
    for level in ORDER_LEVELS:
        order = grid_order(level)
        assert order.max() < 2 ** 16
        path = _path(level, folder)
        np.save(path, order.astype(np.uint16), allow_pickle=False)
        out.append(path)
    return out


if __name__ == "__main__":  # pragma: no cover
    for written in write_grid_orders():
        print(written)
