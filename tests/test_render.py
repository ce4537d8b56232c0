"""The splat renderer: colours where expected, background elsewhere, z-buffer, path overlay,
upright thumbnails."""

import numpy as np
import pytest
from PIL import Image
from scipy import ndimage

from surfidx import FileFormatError, InputError, SurfelSet, TriangleMesh, read_surfels
from surfidx.io import up_axis
from surfidx.render import (FLAT_RATIO, PRINCIPAL, THUMBNAIL, VIEWS, camera_basis, is_flat,
                            principal_basis, render, save_png, thumbnail_basis)

from conftest import icosphere_mesh

MAGENTA = (255, 0, 255)


def coverage(img, bg=MAGENTA):
    return np.any(img != np.array(bg, np.uint8), axis=2)


@pytest.fixture(scope="module")
def halves_sphere():
    """Unit sphere: red where x > 0, blue where x < 0, green cap at y > 0.8."""
    v, f = icosphere_mesh(4)
    col = np.where(v[:, :1] > 0, [[220, 20, 20]], [[20, 20, 220]])
    col[v[:, 1] > 0.8] = (20, 200, 20)
    return TriangleMesh(v, f, vertex_colors=col).to_surfels()


def dominant(img, y, x, r=3):
    patch = img[y - r:y + r + 1, x - r:x + r + 1].reshape(-1, 3).astype(int).mean(axis=0)
    return "rgb"[int(np.argmax(patch))], patch


def test_colours_and_background_where_expected(halves_sphere):
    img = render(halves_sphere, width=120, height=100, view="front", background=MAGENTA)
    assert img.shape == (100, 120, 3) and img.dtype == np.uint8
    # camera on +z, +x to the right: blue left, red right, green top
    assert dominant(img, 55, 40)[0] == "b"
    assert dominant(img, 55, 80)[0] == "r"
    assert dominant(img, 12, 60)[0] == "g"
    # corners and the sides beyond the sphere's disc are background, exactly
    for y, x in ((0, 0), (0, 119), (99, 0), (99, 119), (50, 3), (50, 116)):
        assert tuple(img[y, x]) == MAGENTA
    # the model fills the frame less the margin: disc diameter ~ 88% of the height
    rows = np.flatnonzero(coverage(img).any(axis=1))
    assert 80 <= rows[-1] - rows[0] + 1 <= 89


def test_views_move_the_colours(halves_sphere):
    back = render(halves_sphere, width=100, height=100, view="back", background=MAGENTA)
    assert dominant(back, 55, 30)[0] == "r" and dominant(back, 55, 70)[0] == "b"
    top = render(halves_sphere, width=100, height=100, view="top", background=MAGENTA)
    assert dominant(top, 50, 50)[0] == "g"
    right = render(halves_sphere, width=100, height=100, view=(90.0, 0.0), background=MAGENTA)
    assert dominant(right, 60, 50)[0] == "r"
    assert np.array_equal(right, render(halves_sphere, width=100, height=100, view="right",
                                        background=MAGENTA))


def test_no_holes_between_splats(sphere_surfels):
    for view in VIEWS:
        img = render(sphere_surfels, width=150, height=150, view=view, background=MAGENTA)
        cov = coverage(img)
        assert not np.any(ndimage.binary_fill_holes(cov) & ~cov), view
        rows, cols = np.flatnonzero(cov.any(axis=1)), np.flatnonzero(cov.any(axis=0))
        cy, cx = (rows[0] + rows[-1] + 1) / 2, (cols[0] + cols[-1] + 1) / 2
        radius = (rows[-1] - rows[0] + 1) / 2
        yy, xx = np.mgrid[:150, :150]
        disc = (yy + 0.5 - cy) ** 2 + (xx + 0.5 - cx) ** 2 < (0.93 * radius) ** 2
        assert cov[disc].all(), view
        assert radius > 0.4 * 150 * 0.88 and abs(cy - 75) < 2 and abs(cx - 75) < 2  # fills, centred


def test_grey_without_colour_and_lit_from_the_key_light(sphere_surfels):
    img = render(sphere_surfels.without_color(), width=100, height=100, view="front").astype(int)
    centre = img[45:55, 45:55].reshape(-1, 3)
    assert np.all(np.ptp(centre, axis=1) <= 1)  # grey: R = G = B
    # the key light sits upper-left: that quadrant is brighter than the lower right
    assert img[30, 30].sum() > img[70, 70].sum() + 60
    assert tuple(img[0, 0]) == (255, 255, 255)  # default white background
    assert img[45:55, 45:55].max() < 255         # the model never blends into the background


def two_disks(z_red, z_blue):
    pos = np.array([[0.0, 0.0, z_red], [0.3, 0.0, z_blue]])
    nrm = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    return SurfelSet(pos, nrm, np.array([1.0, 1.0]), np.array([[255, 0, 0], [0, 0, 255]]))


def test_z_buffer_keeps_the_nearer_disk():
    # camera on +z: larger z is nearer; depths differ by more than the blending range (1 radius)
    for z_red, z_blue, want in ((2.5, 0.0, "r"), (0.0, 2.5, "b")):
        s = two_disks(z_red, z_blue)
        img = render(s, width=100, height=100, view="front", supersample=1)
        assert dominant(img, 50, 55, r=2)[0] == want
        # the order of the surfels in the set does not matter
        flipped = s.subset([1, 0])
        assert np.array_equal(render(flipped, width=100, height=100, view="front",
                                     supersample=1), img)


def test_oblique_and_backfacing_disks_still_show():
    # a disk seen exactly edge-on still covers pixels (clamped to ~1 px) ...
    edge = SurfelSet([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
                     [0.5, 0.5])
    img = render(edge, width=80, height=80, view="front", background=MAGENTA, supersample=1)
    lower = coverage(img)[50:, :]
    assert lower.any() and lower.sum(axis=1).max() <= 3
    # ... and a disk facing away is lit like one facing the camera (two-sided)
    a = SurfelSet([[0, 0, 0.0]], [[0, 0, 1.0]], [1.0])
    b = SurfelSet([[0, 0, 0.0]], [[0, 0, -1.0]], [1.0])
    assert np.array_equal(render(a, width=40, height=40, view="front"),
                          render(b, width=40, height=40, view="front"))


def test_path_overlay_changes_pixels_along_it(halves_sphere):
    base = render(halves_sphere, width=120, height=120, view="front", background=MAGENTA)
    t = np.linspace(-np.pi / 2, np.pi / 2, 60)  # half great circle across the front (z > 0)
    front = np.stack([np.sin(t), np.zeros_like(t), np.cos(t)], axis=1) * 1.001
    img = render(halves_sphere, width=120, height=120, view="front", background=MAGENTA,
                 path_points=front, path_color=(255, 255, 0))
    diff = np.any(img != base, axis=2)
    rows = np.flatnonzero(diff.any(axis=1))
    assert rows.min() >= 55 and rows.max() <= 65        # a thin band around the equator
    assert diff[60, 20:100].all()                         # along its whole length
    assert tuple(img[60, 60]) == (255, 255, 0)            # drawn in the path colour
    # the same arc on the back is hidden: faded, not fully drawn
    back = front * [1, 1, -1]
    hid = render(halves_sphere, width=120, height=120, view="front", background=MAGENTA,
                 path_points=back, path_color=(255, 255, 0)).astype(int)
    px, old = hid[60, 60], base[60, 60].astype(int)
    assert np.any(px != old) and tuple(px) != (255, 255, 0)
    assert px[1] > old[1]  # shifted towards yellow
    assert tuple(hid[60, 60]) != tuple(img[60, 60])


def test_camera_basis_is_orthonormal_and_right_handed():
    for view in list(VIEWS) + [(17.0, -33.0)]:
        for up in ("y", "z", "-x"):
            b = camera_basis(view, up=up)
            assert np.allclose(b @ b.T, np.eye(3))
            assert np.isclose(np.linalg.det(b), 1.0)
    assert np.allclose(camera_basis("front"), np.eye(3))
    assert np.allclose(camera_basis("front", up="z")[1], [0, 0, 1])


# ---------------------------------------------------------------------- thumbnails
def ellipsoid(semi_axes, level=3):
    """Surfels of an ellipsoid with these semi-axes (x, y, z): a standing figure when it is
    taller along its up axis than wide."""
    v, f = icosphere_mesh(level)
    return TriangleMesh(v * semi_axes, f).to_surfels()


def extent(img, bg=(255, 255, 255)):
    """(height, width) in pixels of the bounding box of the pixels that are not background."""
    cov = coverage(img, bg)
    rows, cols = np.flatnonzero(cov.any(axis=1)), np.flatnonzero(cov.any(axis=0))
    return rows[-1] - rows[0] + 1, cols[-1] - cols[0] + 1


def test_a_standing_figure_stands_in_its_thumbnail():
    figure = ellipsoid([0.5, 2.0, 0.35])              # +y up, as a mesh file keeps it
    h, w = extent(render(figure, width=96, height=96, view=THUMBNAIL, up="+y"))
    assert h > 2 * w
    # the principal view lays it down (what thumbnails showed before they kept the up axis)
    h, w = extent(render(figure, width=96, height=96, view=PRINCIPAL))
    assert w > 2 * h
    # the up axis decides, not the shape: told +x is up, the figure lies
    h, w = extent(render(figure, width=96, height=96, view=THUMBNAIL, up="+x"))
    assert w > 2 * h


def test_a_z_up_scan_stands_in_its_thumbnail(tmp_path):
    v, _ = icosphere_mesh(3)
    path = tmp_path / "pole.xyz"
    np.savetxt(path, v * [0.5, 0.35, 2.0], fmt="%.6f")   # a scanner's file: +z up
    scan = read_surfels(path)
    assert up_axis(path) == "+z"
    h, w = extent(render(scan, width=96, height=96, view=THUMBNAIL, up=up_axis(path)))
    assert h > 2 * w
    h, w = extent(render(scan, width=96, height=96, view=THUMBNAIL, up="+y"))
    assert w > h                                          # seen as a mesh would be, it lies


def test_a_flat_model_falls_back_to_the_principal_view():
    pliers = ellipsoid([2.0, 0.2, 1.4])                   # lying flat: thin along +y
    assert is_flat(pliers, up="+y") and not is_flat(pliers, up="+z")
    assert np.array_equal(thumbnail_basis(pliers, up="+y"), principal_basis(pliers))
    assert np.array_equal(render(pliers, width=64, height=64, view=THUMBNAIL),
                          render(pliers, width=64, height=64, view=PRINCIPAL))
    # its largest silhouette: the principal view looks along +-y, down at it
    assert np.allclose(np.abs(principal_basis(pliers)[2]), [0, 1, 0])
    # flatness is the up extent against the larger horizontal one, at FLAT_RATIO
    below = ellipsoid([2.0, 2.0 * FLAT_RATIO * 0.95, 1.4])
    above = ellipsoid([2.0, 2.0 * FLAT_RATIO * 1.05, 1.4])   # a table, a car: stays upright
    assert is_flat(below) and not is_flat(above)
    assert np.allclose(thumbnail_basis(above), camera_basis("three-quarter"))
    assert np.allclose(thumbnail_basis(above, up="z"), camera_basis("three-quarter", up="+z"))


def test_the_thumbnail_is_deterministic(tmp_path):
    figure = ellipsoid([0.5, 2.0, 0.35], level=4)
    a = render(figure, width=80, height=80, view=THUMBNAIL)
    b = render(ellipsoid([0.5, 2.0, 0.35], level=4), width=80, height=80, view=THUMBNAIL)
    assert np.array_equal(a, b)
    save_png(a, tmp_path / "a.png")
    save_png(b, tmp_path / "b.png")
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()


def test_save_png_round_trip(tmp_path, halves_sphere):
    img = render(halves_sphere, width=64, height=48)
    out = tmp_path / "s.png"
    save_png(img, out)
    with Image.open(out) as im:
        assert im.size == (64, 48) and np.array_equal(np.asarray(im.convert("RGB")), img)
    assert not (tmp_path / "s.png.part").exists()


# ---------------------------------------------------------------------- errors
def test_render_errors(sphere_surfels):
    empty = SurfelSet(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    with pytest.raises(InputError, match="cannot render an empty surfel set"):
        render(empty)
    with pytest.raises(InputError, match="surfels must be a SurfelSet"):
        render(np.zeros((3, 3)))
    with pytest.raises(InputError, match="unknown view 'side'; .* principal, thumbnail or"):
        render(sphere_surfels, view="side")
    with pytest.raises(InputError, match=r"view must have shape \(2,\)"):
        render(sphere_surfels, view=(1.0, 2.0, 3.0))
    with pytest.raises(InputError, match="unknown up axis 'w'"):
        render(sphere_surfels, up="w")
    for view in (THUMBNAIL, PRINCIPAL):
        with pytest.raises(InputError, match=r"unknown up axis '\+w'; use one of \+y"):
            render(sphere_surfels, view=view, up="+w")
    with pytest.raises(InputError, match="unknown up axis 'w'"):
        thumbnail_basis(sphere_surfels, up="w")
    with pytest.raises(InputError, match="width must be at least 1"):
        render(sphere_surfels, width=0)
    with pytest.raises(InputError, match="height must be an integer"):
        render(sphere_surfels, height=10.5)
    with pytest.raises(InputError, match="too large"):
        render(sphere_surfels, width=10000, height=10000)
    with pytest.raises(InputError, match="background must hold three values in 0..255"):
        render(sphere_surfels, background=(0, 0, 300))
    with pytest.raises(InputError, match=r"path_points must have shape \(n, 3\)"):
        render(sphere_surfels, path_points=np.zeros((4, 2)))
    with pytest.raises(InputError, match="path_points contains 1 NaN"):
        render(sphere_surfels, path_points=[[0, 0, 0], [1, np.nan, 0]])
    with pytest.raises(InputError, match="light must be a non-zero direction"):
        render(sphere_surfels, light=(0, 0, 0))


def test_save_png_errors(tmp_path):
    with pytest.raises(InputError, match=r"must be an \(h, w, 3\) uint8 array"):
        save_png(np.zeros((4, 4)), tmp_path / "x.png")
    with pytest.raises(FileFormatError, match="cannot write the PNG"):
        save_png(np.zeros((4, 4, 3), np.uint8), tmp_path / "missing" / "x.png")


# ---------------------------------------------------------------------- real models
@pytest.mark.slow
def test_igea_renders_without_holes(models):
    s = read_surfels(models / "igea.ply")
    img = render(s, background=MAGENTA)
    cov = coverage(img)
    assert not np.any(ndimage.binary_fill_holes(cov) & ~cov)
    rows, cols = np.flatnonzero(cov.any(axis=1)), np.flatnonzero(cov.any(axis=0))
    assert max(rows[-1] - rows[0], cols[-1] - cols[0]) > 0.85 * 800  # fills the frame


@pytest.mark.slow
def test_textured_banana_is_yellow(models):
    s = read_surfels(models / "ycb_banana" / "textured_simple_reoriented.obj")
    img = render(s, width=160, height=160, background=MAGENTA)
    px = img[coverage(img)].astype(int)
    yellowish = (px[:, 0] > px[:, 2] + 40) & (px[:, 1] > px[:, 2] + 40)
    assert yellowish.mean() > 0.7
