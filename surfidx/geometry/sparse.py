"""Sparse symmetric positive definite systems, factored in a nested-dissection order.

The sphere stage factors mesh Laplacians (the balancing's preconditioner, circle-pattern Newton
steps). SuperLU's own column orders fill such factors several times more than a nested
dissection does (METIS, through pymetis), and the solves cost what the factors hold. The matrix
is permuted symmetrically by that order and factored with diagonal pivots, which a positive
definite matrix needs no more than.

The order depends on the sparsity pattern alone: :class:`SPDSolver` computes it once per
pattern, so the factorisations of one mesh's matrices (Newton's Jacobians) share it, or is
handed the order of a pattern known in advance (the icosahedral grid's, which every model's
grid Laplacian has); :func:`spd_factor` is the one-call form. METIS orders with its fixed default
seed (:func:`nested_dissection`), so the same matrix gives the same factors and solutions on
every run.
"""

from __future__ import annotations

from ..errors import InputError
from ..jit import numba
import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

__all__ = ["SPDSolver", "SPDFactor", "spd_factor", "nested_dissection"]


@numba.njit(cache=True)
def _gather_rows(b, perm, out):  # pragma: no cover - compiled
    """``out[i] = b[perm[i]]`` (one pass, into ``out``'s own layout)."""
    for c in range(b.shape[1]):
        for i in range(b.shape[0]):
            out[i, c] = b[perm[i], c]


@numba.njit(cache=True)
def _scatter_rows(y, perm, out):  # pragma: no cover - compiled
    """``out[perm[i]] = y[i]``."""
    for c in range(y.shape[1]):
        for i in range(y.shape[0]):
            out[perm[i], c] = y[i, c]


class SPDFactor:
    """The factors of a symmetric (Hermitian) positive definite ``a``, solving ``a x = b``."""

    def __init__(self, lu, perm):
        self._lu, self._perm = lu, perm

    @property
    def nnz(self) -> int:
        """Entries of the two factors (what a solve reads)."""
        return int(self._lu.L.nnz + self._lu.U.nnz)

    def solve(self, b):
        """``x`` with ``a x = b``; ``b`` is ``(n,)`` or ``(n, k)``, as is ``x``."""
        b = np.asarray(b)
        dtype = np.result_type(b.dtype, self._lu.U.dtype)
        b2 = b.reshape(len(b), -1)
        permuted = np.empty(b2.shape, dtype=dtype, order="F")   # SuperLU's layout: no copy inside
        _gather_rows(b2, self._perm, permuted)
        x = np.empty(b2.shape, dtype=dtype)
        _scatter_rows(self._lu.solve(permuted), self._perm, x)
        return x.reshape(b.shape)


class SPDSolver:
    """Factors symmetric positive definite matrices, ordering each new sparsity pattern once.

    Parameters
    ----------
    pattern : tuple of two int arrays, optional
        ``(indptr, indices)`` of a sparsity pattern (CSR, sorted indices) whose order is known:
        a matrix of exactly this pattern is factored in ``order`` without asking METIS (other
        patterns are ordered as they come, the last one remembered beside this one).
    order : (n,) int64, optional
        :func:`nested_dissection` of ``pattern`` (with it only).
    keep : bool
        Remember the last factors too: a matrix equal to the last one factored (pattern and
        values) gets those factors back without a new factorisation.

    Examples
    --------
    >>> solver = SPDSolver()
    >>> x = solver.factor(a).solve(b)       # doctest: +SKIP
    """

    def __init__(self, *, pattern=None, order=None, keep: bool = False):
        self._ordered = None    # (indptr, indices, order), replaced in one step (threads)
        self._keep = bool(keep)
        self._last = None       # with keep: (matrix, factors) of the last factorisation
        self._given = None      # the pattern handed in and its order, kept
        if (pattern is None) != (order is None):
            raise InputError("SPDSolver takes a pattern and its order together, or neither")
        if pattern is not None:
            indptr, indices = (np.asarray(a) for a in pattern)
            order = np.asarray(order, dtype=np.int64)
            if len(order) != len(indptr) - 1:
                raise InputError(f"the order has {len(order)} entries for a pattern of "
                                 f"{len(indptr) - 1} rows; pass the pattern's own order")
            self._given = (indptr, indices, order)

    def factor(self, a) -> SPDFactor:
        """Factor ``a``, an ``(n, n)`` sparse symmetric (Hermitian) positive definite matrix.

        Raises
        ------
        RuntimeError
            From SuperLU, when a pivot is zero (``a`` is singular).
        """
        a = sp.csr_matrix(a)
        a.sort_indices()
        last = self._last
        if last is not None and last[0].shape == a.shape \
                and np.array_equal(a.indptr, last[0].indptr) \
                and np.array_equal(a.indices, last[0].indices) \
                and np.array_equal(a.data, last[0].data):
            return last[1]
        for ordered in (self._given, self._ordered):
            if ordered is not None and np.array_equal(a.indptr, ordered[0]) \
                    and np.array_equal(a.indices, ordered[1]):
                break
        else:
            ordered = (a.indptr.copy(), a.indices.copy(), nested_dissection(a))
            self._ordered = ordered
        perm = ordered[2]
        lu = splu(a[perm][:, perm].tocsc(), permc_spec="NATURAL", diag_pivot_thresh=0.0,
                  options={"SymmetricMode": True})
        factors = SPDFactor(lu, perm)
        if self._keep:
            self._last = (a.copy(), factors)
        return factors


def spd_factor(a) -> SPDFactor:
    """:meth:`SPDSolver.factor` of a single matrix (ordered for it alone)."""
    return SPDSolver().factor(a)


def nested_dissection(a) -> np.ndarray:
    """METIS's nested-dissection order of the graph of a square sparse matrix's off-diagonal
    pattern (the values do not count).

    Parameters
    ----------
    a : (n, n) scipy.sparse matrix

    Returns
    -------
    (n,) int64
        The order in which :meth:`SPDSolver.factor` permutes ``a``'s rows and columns.
    """
    import pymetis

    a = sp.csr_matrix(a)
    n = a.shape[0]
    if n < 3:
        return np.arange(n)
    g = sp.csr_matrix((np.ones(a.nnz, np.int8), a.indices, a.indptr), shape=a.shape)
    g = g + g.T                              # a structurally symmetric graph for METIS
    g.setdiag(0)
    g.eliminate_zeros()
    g.sort_indices()
    perm, _ = pymetis.nested_dissection(
        adjacency=pymetis.CSRAdjacency(g.indptr.astype(np.int32), g.indices.astype(np.int32)))
    return np.asarray(perm, dtype=np.int64)
