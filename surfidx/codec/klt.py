"""Karhunen–Loève transform (principal components) of the resampled layers.

The ``k`` layers (x, y, z and optionally r, g, b) sampled on the grid are first put in common
units by per-layer unit weights ``w`` (geometry vs colour: an explicit choice of the caller, stored
with the transform), centred, and rotated onto the eigenvectors of their covariance:

``c = (x · w − mean) @ inv(basis)``  (``inv(basis) = basisᵀ`` up to rounding), and
``x = (c @ basis + mean) / w``,

with ``mean`` the mean of the *weighted* layers and ``basis`` a ``(k, k)`` matrix whose **rows** are
the principal directions, ordered by decreasing eigenvalue (the layout of the ``.sfz`` container
header). Sign convention: the largest-magnitude component of each row is positive (the first such
component on exact ties), so the transform is deterministic.

The analysis uses the numerical inverse of ``basis`` rather than its transpose, so a transform
whose ``mean``/``basis``/``weights`` were rounded for storage (:meth:`KLT.as_float32`, the
container stores float32) is still inverted exactly by the decoder from the stored values.
"""

from __future__ import annotations

import struct

import numpy as np

from ..errors import BitstreamError, InputError
from ..validate import as_array

__all__ = ["KLT"]

_MAGIC = b"SKLT"
_VERSION = 1


class KLT:
    """A fitted Karhunen–Loève transform of ``k`` layers.

    Build it with :meth:`KLT.fit` (from data) or :meth:`KLT.from_arrays` (from stored values).

    Parameters
    ----------
    mean : (k,) float64
        Mean of the weighted layers.
    basis : (k, k) float64
        Rows are the principal directions (invertible; orthonormal when fitted).
    weights : (k,) float64
        Positive per-layer unit weights applied before the transform.
    eigenvalues : (k,) float64, optional
        Variances of the weighted layers along the rows of ``basis`` (NaN when unknown).

    Attributes
    ----------
    mean, basis, weights, eigenvalues : as above
    k : int
        Number of layers.
    """

    __slots__ = ("mean", "basis", "weights", "eigenvalues", "_analysis")

    def __init__(self, mean, basis, weights, eigenvalues=None):
        mean = as_array(mean, "mean", shape=(None,))
        k = len(mean)
        if k < 1:
            raise InputError("mean must have at least one layer")
        basis = as_array(basis, "basis", shape=(k, k))
        weights = as_array(weights, "weights", shape=(k,))
        if not np.all(weights > 0):
            i = int(np.flatnonzero(~(weights > 0))[0])
            raise InputError(f"weights must be positive: weight {i} is {weights[i]:.4g}")
        if eigenvalues is None:
            eigenvalues = np.full(k, np.nan)
        else:
            eigenvalues = as_array(eigenvalues, "eigenvalues", shape=(k,))
        try:
            analysis = np.linalg.inv(basis)
        except np.linalg.LinAlgError:
            analysis = None
        if analysis is None or not np.all(np.isfinite(analysis)):
            raise InputError("basis must be invertible (an orthonormal matrix whose rows are the "
                             "principal directions), got a singular matrix")
        self.mean, self.basis, self.weights, self.eigenvalues = mean, basis, weights, eigenvalues
        self._analysis = analysis
        for a in (mean, basis, weights, eigenvalues, self._analysis):
            a.flags.writeable = False

    @property
    def k(self) -> int:
        """Number of layers."""
        return len(self.mean)

    # ------------------------------------------------------------------ fitting
    @classmethod
    def fit(cls, layers, *, weights=None, sample_weights=None, groups=None) -> "KLT":
        """Fit the transform to data.

        Parameters
        ----------
        layers : (n, k) float64
            One column per layer (e.g. x, y, z, r, g, b), ``n ≥ 2`` samples.
        weights : (k,) float64, optional
            Positive unit weight of each layer (default all 1), e.g. ``[1, 1, 1, w, w, w]`` to
            trade colour against geometry. Stored with the transform.
        sample_weights : (n,) float64, optional
            Non-negative weight of each sample (e.g. grid vertex areas) in the mean and covariance.
        groups : sequence of int, optional
            Sizes of consecutive layer groups decorrelated separately, e.g. ``(3, 3)``: the basis
            is then block-diagonal (each group ordered by decreasing eigenvalue, groups in their
            input order), so the first group's coefficients are a rotation of its layers alone —
            what local-frame wavelets of geometry need. Default: one group of all layers.

        Returns
        -------
        KLT

        Raises
        ------
        InputError
            On a non-2-D or non-finite ``layers``, fewer than 2 samples, wrong-length or
            non-positive ``weights``, negative/all-zero ``sample_weights``, or ``groups`` that do
            not add up to the layer count.
        """
        x = as_array(layers, "layers", shape=(None, None), min_len=2)
        n, k = x.shape
        if k < 1:
            raise InputError("layers must have at least one column")
        sizes = (k,) if groups is None else tuple(int(g) for g in groups)
        if any(g < 1 for g in sizes) or sum(sizes) != k:
            raise InputError(f"groups must be positive layer counts adding up to {k}, got "
                             f"{tuple(groups)}")
        w = np.ones(k) if weights is None else as_array(weights, "weights", shape=(k,))
        if not np.all(w > 0):
            i = int(np.flatnonzero(~(w > 0))[0])
            raise InputError(f"weights must be positive: weight {i} is {w[i]:.4g}")
        if sample_weights is None:
            p = np.full(n, 1.0 / n)
        else:
            p = as_array(sample_weights, "sample_weights", shape=(n,))
            if np.any(p < 0) or not p.sum() > 0:
                raise InputError("sample_weights must be non-negative with a positive sum")
            p = p / p.sum()
        z = x * w
        mean = p @ z
        zc = z - mean
        cov = (zc * p[:, None]).T @ zc
        cov = 0.5 * (cov + cov.T)
        evals, basis = np.zeros(k), np.zeros((k, k))
        start = 0
        for g in sizes:
            sl = slice(start, start + g)
            ev, vec = np.linalg.eigh(cov[sl, sl])
            order = np.argsort(-ev, kind="stable")
            evals[sl] = np.clip(ev[order], 0.0, None)
            basis[sl, sl] = vec[:, order].T
            start += g
        pivot = np.argmax(np.abs(basis), axis=1)  # first one on exact ties
        signs = np.sign(basis[np.arange(k), pivot])
        signs[signs == 0] = 1.0
        basis *= signs[:, None]
        return cls(mean, basis, w, evals)

    @classmethod
    def from_arrays(cls, mean, basis, weights) -> "KLT":
        """A transform from stored ``mean (k,)``, ``basis (k, k)`` (rows) and ``weights (k,)``."""
        return cls(mean, basis, weights)

    def as_float32(self) -> "KLT":
        """The same transform with mean, basis and weights rounded to float32 (container storage).

        Encoding with the rounded transform and decoding with the values read back from the file
        is exact to rounding, since the analysis inverts the stored basis.
        """
        r = [np.asarray(a, np.float32).astype(np.float64) for a in (self.mean, self.basis,
                                                                    self.weights)]
        return KLT(*r, eigenvalues=self.eigenvalues)

    # ------------------------------------------------------------------ transforms
    def _check(self, arr, name):
        a = as_array(arr, name)
        if a.ndim != 2 or a.shape[1] != self.k:
            raise InputError(f"{name} must have shape (n, {self.k}) for this {self.k}-layer "
                             f"transform, got {a.shape}")
        return a

    def forward(self, layers) -> np.ndarray:
        """Layers to decorrelated coefficients.

        Parameters
        ----------
        layers : (n, k) float64

        Returns
        -------
        (n, k) float64
            Column ``i`` is the projection on principal direction ``i`` (decreasing energy).
        """
        x = self._check(layers, "layers")
        return (x * self.weights - self.mean) @ self._analysis

    def inverse(self, coeffs) -> np.ndarray:
        """Coefficients back to layers (exact inverse of :meth:`forward`).

        Parameters
        ----------
        coeffs : (n, k) float64

        Returns
        -------
        (n, k) float64
        """
        c = self._check(coeffs, "coeffs")
        return (c @ self.basis + self.mean) / self.weights

    # ------------------------------------------------------------------ storage
    def to_dict(self) -> dict:
        """Plain-Python description: ``{"mean", "basis" (rows), "weights", "eigenvalues"}``."""
        return {"mean": self.mean.tolist(), "basis": self.basis.tolist(),
                "weights": self.weights.tolist(),
                "eigenvalues": [None if np.isnan(e) else float(e) for e in self.eigenvalues]}

    @classmethod
    def from_dict(cls, d: dict) -> "KLT":
        """Inverse of :meth:`to_dict`.

        Raises
        ------
        InputError
            On missing keys or inconsistent shapes.
        """
        try:
            ev = d.get("eigenvalues")
            ev = None if ev is None or any(e is None for e in ev) else ev
            return cls(d["mean"], d["basis"], d["weights"], ev)
        except KeyError as exc:
            raise InputError(f"KLT description lacks {exc.args[0]!r}; expected the keys mean, "
                             "basis, weights") from None

    def to_bytes(self) -> bytes:
        """Binary form: ``b"SKLT"``, version byte, ``k`` byte, then float64 little-endian mean,
        basis (row-major), weights and eigenvalues."""
        body = b"".join(np.asarray(a, "<f8").tobytes()
                        for a in (self.mean, self.basis, self.weights, self.eigenvalues))
        return _MAGIC + struct.pack("<BB", _VERSION, self.k) + body

    @classmethod
    def from_bytes(cls, data: bytes) -> "KLT":
        """Inverse of :meth:`to_bytes`.

        Raises
        ------
        BitstreamError
            On a foreign magic, an unknown version or a wrong length.
        """
        data = bytes(data)
        if len(data) < 6 or data[:4] != _MAGIC:
            raise BitstreamError("not a surfidx KLT record (bad magic)")
        version, k = struct.unpack("<BB", data[4:6])
        if version != _VERSION:
            raise BitstreamError(f"unsupported KLT record version {version} (this build reads "
                                 f"{_VERSION}); upgrade surfidx")
        want = 6 + 8 * (3 * k + k * k)
        if k < 1 or len(data) != want:
            raise BitstreamError(f"KLT record for k={k} must be {want} bytes, got {len(data)}")
        f = np.frombuffer(data, "<f8", offset=6).astype(np.float64)
        mean, basis = f[:k], f[k:k + k * k].reshape(k, k)
        weights, ev = f[k + k * k:2 * k + k * k], f[2 * k + k * k:]
        try:
            return cls(mean, basis, weights, ev if np.all(np.isfinite(ev)) else None)
        except InputError as exc:
            raise BitstreamError(f"corrupt KLT record ({exc.reason})") from None

    def __eq__(self, other) -> bool:
        if not isinstance(other, KLT):
            return NotImplemented
        return (np.array_equal(self.mean, other.mean) and np.array_equal(self.basis, other.basis)
                and np.array_equal(self.weights, other.weights))

    __hash__ = None

    def __repr__(self) -> str:
        return f"KLT(k={self.k}, weights={self.weights.tolist()})"

