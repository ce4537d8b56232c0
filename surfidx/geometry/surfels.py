"""The surfel set: oriented, coloured disks (centre, unit normal, radius, optional RGB)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError
from ..tolerance import TOL
from ..validate import as_array

if TYPE_CHECKING:                      # trimesh is imported by :meth:`SurfelSet.to_trimesh` only
    import trimesh

__all__ = ["SurfelSet"]


class SurfelSet:
    """A set of surfels, validated once at construction.

    Parameters
    ----------
    positions : (n, 3) float64
        Disk centres.
    normals : (n, 3) float64
        Unit normals (renormalised; a length further than ``TOL.unit_normal`` from 1 is an error).
    radii : (n,) float64
        Positive disk radii.
    colors : (n, 3) uint8, optional
        RGB colours.
    faces : (m, 3) int64, optional
        Triangle connectivity over the surfels when they came from a mesh (surfel ``i`` is the
        mesh's ``i``-th used vertex). Kept for topology checks; most algorithms ignore it.
    name : str, optional
        A label (usually the source file's name).
    patch : (n,) int32, optional
        Virtual patch of each surfel: -1 for the scan's own surfels, ``p >= 0`` for surfels that
        topology repair (:func:`surfidx.topology.close_surface`) added to cap boundary loop
        ``p``. ``None``: every surfel is real. The codec codes the virtual region as a mask so
        decoding can drop it again.
    patch_cut : (P,) int32, optional
        For each patch ``p`` (``P = patch.max() + 1``), the handle cut it closes (cuts numbered
        from 0; both sides of cut ``k`` carry ``k``) or -1 for a hole of the input. Defaults to
        all -1 when ``patch`` is given.

    Attributes
    ----------
    positions : (n, 3) float64
    normals : (n, 3) float64
        Unit length.
    radii : (n,) float64
        Positive.
    colors : (n, 3) uint8 or None
        RGB; None when the surfels carry no colour (:attr:`has_color`).
    faces : (m, 3) int64 or None
        Triangles over the surfels (indices into :attr:`positions`), or None.
    name : str or None
    patch : (n,) int32 or None
        Virtual patch of each surfel (-1: a surfel of the scan), or None when all are real.
    patch_cut : (P,) int32 or None
        Handle cut of each patch (-1: a hole), or None without :attr:`patch`.

    Raises
    ------
    InputError
        On NaN or infinite values, mismatched lengths, non-unit normals, non-positive radii,
        colours outside 0..255, faces indexing missing surfels, or patch labels that are not
        -1 or a patch index (``patch_cut`` of the wrong length, or pairing other than two
        patches per cut).

    See Also
    --------
    surfidx.io.as_surfels : a ``trimesh.Trimesh``, ``PointCloud`` or ``Scene`` as surfels.
    """

    __slots__ = ("positions", "normals", "radii", "colors", "faces", "name", "patch", "patch_cut")

    def __init__(self, positions, normals, radii, colors=None, *, faces=None, name=None,
                 patch=None, patch_cut=None):
        positions = as_array(positions, "positions", shape=(None, 3))
        n = len(positions)
        normals = as_array(normals, "normals", shape=(n, 3))
        radii = as_array(radii, "radii", shape=(n,))
        lengths = np.linalg.norm(normals, axis=1)
        bad = np.abs(lengths - 1.0) > TOL.unit_normal
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise InputError(
                f"normals must have unit length: {int(bad.sum())} do not (normal {i} has length "
                f"{lengths[i]:.4g}); normalise them or recompute them")
        normals = normals / lengths[:, None]
        if n and not np.all(radii > 0):
            i = int(np.flatnonzero(~(radii > 0))[0])
            raise InputError(f"radii must be positive: radius {i} is {radii[i]:.4g}")
        if colors is not None:
            c = np.asarray(colors)
            if c.shape != (n, 3):
                raise InputError(f"colors must have shape ({n}, 3), got {c.shape}")
            if np.issubdtype(c.dtype, np.floating):
                if not np.all(np.isfinite(c)):
                    raise InputError("colors contain NaN or infinite values")
                c = np.round(c)
            if c.size and (c.min() < 0 or c.max() > 255):
                raise InputError(
                    f"colors must lie in 0..255, got {c.min()}..{c.max()}; scale them to 8 bits")
            colors = np.ascontiguousarray(c, dtype=np.uint8)
        if faces is not None:
            faces = as_array(faces, "faces", dtype=np.int64, shape=(None, 3))
            if faces.size and (faces.min() < 0 or faces.max() >= n):
                raise InputError(f"faces index surfels outside 0..{n - 1}")
        self.positions = positions
        self.normals = normals
        self.radii = radii
        self.colors = colors
        self.faces = faces
        self.name = name
        self.patch, self.patch_cut = _check_patches(patch, patch_cut, n)

    # ------------------------------------------------------------------ basic properties
    def __len__(self) -> int:
        return len(self.positions)

    def __repr__(self) -> str:
        col = "rgb" if self.has_color else "no colour"
        return f"SurfelSet({len(self)} surfels, {col}, name={self.name!r})"

    @property
    def virtual(self) -> np.ndarray:
        """(n,) bool: surfels of virtual patches (all False when :attr:`patch` is None)."""
        if self.patch is None:
            return np.zeros(len(self), bool)
        return self.patch >= 0

    @property
    def has_color(self) -> bool:
        """Whether the surfels carry RGB colours."""
        return self.colors is not None

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) float64: minimum and maximum corner of the axis-aligned bounding box."""
        if not len(self):
            raise InputError("an empty surfel set has no bounding box")
        return np.stack([self.positions.min(axis=0), self.positions.max(axis=0)])

    @property
    def diagonal(self) -> float:
        """Length of the bounding-box diagonal (the PSNR peak)."""
        lo, hi = self.bounds
        return float(np.linalg.norm(hi - lo))

    # ------------------------------------------------------------------ derived sets
    def subset(self, index) -> "SurfelSet":
        """Surfels selected by an index array or boolean mask (faces are dropped).

        Parameters
        ----------
        index : (k,) int or (n,) bool
        """
        idx = np.asarray(index)
        return SurfelSet(self.positions[idx], self.normals[idx], self.radii[idx],
                         None if self.colors is None else self.colors[idx], name=self.name,
                         patch=None if self.patch is None else self.patch[idx],
                         patch_cut=self.patch_cut)

    def transformed(self, rotation=None, translation=None, scale: float = 1.0) -> "SurfelSet":
        """Apply ``x -> scale * R x + t``; normals rotate, radii scale.

        Parameters
        ----------
        rotation : (3, 3) float64, optional
            An orthogonal matrix (a reflection is allowed).
        translation : (3,) float64, optional
        scale : float
            Positive scale factor.
        """
        R = np.eye(3) if rotation is None else as_array(rotation, "rotation", shape=(3, 3))
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-8):
            raise InputError("rotation must be an orthogonal 3x3 matrix")
        t = np.zeros(3) if translation is None else as_array(translation, "translation", shape=(3,))
        if not (np.isfinite(scale) and scale > 0):
            raise InputError(f"scale must be a positive number, got {scale!r}")
        return SurfelSet(scale * self.positions @ R.T + t, self.normals @ R.T, scale * self.radii,
                         self.colors, faces=self.faces, name=self.name, patch=self.patch,
                         patch_cut=self.patch_cut)

    def without_color(self) -> "SurfelSet":
        """The same surfels with the colours dropped."""
        return SurfelSet(self.positions, self.normals, self.radii, None, faces=self.faces,
                         name=self.name, patch=self.patch, patch_cut=self.patch_cut)

    # ------------------------------------------------------------------ interoperability
    def to_trimesh(self) -> "trimesh.PointCloud":
        """The surfels as a ``trimesh.PointCloud`` (trimesh is imported on this call).

        A trimesh point cloud holds positions and colours only, so the other arrays go into its
        ``metadata`` dict: copies in surfel order, which trimesh's own operations on the cloud
        (``apply_transform``, ``merge_vertices``) leave as they are. A surfel set with
        :attr:`faces` still gives a point cloud; decode or read a :class:`TriangleMesh`
        for a ``trimesh.Trimesh``.

        Returns
        -------
        trimesh.PointCloud
            ``vertices`` : (n, 3) float64
                :attr:`positions`, in surfel order.
            ``colors`` : (n, 4) uint8
                :attr:`colors` as RGBA, alpha 255; empty when the surfels carry no colour.
            ``metadata`` : dict
                ``"name"`` (str or None), ``"normals"`` (n, 3) float64, ``"radii"`` (n,)
                float64; and where the surfels have them ``"faces"`` (m, 3) int64,
                ``"patch"`` (n,) int32 and ``"patch_cut"`` (P,) int32.

        Notes
        -----
        :func:`surfidx.io.as_surfels` reads the cloud back with the same positions, colours and
        name; it estimates normals and radii from the points again, as for any point cloud.
        """
        import trimesh

        meta = {"name": self.name, "normals": self.normals.copy(), "radii": self.radii.copy()}
        for key in ("faces", "patch", "patch_cut"):
            value = getattr(self, key)
            if value is not None:
                meta[key] = value.copy()
        return trimesh.PointCloud(self.positions.copy(), colors=_rgba(self.colors),
                                  metadata=meta)


def _rgba(colors: np.ndarray | None) -> np.ndarray | None:
    """RGB colours as RGBA with alpha 255, the layout trimesh's colour visuals hold.

    Parameters
    ----------
    colors : (n, 3) uint8 or None

    Returns
    -------
    (n, 4) uint8 or None
        None for None.
    """
    if colors is None:
        return None
    out = np.full((len(colors), 4), 255, np.uint8)
    out[:, :3] = colors
    return out


def _check_patches(patch, patch_cut, n):
    """Validated ``(patch, patch_cut)`` of :class:`SurfelSet` (int32 arrays or ``(None, None)``)."""
    if patch is None:
        if patch_cut is not None and len(np.asarray(patch_cut)):
            raise InputError("patch_cut was given without patch; pass the per-surfel patch labels")
        return None, None
    patch = as_array(patch, "patch", dtype=np.int64, shape=(n,))
    if patch.size and patch.min() < -1:
        raise InputError(f"patch labels must be -1 (a real surfel) or a patch index >= 0, got "
                         f"{int(patch.min())}")
    count = int(patch.max()) + 1 if patch.size else 0
    if patch_cut is None:
        patch_cut = np.full(count, -1, np.int64)
    patch_cut = as_array(patch_cut, "patch_cut", dtype=np.int64, shape=(None,))
    if len(patch_cut) < count:
        raise InputError(f"patch_cut has {len(patch_cut)} entries but the surfels name {count} "
                         "patches; give the cut (or -1) of every patch")
    cuts = patch_cut[patch_cut >= 0]
    per_cut = np.bincount(cuts) if cuts.size else np.zeros(0, np.int64)
    if np.any((per_cut != 0) & (per_cut != 2)):
        raise InputError("patch_cut must name every cut on exactly two patches (its two sides)")
    return patch.astype(np.int32), patch_cut.astype(np.int32)
