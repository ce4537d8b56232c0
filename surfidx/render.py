"""Z-buffered disk-splat renderer: a surfel set to an RGB image (and PNG).

Each surfel is projected orthographically and rasterised as the ellipse its disk projects to, with
the depth of the disk's plane at every pixel. Rendering takes two passes over the splats, as
surface splatting does:

1. **visibility**: the nearest disk depth per pixel (a z-buffer);
2. **blending**: every disk whose depth at a pixel lies within its own radius behind that nearest
   depth adds its normal and colour, weighted by a smooth kernel that falls towards the disk's
   rim. Overlapping splats of one surface thus blend into smooth shading instead of showing each
   disk's flat facet, while surfaces farther back stay hidden.

Shading is Lambert (a key light and a weaker fill) with some ambient and a Blinn-Phong specular,
two-sided (normals facing away from the camera are flipped). The image is rendered at
``supersample`` times the size and box-filtered down, which anti-aliases silhouettes.

The camera looks at the model's centre. Views are named or given as ``(azimuth, elevation)`` in
degrees, in the frame turned so that the model's up axis (``up``, :mod:`surfidx.geometry.axes`)
points up: for a +y-up model, azimuth 0 and elevation 0 look along ``-z`` (the camera sits on
``+z``, ``+y`` up, ``+x`` right); for a +z-up model they look along ``+y`` (the camera on
``-y``, ``+z`` up, ``+x`` right). Positive azimuth moves the camera towards ``+x``, positive
elevation raises it towards the up axis.

The view ``"principal"`` looks along the model's smallest principal axis (of its surfels'
positions, weighted by disk area), with the largest axis across and the middle one up: a flat
model (a bird, pliers) shows its largest silhouette.

The view ``"thumbnail"`` is the one thumbnails use (:func:`thumbnail_basis`): the
``"three-quarter"`` view with the model's up axis up, so a standing figure stands and a chair
shows its seat, back and legs at once (a view straight from the front shows a box as a square
and a chair as its back); a model that is flat along its up axis (:func:`is_flat`: pliers or a
bird with spread wings lying in the horizontal plane, which the three-quarter view shows edge
on) falls back to ``"principal"``.
"""

from __future__ import annotations

import math
from pathlib import Path

from .jit import numba
import numpy as np

from .errors import FileFormatError, InputError
from .validate import as_array, check_positive_int
from .geometry.axes import MESH_UP, check_up, up_rotation
from .geometry.surfels import SurfelSet

__all__ = ["VIEWS", "PRINCIPAL", "THUMBNAIL", "THUMBNAIL_VIEW", "FLAT_RATIO", "render",
           "save_png", "camera_basis", "principal_basis", "thumbnail_basis", "is_flat",
           "read_polyline"]

#: The view name that looks along the model's smallest principal axis (:func:`principal_basis`).
PRINCIPAL = "principal"

#: The view name of thumbnails (:func:`thumbnail_basis`).
THUMBNAIL = "thumbnail"

#: Named views as (azimuth, elevation) in degrees.
VIEWS = {
    "three-quarter": (35.0, 20.0),
    "front": (0.0, 0.0),
    "back": (180.0, 0.0),
    "left": (-90.0, 0.0),
    "right": (90.0, 0.0),
    "top": (0.0, 90.0),
    "bottom": (0.0, -90.0),
}

#: The named view of an upright thumbnail (:func:`thumbnail_basis`).
THUMBNAIL_VIEW = "three-quarter"

#: A model is flat (:func:`is_flat`) when its bounding box's extent along the up axis is below
#: this fraction of its larger horizontal extent. Lying pliers, glasses and spread-winged birds
#: are flatter; a table, a bowl, a fish or a car on its wheels is not.
FLAT_RATIO = 0.25

_GREY = (200, 200, 200)
_MARGIN = 0.06          # fraction of the image left free on each side
_MIN_AXIS = 0.75        # smallest semi-axis of a splat, in (supersampled) pixels
_BLEND_DEPTH = 1.0      # splats within this many of their radii behind the front are blended
_PATH_DEPTH = 3.0       # path points within this many median radii behind the front are visible
_HIDDEN_ALPHA = 0.3     # opacity of the hidden part of a path


# ---------------------------------------------------------------------- camera
def camera_basis(view="three-quarter", *, up: str = MESH_UP) -> np.ndarray:
    """Orthonormal camera axes for a view.

    Parameters
    ----------
    view : str or (2,) float
        A name of :data:`VIEWS` or ``(azimuth_deg, elevation_deg)``.
    up : str
        The model axis shown upwards (:func:`surfidx.geometry.axes.check_up`: ``"+y"``,
        ``"+z"``, ``"-x"``...; ``"y"`` is ``"+y"``). The angles are measured in a frame rotated
        so that this axis plays ``+y``'s role (for ``"+z"``: front looks along ``+y``, from
        ``-y``).

    Returns
    -------
    (3, 3) float64
        Rows: screen right, screen up, towards the camera (right-handed).

    Raises
    ------
    InputError
        For an unknown view name, a malformed angle pair or an unknown up axis.
    """
    turn = up_rotation(up)
    if isinstance(view, str):
        if view not in VIEWS:
            raise InputError(f"unknown view {view!r}; use one of {', '.join(VIEWS)}, "
                             f"{PRINCIPAL}, {THUMBNAIL} or (azimuth, elevation) in degrees")
        az, el = VIEWS[view]
    else:
        az, el = as_array(view, "view", shape=(2,))
    a, e = math.radians(az), math.radians(el)
    back = np.array([math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)])
    right = np.array([math.cos(a), 0.0, -math.sin(a)])  # perpendicular to back for every e
    upward = np.cross(back, right)
    return np.stack([right, upward, back]) @ turn


def principal_basis(surfels: SurfelSet) -> np.ndarray:
    """Camera axes looking along the smallest principal axis of a model.

    Parameters
    ----------
    surfels : SurfelSet

    Returns
    -------
    (3, 3) float64
        Rows: screen right (the largest principal axis), screen up (the middle one), towards the
        camera (the smallest), right-handed. Each axis of the covariance of the positions
        (weighted by the disks' areas) is signed so that its largest component is positive, so
        the view is the same on every run.
    """
    w = surfels.radii ** 2
    w = w / w.sum() if w.sum() > 0 else np.full(len(surfels), 1.0 / max(len(surfels), 1))
    centred = surfels.positions - w @ surfels.positions
    cov = (centred * w[:, None]).T @ centred
    _, vecs = np.linalg.eigh(cov)                       # ascending eigenvalues
    axes = vecs.T[::-1].copy()                          # largest, middle, smallest
    for a in axes[:2]:
        if a[np.argmax(np.abs(a))] < 0:
            a *= -1.0
    axes[2] = np.cross(axes[0], axes[1])
    return axes


def is_flat(surfels: SurfelSet, *, up: str = MESH_UP) -> bool:
    """Whether a model is flat along its up axis (lies in the horizontal plane).

    Parameters
    ----------
    surfels : SurfelSet
    up : str
        The model's up axis (:func:`surfidx.geometry.axes.check_up`).

    Returns
    -------
    bool
        Whether the extent of the surfels' positions along ``up`` is below :data:`FLAT_RATIO`
        times the larger of the two horizontal extents (of the axis-aligned bounding box).
    """
    extent = np.abs(up_rotation(up)) @ (surfels.bounds[1] - surfels.bounds[0])
    return bool(extent[1] < FLAT_RATIO * max(extent[0], extent[2]))


def thumbnail_basis(surfels: SurfelSet, *, up: str = MESH_UP) -> np.ndarray:
    """Camera axes of a thumbnail: upright three-quarter view, principal view when flat.

    Parameters
    ----------
    surfels : SurfelSet
    up : str
        The model's up axis, as its file format keeps it (:func:`surfidx.io.up_axis`) or as
        the user said (``ProcessOptions.up``).

    Returns
    -------
    (3, 3) float64
        :func:`camera_basis` of :data:`THUMBNAIL_VIEW` with ``up`` up, or, for a model that
        :func:`is_flat`, :func:`principal_basis` (its largest silhouette).

    Raises
    ------
    InputError
        For an unknown up axis.
    """
    up = check_up(up)
    if is_flat(surfels, up=up):
        return principal_basis(surfels)
    return camera_basis(THUMBNAIL_VIEW, up=up)


# ---------------------------------------------------------------------- kernels
@numba.njit(cache=True, inline="always")
def _splat_at(dx, dy, nx, ny, nz, r, rmin):
    """Whether pixel offset (dx, dy) lies in the projected disk; its kernel value and depth offset.

    The disk of radius ``r`` and camera-space normal ``(nx, ny, nz)`` (``nz >= 0``) projects to an
    ellipse with semi-axis ``r`` across the projected normal and ``r * nz`` along it; both are
    clamped to at least ``rmin``. Depth grows away from the camera.
    """
    nxy = math.sqrt(nx * nx + ny * ny)
    if nxy > 1e-12:
        mx, my = nx / nxy, ny / nxy
    else:
        mx, my = 1.0, 0.0
    t = dx * mx + dy * my          # along the projected normal
    s = -dx * my + dy * mx          # across it
    a = max(r, rmin)
    b = max(r * nz, rmin)
    q = (s * s) / (a * a) + (t * t) / (b * b)
    if q > 1.0:
        return False, 0.0, 0.0
    if nz > 1e-6:
        dz = t * nxy / nz          # plane: nx dx + ny dy - nz * ddepth = 0 (depth away)
    else:
        dz = 0.0
    if dz > r:
        dz = r
    elif dz < -r:
        dz = -r
    return True, q, dz


@numba.njit(cache=True)
def _bbox(cx, cy, nx, ny, nz, r, rmin, w, h):
    nxy = math.sqrt(nx * nx + ny * ny)
    if nxy > 1e-12:
        mx, my = nx / nxy, ny / nxy
    else:
        mx, my = 1.0, 0.0
    a = max(r, rmin)
    b = max(r * nz, rmin)
    ex = math.sqrt(a * a * my * my + b * b * mx * mx)
    ey = math.sqrt(a * a * mx * mx + b * b * my * my)
    x0 = max(int(math.ceil(cx - ex - 0.5)), 0)
    x1 = min(int(math.floor(cx + ex - 0.5)), w - 1)
    y0 = max(int(math.ceil(cy - ey - 0.5)), 0)
    y1 = min(int(math.floor(cy + ey - 0.5)), h - 1)
    return x0, x1, y0, y1


@numba.njit(cache=True)
def _splat_depth(px, py, pz, nrm, rad, rmin, zbuf):
    """Pass 1: nearest disk depth per pixel (pixel centres at integer + 0.5)."""
    h, w = zbuf.shape
    for i in range(px.shape[0]):
        nx, ny, nz, r = nrm[i, 0], nrm[i, 1], nrm[i, 2], rad[i]
        x0, x1, y0, y1 = _bbox(px[i], py[i], nx, ny, nz, r, rmin, w, h)
        for y in range(y0, y1 + 1):
            dy = y + 0.5 - py[i]
            for x in range(x0, x1 + 1):
                dx = x + 0.5 - px[i]
                inside, q, dz = _splat_at(dx, dy, nx, ny, nz, r, rmin)
                if inside:
                    z = pz[i] + dz
                    if z < zbuf[y, x]:
                        zbuf[y, x] = z


@numba.njit(cache=True)
def _splat_blend(px, py, pz, nrm, rad, col, rmin, depth_tol, zbuf, acc_w, acc_n, acc_c):
    """Pass 2: kernel-weighted normals and colours of the splats near the front depth."""
    h, w = zbuf.shape
    use_col = col.shape[0] == px.shape[0]
    for i in range(px.shape[0]):
        nx, ny, nz, r = nrm[i, 0], nrm[i, 1], nrm[i, 2], rad[i]
        tol = depth_tol * r
        x0, x1, y0, y1 = _bbox(px[i], py[i], nx, ny, nz, r, rmin, w, h)
        for y in range(y0, y1 + 1):
            dy = y + 0.5 - py[i]
            for x in range(x0, x1 + 1):
                dx = x + 0.5 - px[i]
                inside, q, dz = _splat_at(dx, dy, nx, ny, nz, r, rmin)
                if inside and pz[i] + dz <= zbuf[y, x] + tol:
                    wgt = math.exp(-2.0 * q)
                    acc_w[y, x] += wgt
                    acc_n[y, x, 0] += wgt * nx
                    acc_n[y, x, 1] += wgt * ny
                    acc_n[y, x, 2] += wgt * nz
                    if use_col:
                        acc_c[y, x, 0] += wgt * col[i, 0]
                        acc_c[y, x, 1] += wgt * col[i, 1]
                        acc_c[y, x, 2] += wgt * col[i, 2]


@numba.njit(cache=True)
def _draw_path(sx, sy, sz, half, depth_tol, zbuf, mark):
    """Thick polyline: ``mark`` is 2 where a visible part covers a pixel, 1 where only hidden."""
    h, w = zbuf.shape
    for k in range(sx.shape[0] - 1):
        ax, ay, az = sx[k], sy[k], sz[k]
        bx, by, bz = sx[k + 1], sy[k + 1], sz[k + 1]
        ex, ey = bx - ax, by - ay
        ll = ex * ex + ey * ey
        x0 = max(int(math.floor(min(ax, bx) - half)), 0)
        x1 = min(int(math.ceil(max(ax, bx) + half)), w - 1)
        y0 = max(int(math.floor(min(ay, by) - half)), 0)
        y1 = min(int(math.ceil(max(ay, by) + half)), h - 1)
        for y in range(y0, y1 + 1):
            cy = y + 0.5
            for x in range(x0, x1 + 1):
                cx = x + 0.5
                if ll > 0.0:
                    t = ((cx - ax) * ex + (cy - ay) * ey) / ll
                    t = min(max(t, 0.0), 1.0)
                else:
                    t = 0.0
                qx, qy = ax + t * ex - cx, ay + t * ey - cy
                if qx * qx + qy * qy > half * half:
                    continue
                z = az + t * (bz - az)
                if z <= zbuf[y, x] + depth_tol:
                    mark[y, x] = 2
                elif mark[y, x] < 1:
                    mark[y, x] = 1


# ---------------------------------------------------------------------- public API
def render(surfels: SurfelSet, *, width: int = 800, height: int = 800, view="three-quarter",
           up: str = MESH_UP, background=(255, 255, 255), path_points=None,
           path_color=(220, 30, 30), light=(-0.45, 0.55, 1.0), supersample: int = 2) -> np.ndarray:
    """Render surfels as lit, z-buffered disk splats.

    Parameters
    ----------
    surfels : SurfelSet
        The model; its colours are used when present, light grey otherwise.
    width, height : int
        Image size in pixels.
    view : str or (2,) float
        ``"three-quarter"``, ``"front"``, ``"back"``, ``"left"``, ``"right"``, ``"top"``,
        ``"bottom"``, ``"principal"`` (along the smallest principal axis, ``up`` ignored),
        ``"thumbnail"`` (:func:`thumbnail_basis`) or ``(azimuth_deg, elevation_deg)`` (see the
        module notes).
    up : str
        Model axis shown upwards: ``"+y"``, ``"+z"``, ``"+x"`` or negated (``"-z"``); the sign
        may be left out for ``+`` (:func:`surfidx.geometry.axes.check_up`).
    background : (3,) int
        RGB 0..255 where no surfel covers the pixel.
    path_points : (k, 3) float64, optional
        A polyline (e.g. a geodesic path) drawn as a thick line on top; parts hidden behind the
        surface are drawn faded.
    path_color : (3,) int
        Its RGB colour.
    light : (3,) float64
        Direction towards the key light in camera coordinates (x right, y up, z towards the
        viewer); need not be unit length.
    supersample : int
        Render at this many times the size and average down (1 = no anti-aliasing).

    Returns
    -------
    (height, width, 3) uint8
        The image, row 0 at the top. The model's projected bounding box (disk centres plus radii) is
        centred and scaled to fill the image less a margin of 6% per side.

    Raises
    ------
    InputError
        For an empty surfel set, a bad size, view, colour, light or path.
    """
    if not isinstance(surfels, SurfelSet):
        raise InputError(f"surfels must be a SurfelSet, got {type(surfels).__name__}")
    if len(surfels) == 0:
        raise InputError("cannot render an empty surfel set")
    width = check_positive_int(width, "width")
    height = check_positive_int(height, "height")
    ss = check_positive_int(supersample, "supersample")
    if width * height * ss * ss > 64_000_000:
        raise InputError(f"image of {width}x{height} at supersample {ss} is too large "
                         "(over 64 megapixels); lower the size or the supersampling")
    bg = _rgb(background, "background")
    pcol = _rgb(path_color, "path_color")
    key = as_array(light, "light", shape=(3,))
    if not np.linalg.norm(key) > 0:
        raise InputError("light must be a non-zero direction")
    key = key / np.linalg.norm(key)
    path = None
    if path_points is not None:
        path = as_array(path_points, "path_points", shape=(None, 3), min_len=1)
    if isinstance(view, str) and view == PRINCIPAL:
        check_up(up)
        basis = principal_basis(surfels)
    elif isinstance(view, str) and view == THUMBNAIL:
        basis = thumbnail_basis(surfels, up=up)
    else:
        basis = camera_basis(view, up=up)

    # camera space: x right, y up, depth away from the camera
    cam = surfels.positions @ basis.T
    nrm = surfels.normals @ basis.T
    nrm[nrm[:, 2] < 0] *= -1.0                      # two-sided: face the camera
    W, H = width * ss, height * ss
    # fit the projected disks (centres +- radii) into the image less the margin
    lo = (cam[:, :2] - surfels.radii[:, None]).min(axis=0)
    hi = (cam[:, :2] + surfels.radii[:, None]).max(axis=0)
    avail = np.array([W, H]) * (1.0 - 2.0 * _MARGIN)
    scale = float(np.min(avail / (hi - lo)))
    centre = (lo + hi) / 2.0

    def to_pixels(p):
        return ((p[:, 0] - centre[0]) * scale + W / 2.0,
                H / 2.0 - (p[:, 1] - centre[1]) * scale,
                -p[:, 2] * scale)

    px, py, pz = to_pixels(cam)
    rad = surfels.radii * scale
    # screen y points down: flip the normal's y so the ellipse is oriented in pixel axes
    nrm_px = np.ascontiguousarray(np.stack([nrm[:, 0], -nrm[:, 1], nrm[:, 2]], axis=1))
    rmin = _MIN_AXIS

    zbuf = np.full((H, W), np.inf)
    _splat_depth(px, py, pz, nrm_px, rad, rmin, zbuf)
    acc_w = np.zeros((H, W))
    acc_n = np.zeros((H, W, 3))
    col = (surfels.colors.astype(np.float64) if surfels.has_color else np.zeros((0, 3)))
    acc_c = np.zeros((H, W, 3)) if surfels.has_color else np.zeros((1, 1, 3))
    _splat_blend(px, py, pz, nrm_px, rad, col, rmin, _BLEND_DEPTH, zbuf, acc_w, acc_n, acc_c)

    img = np.empty((H, W, 3))
    fill, half_vec = _light_vectors(key)
    _shade_pixels(acc_w, acc_n, acc_c, surfels.has_color, np.array(_GREY, float),
                  np.array(bg, float), key, fill, half_vec, img)

    if path is not None:
        cp = path @ basis.T
        sx, sy, sz = to_pixels(cp)
        mark = np.zeros((H, W), np.int8)
        half = max(1.5, 0.0035 * min(W, H))
        tol = _PATH_DEPTH * float(np.median(rad)) + 1e-9 * scale
        _draw_path(np.ascontiguousarray(sx), np.ascontiguousarray(sy), np.ascontiguousarray(sz),
                   half, tol, zbuf, mark)
        pc = np.array(pcol, float)
        img[mark == 2] = pc
        hid = mark == 1
        img[hid] = (1 - _HIDDEN_ALPHA) * img[hid] + _HIDDEN_ALPHA * pc

    out = np.empty((height, width, 3), np.uint8)
    _downsample(img, ss, out)
    return out


def save_png(image, path) -> None:
    """Write an RGB image as PNG (atomically: a partial file never replaces an old one).

    Parameters
    ----------
    image : (h, w, 3) uint8
    path : str or os.PathLike

    Raises
    ------
    InputError
        When the array is not an (h, w, 3) uint8 image.
    FileFormatError
        When the file cannot be written.
    """
    from PIL import Image

    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.dtype != np.uint8 or not arr.size:
        raise InputError(f"image must be an (h, w, 3) uint8 array, got shape {arr.shape} "
                         f"of {arr.dtype}")
    from .io import write_atomic

    write_atomic(path, lambda tmp: Image.fromarray(arr, "RGB").save(tmp, format="PNG"),
                 what="the PNG")


def read_polyline(path) -> np.ndarray:
    """Read a polyline from a PLY whose ``vertex`` element holds ``x y z`` in path order.

    Other properties and elements are ignored (``surfidx geodesic ... -o PATH.ply`` writes such
    files; so does :func:`surfidx.write_ply` for a set of surfels in order).

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    (k, 3) float64
        The points, ``k >= 1``.

    Raises
    ------
    FileFormatError
        When the file is missing, not a readable PLY, or lacks vertices or ``x y z``.
    InputError
        When a coordinate is NaN or infinite.
    """
    from plyfile import PlyData

    path = Path(path)
    if not path.is_file():
        raise FileFormatError("no such file" if not path.exists() else "is not a file",
                              path=path)
    if path.suffix.lower() != ".ply":
        raise FileFormatError("a path must be a PLY file (vertex element with x y z)", path=path)
    try:
        ply = PlyData.read(str(path))
        vertex = ply["vertex"].data
    except KeyError as exc:
        raise FileFormatError("PLY has no 'vertex' element", path=path) from exc
    except Exception as exc:  # plyfile raises many kinds on damaged input
        msg = str(exc).strip() or type(exc).__name__
        raise FileFormatError(f"not a readable PLY file ({msg}); the file may be truncated or "
                              "corrupt", path=path) from exc
    props = vertex.dtype.names or ()
    missing = [a for a in "xyz" if a not in props]
    if missing:
        raise FileFormatError(f"PLY vertex element lacks {' '.join(missing)}; a path needs x y z",
                              path=path)
    if len(vertex) == 0:
        raise FileFormatError("the path PLY has no vertices", path=path)
    pts = np.stack([np.asarray(vertex[a], np.float64) for a in "xyz"], axis=1)
    return as_array(pts, "path points", shape=(None, 3), path=path)


# ---------------------------------------------------------------------- helpers
def _rgb(value, name):
    c = as_array(value, name, shape=(3,))
    if c.min() < 0 or c.max() > 255:
        raise InputError(f"{name} must hold three values in 0..255, got {tuple(c)}")
    return tuple(float(x) for x in c)


def _light_vectors(key: np.ndarray):
    """Unit fill-light direction and the key light's Blinn-Phong half vector."""
    fill = np.array([0.6, -0.25, 0.75])
    fill /= np.linalg.norm(fill)
    half = key + np.array([0.0, 0.0, 1.0])
    half /= np.linalg.norm(half)
    return fill, half


@numba.njit(cache=True)
def _shade_pixels(acc_w, acc_n, acc_c, has_col, grey, bg, key, fill, half, img):
    """Normalise the blended normals and colours and light them (camera axes, pixel y down).

    Lambert key + fill, a headlight term, ambient and a soft Blinn-Phong highlight.
    """
    h, w = acc_w.shape
    for y in range(h):
        for x in range(w):
            wt = acc_w[y, x]
            if wt <= 0.0:
                img[y, x, 0], img[y, x, 1], img[y, x, 2] = bg[0], bg[1], bg[2]
                continue
            nx, ny, nz = acc_n[y, x, 0], -acc_n[y, x, 1], acc_n[y, x, 2]
            ln = math.sqrt(nx * nx + ny * ny + nz * nz)
            if ln > 1e-12:
                nx, ny, nz = nx / ln, ny / ln, nz / ln
            else:
                nx, ny, nz = 0.0, 0.0, 1.0
            dk = max(nx * key[0] + ny * key[1] + nz * key[2], 0.0)
            df = max(nx * fill[0] + ny * fill[1] + nz * fill[2], 0.0)
            sp = max(nx * half[0] + ny * half[1] + nz * half[2], 0.0) ** 40
            lum = 0.16 + 0.6 * dk + 0.16 * df + 0.1 * max(nz, 0.0)
            for c in range(3):
                base = acc_c[y, x, c] / wt if has_col else grey[c]
                img[y, x, c] = base * lum + 35.0 * sp


@numba.njit(cache=True)
def _downsample(img, ss, out):
    """Box-filter ``img`` by ``ss`` in both axes into ``out`` (rounded, clipped to 0..255)."""
    h, w = out.shape[0], out.shape[1]
    inv = 1.0 / (ss * ss)
    for y in range(h):
        for x in range(w):
            for c in range(3):
                acc = 0.0
                for j in range(ss):
                    for i in range(ss):
                        acc += img[y * ss + j, x * ss + i, c]
                v = math.floor(acc * inv + 0.5)
                out[y, x, c] = min(max(v, 0.0), 255.0)
