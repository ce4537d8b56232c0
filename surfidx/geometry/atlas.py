"""A texture atlas of the icosahedral grid and colour baked into it.

Each of the icosahedron's 20 base triangles is a chart: the level-``L`` grid subdivides it into
a triangular lattice of ``2^L`` steps a side, which the atlas maps affinely onto a right
triangle. The charts are paired in the halves of 10 cells of a 4 × 3 layout of the image
(two cells left empty), base triangle ``2k`` in the lower-left half of cell ``k`` and ``2k + 1``
in the upper-right half, turned half a turn. A chart's corners sit on texel centres and every
chart keeps :data:`GUTTER` texels to its cell's border and more to the other chart of the cell,
so a bilinear look-up inside a chart reads only texels of that chart: each texel belongs to the
chart on its side of the cell's diagonal, and a texel outside its chart (the gutter) takes the
colour of the chart's nearest edge point, as dilation from inside the chart would give.

A grid vertex on a base edge lies in two charts and a base corner in five: the atlas has one
texture coordinate per (chart, lattice point), and a mesh exported with it has its vertices
duplicated along those seams.

The colour of a texel is a function of a point on the unit sphere (:func:`bake_texture`): the
texel's point on its chart is a point of one grid triangle with barycentric weights, and its
sphere point is the central projection of that triangle's point, which the colour source
evaluates. :class:`GridColor` is such a source for colours on the vertices of a grid of any
level, located by descending the grid's face hierarchy (:func:`locate_on_grid`), so a colour
grid finer than the geometry's plugs into the same bake.
"""

from __future__ import annotations

import functools

import numpy as np

from ..errors import InputError
from ..validate import as_array
from ..jit import njit
from .icosphere import MAX_LEVEL, check_level, icosphere

__all__ = ["GridAtlas", "grid_atlas", "grid_face_index", "locate_on_grid", "GridColor",
           "bake_texture", "atlas_uv_faces", "default_texture_size", "check_texture_size", "GUTTER", "MIN_TEXTURE_SIZE",
           "MAX_TEXTURE_SIZE"]

#: Texels between a chart and its cell's border (the chart's gutter there).
GUTTER = 2
#: Texels by which a chart's diagonal edge is set back from its cell's diagonal corners.
_DIAGONAL = 4
#: Cells of the layout, columns and rows; 10 of the 12 hold two charts each.
_COLUMNS, _ROWS = 4, 3
#: The smallest and largest texture side.
MIN_TEXTURE_SIZE = 64
MAX_TEXTURE_SIZE = 8192
#: Texels of the horizontal chart leg per grid edge, for :func:`default_texture_size`.
_TEXELS_PER_EDGE = 2


def default_texture_size(level: int) -> int:
    """The texture side for a grid level: about :data:`_TEXELS_PER_EDGE` texels per grid edge
    along a chart's shorter leg, a power of two from 256 to 4096.

    Parameters
    ----------
    level : int

    Returns
    -------
    int
    """
    lev = check_level(level)
    return int(min(4096, max(256, _COLUMNS * _TEXELS_PER_EDGE * 2 ** lev)))


def check_texture_size(size) -> int:
    """``size`` checked as a texture side: an integer from :data:`MIN_TEXTURE_SIZE` to
    :data:`MAX_TEXTURE_SIZE`.

    Raises
    ------
    InputError
        Another value.
    """
    if (isinstance(size, bool) or not isinstance(size, (int, np.integer))
            or not MIN_TEXTURE_SIZE <= size <= MAX_TEXTURE_SIZE):
        raise InputError(f"texture_size must be an integer from {MIN_TEXTURE_SIZE} to "
                         f"{MAX_TEXTURE_SIZE} (texels a side), got {size!r}")
    return int(size)


@functools.lru_cache(maxsize=2)
def _lattice_corners(level: int) -> np.ndarray:
    """(20·4^L, 3, 2) int64: the lattice coordinates ``(i, j)`` of each grid face's corners in
    its base triangle ``(a, b, c)`` (point ``a + i/N (b - a) + j/N (c - a)``, ``N = 2^L``),
    following the subdivision's face order (children ``(a, ab, ca), (b, bc, ab),
    (c, ca, bc), (ab, bc, ca)``); cached (an atlas and its texels' faces both need it), read
    only."""
    n = 2 ** level
    cur = np.broadcast_to(np.array([[0, 0], [n, 0], [0, n]], np.int64), (20, 3, 2)).copy()
    for _ in range(level):
        a, b, c = cur[:, 0], cur[:, 1], cur[:, 2]
        ab, bc, ca = (a + b) // 2, (b + c) // 2, (c + a) // 2
        cur = np.stack([np.stack(t, 1) for t in ((a, ab, ca), (b, bc, ab), (c, ca, bc),
                                                 (ab, bc, ca))], 1).reshape(-1, 3, 2)
    cur.flags.writeable = False
    return cur


def _lattice_index(i, j, n: int):
    """Index of lattice point ``(i, j)`` (``i + j <= n``) within its chart, row ``j`` by row."""
    return j * (n + 1) - j * (j - 1) // 2 + i


class GridAtlas:
    """The texture atlas of the level-``L`` grid (module docs), for a square image.

    Attributes
    ----------
    level : int
    size : int
        Image side in texels.
    uv : (20·(N+1)(N+2)/2, 2) float64
        Texture coordinates, one per (chart, lattice point), ``N = 2^L``; v upwards (row 0 of
        the image at v = 1), on texel centres at the charts' corners.
    uv_vertex : (len(uv),) int64
        The grid vertex of each texture coordinate.
    uv_faces : (20·4^L, 3) int64
        The texture coordinate of each grid face's corners (in the face's corner order).
    corners : (20, 3, 2) float64
        Pixel coordinates (x right, y down, texel centres at half-integers) of each chart's
        corners, in the order of its base triangle's corners.
    """

    def __init__(self, level: int, size: int):
        self.level, self.size = check_level(level), check_texture_size(size)
        n = 2 ** self.level
        lat = _lattice_corners(self.level)
        per_chart = (n + 1) * (n + 2) // 2
        chart = np.arange(len(lat)) // 4 ** self.level
        self.uv_faces = chart[:, None] * per_chart + _lattice_index(lat[..., 0], lat[..., 1], n)
        self.uv_vertex = np.empty(20 * per_chart, np.int64)
        self.uv_vertex[self.uv_faces.ravel()] = icosphere(self.level).faces.ravel()
        self.corners = _chart_corners(self.size)
        j = np.concatenate([np.full(n + 1 - r, r) for r in range(n + 1)])
        i = np.concatenate([np.arange(n + 1 - r) for r in range(n + 1)])
        s, t = i / n, j / n
        c = self.corners
        px = (c[:, None, 0] + s[None, :, None] * (c[:, None, 1] - c[:, None, 0])
              + t[None, :, None] * (c[:, None, 2] - c[:, None, 0])).reshape(-1, 2)
        self.uv = np.stack([px[:, 0] / self.size, 1.0 - px[:, 1] / self.size], 1)
        for a in (self.uv, self.uv_vertex, self.uv_faces, self.corners):
            a.flags.writeable = False

    def texel_charts(self) -> np.ndarray:
        """(size, size) int64: the chart each texel belongs to (-1 in the two empty cells and
        the leftover texels beyond the last full cell): the chart on the texel's side of its
        cell's diagonal."""
        return self._texels()[0].reshape(self.size, self.size)

    def texel_points(self):
        """Where each texel of a chart samples the grid: the chart point nearest the texel's
        centre, as a grid triangle and barycentric weights.

        Returns
        -------
        rows : (k,) int64
            Flat indices (``y * size + x``) of the texels that belong to a chart.
        vertices : (k, 3) int64
            The grid vertices of the triangle holding each texel's chart point.
        weights : (k, 3) float64
            Its barycentric weights (non-negative, summing to 1).
        """
        rows, _, vertices, w = self._texel_cells()
        return rows, vertices, w

    def texel_faces(self):
        """Where each texel of a chart samples the grid, as :meth:`texel_points` but with the
        grid face (of level ``level``, in the icosphere's face order) holding its chart point.

        Returns
        -------
        rows : (k,) int64
        faces : (k,) int64
        vertices : (k, 3) int64
        weights : (k, 3) float64
            As :meth:`texel_points`; ``vertices`` are ``faces``' corners, though not always in
            the face's corner order.
        """
        rows, (chart, ia, ib, down), vertices, w = self._texel_cells()
        n = 2 ** self.level
        lat = _lattice_corners(self.level)
        lo = lat.min(axis=1)
        # a lattice triangle pointing down has corner sums 3(i + j) + 4, one pointing up + 2
        flip = (lat.sum(axis=(1, 2)) - 3 * lo.sum(axis=1)) == 4
        base = np.arange(len(lat)) // 4 ** self.level
        table = np.empty(20 * n * n * 2, np.int64)
        table[((base * n + lo[:, 1]) * n + lo[:, 0]) * 2 + flip] = np.arange(len(lat))
        return rows, table[((chart * n + ib) * n + ia) * 2 + down], vertices, w

    def _texel_cells(self):
        """The chart texels' flat indices, their lattice cells ``(chart, i, j, down)``, the
        grid vertices of the cells' triangles and the texels' barycentric weights in them."""
        chart, ia, ib, down, w = self._texels()
        rows = np.flatnonzero(chart >= 0)
        ch, ia, ib, down, w = chart[rows], ia[rows], ib[rows], down[rows], w[rows]
        n = 2 ** self.level
        d = down.astype(np.int64)
        # the cell's corners (i + d, j + d), (i + 1 - d, j + d), (i + d, j + 1 - d): two on
        # lattice row j + d, one on row j + 1 - d
        first = ch * ((n + 1) * (n + 2) // 2)
        row = first + _lattice_index(0, ib + d, n)
        uv = np.empty((len(rows), 3), np.int64)
        uv[:, 0] = row + ia + d
        uv[:, 1] = row + ia + 1 - d
        uv[:, 2] = first + _lattice_index(ia + d, ib + 1 - d, n)
        return rows, (ch, ia, ib, down), self.uv_vertex[uv], w

    def _texels(self):
        """Per texel (flat, row by row): its chart (-1: none) and the lattice cell and
        barycentric weights of its nearest chart point (:func:`_texel_kernel`)."""
        m = self.size * self.size
        chart, ia, ib = (np.empty(m, np.int64) for _ in range(3))
        down, w = np.empty(m, np.bool_), np.empty((m, 3))
        _texel_kernel(self.size, np.ascontiguousarray(self.corners), 2 ** self.level,
                      chart, ia, ib, down, w)
        return chart, ia, ib, down, w


@njit(cache=True)
def _texel_kernel(size, corners, n, chart_out, ia_out, ib_out, down_out, w_out):
    """Each texel's chart: the one on its side of its cell's diagonal through the cell's
    centre, parallel to the charts' long edges (-1 outside the 10 cells). Its chart point: the
    texel centre's lattice coordinates ``(s, t)`` (fractions of the base triangle's legs),
    clamped to ``s, t >= 0`` and moved back along the long edge's normal to ``s + t <= 1``.
    Its lattice cell ``(i, j)`` and whether the point lies in the cell's downward triangle
    (never beyond the chart's long edge, where rounding can put it), and the point's
    barycentric weights in that triangle (clipped at 0, normalised)."""
    cw, ch = size // _COLUMNS, size // _ROWS
    ku, kv = ch - 2 * GUTTER - _DIAGONAL - 1, cw - 2 * GUTTER - _DIAGONAL - 1
    for y in range(size):
        for x in range(size):
            q = y * size + x
            col, row = x // cw, y // ch
            cell = row * _COLUMNS + col
            px, py = x + 0.5, y + 0.5
            if col < _COLUMNS and row < _ROWS and cell < 10:
                lu = (px - col * cw) / cw - 0.5
                lv = (py - row * ch) / ch - 0.5
                chart = 2 * cell + (1 if lu * cw * ku + lv * ch * kv > 0 else 0)
            else:
                chart = -1
            chart_out[q] = chart
            c = corners[max(chart, 0)]
            s = max((px - c[0, 0]) / (c[1, 0] - c[0, 0]), 0.0)
            t = max((py - c[0, 1]) / (c[2, 1] - c[0, 1]), 0.0)
            if s + t > 1.0:
                excess = (s + t - 1.0) / 2.0
                s, t = s - excess, t - excess
            s, t = min(max(s, 0.0), 1.0), min(max(t, 0.0), 1.0)
            s = min(s, 1.0 - t)
            a, b = s * n, t * n
            ib = min(np.floor(b), n - 1.0)
            ia = min(min(np.floor(a), n - 1.0), n - 1.0 - ib)
            fa, fb = a - ia, b - ib
            down = fa + fb > 1.0 and ia + ib < n - 1.0
            if down:
                w0, w1, w2 = fa + fb - 1.0, 1.0 - fa, 1.0 - fb
            else:
                w0, w1, w2 = 1.0 - fa - fb, fa, fb
            w0, w1, w2 = min(max(w0, 0.0), 1.0), min(max(w1, 0.0), 1.0), min(max(w2, 0.0), 1.0)
            tot = w0 + w1 + w2
            ia_out[q], ib_out[q], down_out[q] = np.int64(ia), np.int64(ib), down
            w_out[q, 0], w_out[q, 1], w_out[q, 2] = w0 / tot, w1 / tot, w2 / tot


def _chart_corners(size: int) -> np.ndarray:
    """(20, 3, 2) float64 pixel coordinates of the charts' corners (see :class:`GridAtlas`)."""
    cw, ch = size // _COLUMNS, size // _ROWS
    g, e = GUTTER, _DIAGONAL
    out = np.empty((20, 3, 2))
    for k in range(10):
        ox, oy = (k % _COLUMNS) * cw, (k // _COLUMNS) * ch
        out[2 * k] = [[ox + g + .5, oy + g + .5], [ox + cw - g - e - .5, oy + g + .5],
                      [ox + g + .5, oy + ch - g - e - .5]]
        out[2 * k + 1] = [[ox + cw - g - .5, oy + ch - g - .5],
                          [ox + g + e + .5, oy + ch - g - .5],
                          [ox + cw - g - .5, oy + g + e + .5]]
    return out


def grid_atlas(level: int, *, size: int | None = None) -> GridAtlas:
    """The texture atlas of the level-``level`` grid (module docs).

    Parameters
    ----------
    level : int
        Grid level, 0 … :data:`~surfidx.geometry.icosphere.MAX_LEVEL`.
    size : int, optional
        Image side in texels, :data:`MIN_TEXTURE_SIZE` … :data:`MAX_TEXTURE_SIZE` (default
        :func:`default_texture_size`).

    Returns
    -------
    GridAtlas

    Raises
    ------
    InputError
        A level or size out of range.
    """
    lev = check_level(level)
    return GridAtlas(lev, default_texture_size(lev) if size is None else size)


def grid_face_index(level: int, faces) -> np.ndarray:
    """The level-``level`` grid face of each triangle of grid vertices (any corner rotation or
    order), or -1 for a triangle that is not a grid face (a strip that zips a cut, say).

    Parameters
    ----------
    level : int
    faces : (m, 3) int64
        Grid vertex ids.

    Returns
    -------
    (m,) int64
    """
    grid = icosphere(check_level(level))
    f = as_array(faces, "faces", dtype=np.int64, shape=(None, 3))
    nv = np.int64(grid.n_vertices)

    def keys(tri):
        s = np.sort(tri, axis=1)
        return (s[:, 0] * nv + s[:, 1]) * nv + s[:, 2]

    gk = keys(np.asarray(grid.faces))
    order = np.argsort(gk)
    q = keys(f)
    pos = np.minimum(np.searchsorted(gk, q, sorter=order), len(gk) - 1)
    hit = gk[order[pos]] == q
    return np.where(hit, order[pos], -1)


@njit(cache=True)
def _det3(a0, a1, a2, b0, b1, b2, p0, p1, p2):
    return (a1 * b2 - a2 * b1) * p0 + (a2 * b0 - a0 * b2) * p1 + (a0 * b1 - a1 * b0) * p2


@njit(cache=True)
def _descend(p, verts, faces, offsets, level, start, start_level, face_out, w_out):
    """Per point: the base face whose worst edge test is best (or ``start[q]``, a face of
    level ``start_level``), then at each finer level the child beyond the inner triangle's
    most violated edge (or the inner one); barycentric weights by Cramer's rule in the last
    face, clipped at 0 and normalised."""
    for q in range(p.shape[0]):
        x, y, z = p[q, 0], p[q, 1], p[q, 2]
        best, face = -np.inf, 0
        if start_level > 0:
            face = start[q]
        else:
            for f in range(20):
                s = np.inf
                for k in range(3):
                    a, b = faces[f, k], faces[f, (k + 1) % 3]
                    d = _det3(verts[a, 0], verts[a, 1], verts[a, 2],
                              verts[b, 0], verts[b, 1], verts[b, 2], x, y, z)
                    s = min(s, d)
                if s > best:
                    best, face = s, f
        for j in range(start_level + 1, level + 1):
            inner = offsets[j] + 4 * face + 3
            worst, child, kk = np.inf, 3, 0
            for k in range(3):
                # inner (ab, bc, ca): edge (ca, ab) faces child 0, (ab, bc) 1, (bc, ca) 2
                a, b = faces[inner, (k + 2) % 3], faces[inner, k]
                d = _det3(verts[a, 0], verts[a, 1], verts[a, 2],
                          verts[b, 0], verts[b, 1], verts[b, 2], x, y, z)
                if d < worst:
                    worst, kk = d, k
            if worst < 0:
                child = kk
            face = 4 * face + child
        f = offsets[level] + face
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        w0 = _det3(verts[b, 0], verts[b, 1], verts[b, 2], verts[c, 0], verts[c, 1],
                   verts[c, 2], x, y, z)
        w1 = _det3(verts[c, 0], verts[c, 1], verts[c, 2], verts[a, 0], verts[a, 1],
                   verts[a, 2], x, y, z)
        w2 = _det3(verts[a, 0], verts[a, 1], verts[a, 2], verts[b, 0], verts[b, 1],
                   verts[b, 2], x, y, z)
        w0, w1, w2 = max(w0, 0.0), max(w1, 0.0), max(w2, 0.0)
        t = w0 + w1 + w2
        if t > 0:
            w0, w1, w2 = w0 / t, w1 / t, w2 / t
        else:
            w0 = w1 = w2 = 1.0 / 3.0
        face_out[q] = face
        w_out[q, 0], w_out[q, 1], w_out[q, 2] = w0, w1, w2


def _level_faces(level: int):
    """The faces of levels 0 … ``level`` stacked, and each level's first row."""
    faces = [np.asarray(icosphere(j).faces) for j in range(level + 1)]
    offsets = np.cumsum([0] + [len(f) for f in faces[:-1]]).astype(np.int64)
    return np.ascontiguousarray(np.vstack(faces)), offsets


def locate_on_grid(points, level: int, *, within=None, within_level: int = 0):
    """The level-``level`` grid face holding each unit vector, by descending the faces'
    hierarchy from the icosahedron (each face's four children split it along great circles),
    and the point's barycentric weights in it (central projection onto the face's plane).

    Parameters
    ----------
    points : (n, 3) float64
        Unit vectors (any non-zero vectors: their directions are used).
    level : int
    within : (n,) int64, optional
        A face of the level-``within_level`` grid known to hold each point (a texel's face on
        an atlas, say): the descent starts there instead of at the icosahedron.
    within_level : int
        The level of ``within``, 1 … ``level`` (ignored without ``within``).

    Returns
    -------
    faces : (n,) int64
    weights : (n, 3) float64
        Non-negative, summing to 1, in the order of the face's corners.

    Raises
    ------
    InputError
        ``within`` of another length, a face out of range, or ``within_level`` outside
        1 … ``level``.
    """
    lev = check_level(level)
    p = np.ascontiguousarray(as_array(points, "points", shape=(None, 3)))
    start, start_level = np.zeros(0, np.int64), 0
    if within is not None:
        if (isinstance(within_level, bool) or not isinstance(within_level, (int, np.integer))
                or not 1 <= within_level <= lev):
            raise InputError(f"within_level must be an integer from 1 to level={lev}, got "
                             f"{within_level!r}")
        start = np.ascontiguousarray(as_array(within, "within", dtype=np.int64,
                                              shape=(len(p),)))
        if len(start) and (start.min() < 0 or start.max() >= 20 * 4 ** within_level):
            raise InputError(f"within must hold faces of the level-{within_level} grid "
                             f"(0 … {20 * 4 ** within_level - 1}), got values from "
                             f"{start.min()} to {start.max()}")
        start_level = int(within_level)
    faces, offsets = _level_faces(lev)
    verts = np.ascontiguousarray(icosphere(lev).vertices)
    face = np.empty(len(p), np.int64)
    w = np.empty((len(p), 3))
    _descend(p, verts, faces, offsets, lev, start, start_level, face, w)
    return face, w


class GridColor:
    """Colours on the vertices of a grid of any level, as a function of sphere points
    (barycentric in the grid triangle holding each point): the colour source
    :func:`bake_texture` takes.

    Parameters
    ----------
    colors : (10·4^L + 2, 3) float64
        One colour per grid vertex (0..255).
    """

    def __init__(self, colors):
        from .icosphere import level_of_count

        self.colors = as_array(colors, "colors", shape=(None, 3))
        level = level_of_count(len(self.colors))
        if level is None or level > MAX_LEVEL:
            raise InputError(f"colors must have 10·4^L + 2 rows (one per grid vertex, "
                             f"L <= {MAX_LEVEL}), got {len(self.colors)}")
        self.level = level

    def __call__(self, points, *, within=None, within_level: int = 0) -> np.ndarray:
        """(n, 3) float64 colours at unit vectors ``points`` (n, 3) float64; ``within`` and
        ``within_level`` as :func:`locate_on_grid` takes them (a coarser grid's faces known
        to hold the points)."""
        face, w = locate_on_grid(points, self.level, within=within, within_level=within_level)
        corners = np.asarray(icosphere(self.level).faces)[face]
        return np.einsum("ij,ijk->ik", w, self.colors[corners])


def bake_texture(atlas: GridAtlas, color) -> np.ndarray:
    """The texture image of a colour source on an atlas: each chart texel takes the colour at
    the sphere point of its chart point (module docs), texels outside the charts black.

    Parameters
    ----------
    atlas : GridAtlas
    color : callable
        ``color(points)``: (n, 3) colours (0..255) at unit vectors ``points`` (n, 3) float64,
        e.g. a :class:`GridColor`.

    Returns
    -------
    (size, size, 3) uint8
        Row 0 at the top (v = 1).

    Raises
    ------
    InputError
        A colour source that does not return one finite RGB row per point.
    """
    rows, faces, verts, w = atlas.texel_faces()
    sphere = np.asarray(icosphere(atlas.level).vertices)
    p = np.einsum("ij,ijk->ik", w, sphere[verts])
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    if isinstance(color, GridColor) and color.level >= atlas.level >= 1:
        # the texel's atlas face holds its point: the colour grid's search starts there
        col = color(p, within=faces, within_level=atlas.level)
    else:
        col = np.asarray(color(p), dtype=np.float64)
    if col.shape != (len(p), 3) or not np.all(np.isfinite(col)):
        raise InputError(f"the colour source must return ({len(p)}, 3) finite colours, got "
                         f"shape {col.shape}")
    img = np.zeros((atlas.size * atlas.size, 3), np.uint8)
    img[rows] = np.clip(np.round(col), 0, 255).astype(np.uint8)
    return img.reshape(atlas.size, atlas.size, 3)


def atlas_uv_faces(atlas: GridAtlas, faces, *, grid_faces=None) -> np.ndarray:
    """The texture coordinates of the corners of triangles of grid vertices on an atlas: a
    grid face's own, in the triangle's corner order; a triangle that is no grid face (a strip
    that zips a cut) takes its first corner's texture coordinate at all three corners, so it
    shows that vertex's colour and never spans charts.

    Parameters
    ----------
    atlas : GridAtlas
    faces : (m, 3) int64
        Grid vertex ids of the level ``atlas.level``.
    grid_faces : (m,) int64, optional
        The grid face each triangle is, where the caller knows it (its corners in any
        order), -1 where it does not: those triangles are looked up
        (:func:`grid_face_index`), as all of them are without ``grid_faces``.

    Returns
    -------
    (m, 3) int64
        Indices into ``atlas.uv``.

    Raises
    ------
    InputError
        ``grid_faces`` of another length, or holding a value outside -1 … the grid's last face.
    """
    f = as_array(faces, "faces", dtype=np.int64, shape=(None, 3))
    own = np.asarray(icosphere(atlas.level).faces)
    if grid_faces is not None:
        idx = np.array(as_array(grid_faces, "grid_faces", dtype=np.int64, shape=(len(f),)))
        if len(idx) and (idx.min() < -1 or idx.max() >= len(own)):
            raise InputError(f"grid_faces must hold faces of the level-{atlas.level} grid "
                             f"(0 … {len(own) - 1}) or -1, got values from {idx.min()} to "
                             f"{idx.max()}")
    if f.shape == own.shape and np.array_equal(f, own):
        return np.array(atlas.uv_faces)       # the grid's faces themselves (no search)
    if grid_faces is None:
        idx = grid_face_index(atlas.level, f)
    else:
        unknown = idx < 0
        if unknown.any():
            idx[unknown] = grid_face_index(atlas.level, f[unknown])
    grid = idx >= 0
    out = np.empty_like(f)
    uvf = atlas.uv_faces[idx[grid]]
    owner = atlas.uv_vertex[uvf]
    for k in range(3):
        pick = np.argmax(owner == f[grid, k][:, None], axis=1)
        out[grid, k] = uvf[np.arange(len(uvf)), pick]
    if not grid.all():
        _, first = np.unique(atlas.uv_vertex, return_index=True)   # every grid vertex has one
        out[~grid] = first[f[~grid, 0]][:, None]
    return out
