"""The reconstruction's self-check (:mod:`bodystudio.reconstruct.plausibility`) on inputs whose figures are known by
hand: a square whose projection lands on whole pixels (IoU 1/3 counted pixel by pixel), a depth map in metres or
millimetres over a plane at 2 m, a sphere seen by cameras around it (silhouette coherence 1 for a consistent rig,
~0.5 + the voxel's reach for a mask moved by its own radius), and hand-written frame figures at the thresholds'
boundaries (warn vs refuse, which camera is named, every sentence as the user reads it). Fast: no session, no
fit (about 5 s of CPU, most of it numba's first calls); the whole-session checks are
tests/reliability/test_reconstruct_plausibility.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bodystudio.capture.render import render
from bodystudio.geometry.camera import Camera
from bodystudio.reconstruct import plausibility as P

F_PX = 64.0


def _front_camera(name="a", w=48, h=40):
    """A camera at the origin looking down +z, f = 64 px, principal point (0, 0): a point (x, y, 2) lands on
    pixel (32 x, 32 y), exactly, for the dyadic coordinates used here."""
    return Camera(name, [[F_PX, 0, 0], [0, F_PX, 0], [0, 0, 1]], None, np.eye(3), np.zeros(3), w, h)


def _square(u0, u1, v0, v1, z=2.0):
    """Two triangles whose projection in :func:`_front_camera` is the pixel rectangle [u0, u1] x [v0, v1]."""
    uv = np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]], float)
    return np.c_[uv * z / F_PX, np.full(4, z)], np.array([[0, 1, 2], [0, 2, 3]])


def _rect_mask(rows, cols, shape=(40, 48), value=1):
    m = np.zeros(shape, np.uint8)
    m[rows[0]:rows[1], cols[0]:cols[1]] = value
    return m


# --- silhouette_agreement: IoU per camera ----------------------------------------------------------------------

def test_iou_of_a_square_with_a_mask_half_beside_it_is_one_third():
    """The square covers the pixel centres of columns and rows 10..29 (400 pixels); a mask over columns 20..39
    shares 200 of them: IoU 200 / 600. The same rectangle as a mask gives 1; a mask of 255s counts as one of 1s."""
    V, F = _square(10, 29, 10, 29)
    cam = _front_camera()
    assert P.silhouette_agreement(V, F, [cam], {"a": _rect_mask((10, 30), (20, 40))}) == {"a": 1 / 3}
    assert P.silhouette_agreement(V, F, [cam], {"a": _rect_mask((10, 30), (10, 30), value=255)}) == {"a": 1.0}
    # a mask inside the silhouette: 100 / 400
    assert P.silhouette_agreement(V, F, [cam], {"a": _rect_mask((10, 20), (10, 20))})["a"] == 0.25
    # a bool mask, and negative values are not the person
    bool_mask = _rect_mask((10, 30), (10, 20)).astype(bool)
    assert P.silhouette_agreement(V, F, [cam], {"a": bool_mask})["a"] == 0.5
    assert P.silhouette_agreement(V, F, [cam], {"a": -_rect_mask((10, 30), (10, 20)).astype(np.int16)})["a"] == 0.0


def test_iou_is_per_camera_by_name_and_an_empty_view_with_an_empty_mask_agrees():
    """Each camera is compared with its own mask (by name); a camera that sees neither the mesh nor any mask
    pixel has nothing to disagree about: IoU 1. A mask with no mesh in view: 0."""
    V, F = _square(10, 29, 10, 29)
    a = _front_camera("a")
    b = _front_camera("b", w=64)
    away = Camera("away", [[F_PX, 0, 0], [0, F_PX, 0], [0, 0, 1]], None, np.diag([-1.0, 1.0, -1.0]), np.zeros(3),
                  48, 40)
    masks = {"a": _rect_mask((10, 30), (20, 40)), "b": _rect_mask((10, 30), (10, 30), shape=(40, 64)),
             "away": np.zeros((40, 48), np.uint8)}
    assert P.silhouette_agreement(V, F, [a, b, away], masks) == {"a": 1 / 3, "b": 1.0, "away": 1.0}
    masks["away"] = _rect_mask((0, 5), (0, 5))
    assert P.silhouette_agreement(V, F, [away], masks) == {"away": 0.0}
    # the mesh given as float32 and faces as int32 lists: the same figures
    assert P.silhouette_agreement(V.astype(np.float32), F.tolist(), [a], masks)["a"] == pytest.approx(1 / 3)


# --- depth_agreement: coverage, gap and ratio ------------------------------------------------------------------

def test_depth_in_metres_over_the_fitted_plane_agrees_and_in_millimetres_leaves_no_reading_in_range():
    V, F = _square(10, 29, 10, 29)  # a plane at z = 2 m: 19 x 19 pixels in render()'s raster (rows 11..29)
    cam = _front_camera()
    assert P.depth_agreement(V, F, np.full((40, 48), 2.0), cam) == {"coverage": 1.0, "gap_m": 0.0, "ratio": 1.0,
                                                                    "pixels": 361}
    mm = P.depth_agreement(V, F, np.full((40, 48), 2000.0), cam)
    assert mm == {"coverage": 0.0, "gap_m": math.inf, "ratio": 1000.0, "pixels": 361}
    off = P.depth_agreement(V, F, np.full((40, 48), 2.03), cam)
    assert off["coverage"] == 1.0 and off["gap_m"] == pytest.approx(0.03, abs=1e-12)
    assert off["ratio"] == pytest.approx(1.015, abs=1e-12)
    near = P.depth_agreement(V, F, np.full((40, 48), 1.5), cam)  # a reading nearer than the body: |gap|
    assert near["gap_m"] == pytest.approx(0.5, abs=1e-12) and near["ratio"] == pytest.approx(0.75)


@pytest.mark.parametrize("reading, in_range", [(0.4, False), (0.40001, True), (4.99999, True), (5.0, False)])
def test_depth_range_bounds_are_open(reading, in_range):
    """Readings count where depth_range_m[0] < D < depth_range_m[1] (0.4, 5.0 m); the ratio uses every reading."""
    V, F = _square(10, 29, 10, 29)
    out = P.depth_agreement(V, F, np.full((40, 48), reading), _front_camera())
    assert out["coverage"] == (1.0 if in_range else 0.0)
    assert out["gap_m"] == (pytest.approx(abs(reading - 2.0), abs=1e-6) if in_range else math.inf)
    assert out["ratio"] == pytest.approx(reading / 2.0, abs=1e-6)


def test_depth_range_argument_and_missing_readings():
    V, F = _square(10, 29, 10, 29)
    cam = _front_camera()
    # another range: 2 m readings are outside (2.5, 6)
    assert P.depth_agreement(V, F, np.full((40, 48), 2.0), cam, depth_range_m=(2.5, 6.0))["coverage"] == 0.0
    assert P.depth_agreement(V, F, np.full((40, 48), 2.0), cam, depth_range_m=(1.0, 2.5))["coverage"] == 1.0
    # NaN, inf and 0 are no reading: coverage counts the mesh's pixels that have one (columns 20..28: 9 of 19)
    D = np.full((40, 48), 2.0)
    D[:, :15] = np.nan
    D[:, 15:18] = np.inf
    D[:, 18:20] = 0.0
    D[0:20, 20:] = -np.inf
    out = P.depth_agreement(V, F, D, cam)
    assert out["pixels"] == 361
    # render()'s raster covers rows 11..29, columns 10..28: rows 11..19 of columns 20..28 are -inf, 10 rows x 9
    # columns are left
    assert out["coverage"] == pytest.approx(90 / 361) and out["gap_m"] == 0.0 and out["ratio"] == 1.0
    # every reading missing (NaN, or +-inf: no reading either): no gap, no ratio
    for missing in (np.nan, np.inf, -np.inf):
        none = P.depth_agreement(V, F, np.full((40, 48), missing), cam)
        assert none["coverage"] == 0.0 and none["gap_m"] == math.inf and math.isnan(none["ratio"]), missing


def test_a_body_nearer_than_a_metre_is_covered():
    """The mesh's pixels are those render() covers at any depth: a plane 0.75 m away, read at 0.75 m."""
    V, F = _square(10, 29, 10, 29, z=0.75)
    out = P.depth_agreement(V, F, np.full((40, 48), 0.75), _front_camera())
    assert out == {"coverage": 1.0, "gap_m": 0.0, "ratio": 1.0, "pixels": 361}


def test_depth_gap_is_the_median_not_the_mean():
    """190 of the plane's 361 pixels read exactly 2 m, 171 read 2.03 m: median gap 0 (a mean would be 0.014);
    with the halves swapped the median gap is 0.03."""
    V, F = _square(10, 29, 10, 29)
    cam = _front_camera()
    D = np.full((40, 48), 2.0)
    D[:, 20:] = 2.03  # render()'s raster covers columns 10..28: 10 at 2.0, 9 at 2.03
    out = P.depth_agreement(V, F, D, cam)
    assert out["gap_m"] == 0.0 and out["ratio"] == 1.0
    D2 = np.where(D == 2.0, 2.03, 2.0)
    assert P.depth_agreement(V, F, D2, cam)["gap_m"] == pytest.approx(0.03, abs=1e-12)


def test_a_mesh_the_depth_camera_does_not_see_has_no_figures():
    V, F = _square(10, 29, 10, 29)
    V = V * np.array([1.0, 1.0, -1.0])  # behind the camera
    out = P.depth_agreement(V, F, np.full((40, 48), 2.0), _front_camera())
    assert out["coverage"] == 0.0 and out["gap_m"] == math.inf and math.isnan(out["ratio"]) and out["pixels"] == 0
    assert list(out) == ["coverage", "gap_m", "ratio", "pixels"]


# --- silhouette_coherence: leave-one-out visual hull -----------------------------------------------------------

def _look_at(name, eye, f=200.0, w=96, h=96):
    """An OpenCV camera at ``eye`` looking at the origin, world y up."""
    eye = np.asarray(eye, float)
    z = -eye / np.linalg.norm(eye)
    x = np.cross(z, [0.0, -1.0, 0.0])
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return Camera(name, [[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]], None, R, -R @ eye, w, h)


def _box(half, center=(0.0, 0.0, 0.0)):
    """A closed box mesh with half sizes ``half`` around ``center``."""
    c = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    V = c * np.asarray(half, float) + np.asarray(center, float)
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return V, F


def _sphere(r=0.3, n=24, center=(0.0, 0.0, 0.0)):
    """A UV sphere of radius ``r``: its silhouette from 3 m is a disc of r * f / 3 px."""
    th = np.linspace(0, np.pi, n + 1)[1:-1]
    ph = np.linspace(0, 2 * np.pi, 2 * n, endpoint=False)
    V = [[0, r, 0]] + [[r * np.sin(a) * np.cos(b), r * np.cos(a), r * np.sin(a) * np.sin(b)] for a in th for b in ph]
    V.append([0, -r, 0])
    m = 2 * n
    F = [[0, 1 + j, 1 + (j + 1) % m] for j in range(m)]
    for i in range(n - 2):
        for j in range(m):
            a, b = 1 + i * m + j, 1 + i * m + (j + 1) % m
            F += [[a, a + m, b], [b, a + m, b + m]]
    last, base = len(V) - 1, 1 + (n - 2) * m
    F += [[base + j, last, base + (j + 1) % m] for j in range(m)]
    return np.array(V) + np.asarray(center, float), np.array(F)


def _ring(n=4, dist=3.0, center=(0.0, 0.0, 0.0), **kw):
    c = np.asarray(center, float)
    return [_look_at(f"c{k}", c + [dist * np.sin(2 * np.pi * k / n), 0, dist * np.cos(2 * np.pi * k / n)], **kw)
            for k in range(n)]


def _masks(V, F, cams):
    return {c.name: render(V, F, c).mask.astype(np.uint8) for c in cams}


def test_a_consistent_rig_is_coherent_in_every_view_and_a_mask_moved_by_its_radius_is_half_explained():
    """Four cameras around a 0.3 m sphere (a disc of 20 px): every mask lies inside the others' hull (1.0). With
    one camera's mask moved down by 20 px, the others' hull (carved by the moved mask too) explains ~0.5 of it
    plus the strip the voxels' reach adds (0.5 + 2 w / (pi r) for a reach of w ~4 px), plus what the box's voxels
    outside the other views' 96 x 96 images (uncarved) add: 0.61; the views beside it lose the part of their disc
    the moved mask carves away."""
    V, F = _sphere()
    cams = _ring()
    masks = _masks(V, F, cams)
    assert P.silhouette_coherence(cams, masks, np.zeros(3)) == {f"c{k}": 1.0 for k in range(4)}
    moved = dict(masks, c0=np.roll(masks["c0"], 20, axis=0))
    coh = P.silhouette_coherence(cams, moved, np.zeros(3))
    assert coh["c0"] == pytest.approx(0.6087, abs=0.005)
    assert coh["c1"] == pytest.approx(0.6300, abs=0.005) and coh["c3"] == pytest.approx(0.6300, abs=0.005)
    assert coh["c2"] == pytest.approx(0.5771, abs=0.005)


def test_two_orthogonal_views_the_moved_disc_is_half_covered_plus_the_voxel_reach():
    """Camera c1 (along x) sees the sphere as a disc: its hull is a cylinder along x, which c0 sees as a band of
    the disc's height. c0's disc moved down by its radius: half of it in the band, plus the band's widening by
    the voxel's sphere (0.87 voxel, +0.5 px) and the drawn voxels' dilation: 0.649. c1's view of the moved
    mask's hull (a cylinder along z, moved): 0.630. The images (160 x 160) hold the whole box."""
    V, F = _sphere()
    cams = _ring(w=160, h=160)[:2]
    masks = _masks(V, F, cams)
    assert P.silhouette_coherence(cams, masks, np.zeros(3)) == {"c0": 1.0, "c1": 1.0}
    moved = dict(masks, c0=np.roll(masks["c0"], 20, axis=0))
    coh = P.silhouette_coherence(cams, moved, np.zeros(3))
    assert coh["c0"] == pytest.approx(0.6490, abs=0.004) and coh["c1"] == pytest.approx(0.6300, abs=0.004)
    # a finer voxel reaches less beyond the band: nearer one half
    fine = P.silhouette_coherence(cams, moved, np.zeros(3), voxel_m=0.02)
    assert 0.5 < fine["c0"] < coh["c0"] - 0.03


def test_the_box_is_around_the_given_center():
    """The hull is carved in a box around ``center`` (the fitted body): a sphere at (0.5, 0, 0.2) with the box
    around it is coherent; the box around the origin (0.6 m half width) cuts the sphere's far side off."""
    c = (0.5, 0.0, 0.2)
    V, F = _sphere(center=c)
    cams = _ring(center=c)
    masks = _masks(V, F, cams)
    assert P.silhouette_coherence(cams, masks, np.asarray(c)) == {f"c{k}": 1.0 for k in range(4)}
    off = P.silhouette_coherence(cams, masks, np.zeros(3))
    assert min(off.values()) < 0.95


@pytest.mark.parametrize("axis, half", [(0, 0.6), (1, 1.1), (2, 0.6)])
def test_the_default_box_is_0_6_by_1_1_by_0_6_m(axis, half):
    """A 3 m bar along one axis: the default box (half sizes 0.6, 1.1, 0.6 m) explains only its middle; a view
    across the bar covers ~(2 half + reach) / 3 of its mask, so the two views across it fall below 0.9 and
    above (2 half - 0.05) / 3, and a box wide enough explains all of it."""
    size = np.full(3, 0.1)
    size[axis] = 1.5
    V, F = _box(size)
    cams = [_look_at("x", [4.0, 0.3, 0.2], w=200, h=200, f=60.0), _look_at("y", [0.3, 4.0, 0.2], w=200, h=200,
                                                                           f=60.0),
            _look_at("z", [0.2, 0.3, 4.0], w=200, h=200, f=60.0)]
    masks = _masks(V, F, cams)
    coh = P.silhouette_coherence(cams, masks, np.zeros(3))
    across = [c.name for c in cams if c.name != "xyz"[axis]]
    for name in across:
        assert (2 * half - 0.05) / 3 < coh[name] < (2 * half + 0.35) / 3, (name, coh)
    wide = P.silhouette_coherence(cams, masks, np.zeros(3), half_size_m=(1.7, 1.7, 1.7))
    assert min(wide.values()) > 0.97, wide


def test_a_camera_inside_the_box_carves_nothing_and_explains_none_of_its_mask():
    """A camera with voxels behind it (inside the box) cannot project the box: it carves nothing (the others stay
    coherent) and nothing is drawn into it (coherence 0 of a non-empty mask); an empty mask is coherent (1)."""
    V, F = _sphere()
    cams = _ring()
    masks = _masks(V, F, cams)
    inside = Camera("in", [[100, 0, 48], [0, 100, 48], [0, 0, 1]], None, np.eye(3), np.array([0.0, 0.0, -0.5]),
                    96, 96)
    coh = P.silhouette_coherence(cams + [inside], dict(masks, **{"in": _rect_mask((0, 96), (0, 96),
                                                                                   shape=(96, 96))}), np.zeros(3))
    assert coh["in"] == 0.0 and all(coh[c.name] == 1.0 for c in cams)
    coh = P.silhouette_coherence(cams + [inside], dict(masks, **{"in": np.zeros((96, 96), np.uint8)}), np.zeros(3))
    assert coh["in"] == 1.0


def test_one_camera_alone_is_explained_by_the_whole_box_and_an_empty_mask_is_coherent():
    V, F = _sphere()
    cams = _ring()
    masks = _masks(V, F, cams)
    assert P.silhouette_coherence(cams[:1], masks, np.zeros(3)) == {"c0": 1.0}
    empty = dict(masks, c2=np.zeros_like(masks["c2"]))
    coh = P.silhouette_coherence(cams, empty, np.zeros(3))
    assert coh["c2"] == 1.0
    # an empty mask carves everything away: the other views are explained by nothing
    assert all(coh[c] == 0.0 for c in ("c0", "c1", "c3")), coh


def test_a_camera_near_the_body_and_one_that_sees_part_of_it_keep_a_consistent_rig_coherent():
    """A fifth camera 1 m from the sphere (the box's nearest voxels 0.4 m from it, its voxel spheres 3-22 px wide)
    and, instead, one whose image holds only part of the sphere (principal point at column 8: the left third is
    outside its image): every view stays 1.0; the part-view does not carve what it cannot see. With c0's mask moved
    by 20 px the near camera is explained 0.562 (pinned, as the ring's figures)."""
    V, F = _sphere()
    cams = _ring()
    near = _look_at("near", [0.0, 0.0, -1.0], f=100.0, w=160, h=160)
    masks = _masks(V, F, cams + [near])
    assert P.silhouette_coherence(cams + [near], masks, np.zeros(3)) == {**{f"c{k}": 1.0 for k in range(4)},
                                                                          "near": 1.0}
    moved = dict(masks, c0=np.roll(masks["c0"], 20, axis=0))
    coh = P.silhouette_coherence(cams + [near], moved, np.zeros(3))
    assert coh["near"] == pytest.approx(0.5622, abs=0.004) and coh["c0"] == pytest.approx(0.6087, abs=0.005)
    c1 = cams[1]
    part = Camera("part", [[200, 0, 8], [0, 200, 48], [0, 0, 1]], None, c1.R, c1.t, 96, 96)
    pmasks = _masks(V, F, cams + [part])
    assert 0 < pmasks["part"][:, 0].sum() and pmasks["part"].sum() < masks["c1"].sum()
    assert P.silhouette_coherence(cams + [part], pmasks, np.zeros(3)) == {**{f"c{k}": 1.0 for k in range(4)},
                                                                           "part": 1.0}


def test_a_box_smaller_than_a_voxel_is_one_voxel_and_a_bar_ending_in_the_box():
    """Half sizes of 1 cm (under the 4 cm voxel): one voxel at the centre, drawn as a disc of its reach (3 px) in
    each 20 px disc: 0.026. A 1.5 m bar hanging below the centre (y from -1.5 to 0): the box (y >= -1.1) explains
    its upper 1.1 m plus the voxels' reach: 0.797 in both views across it."""
    V, F = _sphere()
    cams = _ring()
    masks = _masks(V, F, cams)
    tiny = P.silhouette_coherence(cams, masks, np.zeros(3), half_size_m=(0.01, 0.01, 0.01))
    assert tiny == {f"c{k}": pytest.approx(0.02609, abs=0.001) for k in range(4)}
    Vb, Fb = _box((0.1, 0.75, 0.1), (0.0, -0.75, 0.0))
    views = [_look_at("x", [4.0, 0.3, 0.2], w=200, h=200, f=60.0), _look_at("z", [0.2, 0.3, 4.0], w=200, h=200,
                                                                           f=60.0)]
    coh = P.silhouette_coherence(views, _masks(Vb, Fb, views), np.zeros(3))
    assert coh == {"x": pytest.approx(0.7971, abs=0.004), "z": pytest.approx(0.7971, abs=0.004)}


# --- frame_plausibility and coherence_frames ---------------------------------------------------------------------

def test_frame_plausibility_holds_the_figures_it_was_given_inputs_for():
    V, F = _sphere()
    cams = _ring()
    masks = _masks(V, F, cams)
    cam = _front_camera()
    Vs, Fs = _square(10, 29, 10, 29)
    assert P.frame_plausibility(V, F, cams, None) == {}
    sil = {"silhouette_iou", "silhouette_precision_tol", "silhouette_recall_tol"}  # + trust4's band figures
    out = P.frame_plausibility(V, F, cams, masks)
    assert set(out) == sil and min(out["silhouette_iou"].values()) > 0.95
    assert out["silhouette_precision_tol"] == out["silhouette_recall_tol"] == {f"c{k}": 1.0 for k in range(4)}
    out = P.frame_plausibility(V, F, cams, masks, coherence=True)
    assert set(out) == sil | {"coherence"} and out["coherence"] == {f"c{k}": 1.0 for k in range(4)}
    # the box goes around the mesh's mean point: a sphere 1.3 m from the origin stays coherent
    V2, _ = _sphere(center=(1.0, 0.0, -0.8))
    cams2 = _ring(center=(1.0, 0.0, -0.8))
    out = P.frame_plausibility(V2, F, cams2, _masks(V2, F, cams2), coherence=True)
    assert out["coherence"] == {f"c{k}": 1.0 for k in range(4)}
    # two cameras: each one's coherence from the other
    assert P.frame_plausibility(V, F, cams[:2], masks, coherence=True)["coherence"] == {"c0": 1.0, "c1": 1.0}
    # one camera: no coherence (nothing to leave out)
    assert set(P.frame_plausibility(V, F, cams[:1], masks, coherence=True)) == sil
    # depth needs the map and its camera
    depth = np.full((40, 48), 2.0)
    assert P.frame_plausibility(Vs, Fs, [cam], None, depth, cam) == {"depth": {"coverage": 1.0, "gap_m": 0.0,
                                                                              "ratio": 1.0, "pixels": 361}}
    assert P.frame_plausibility(Vs, Fs, [cam], None, depth, None) == {}
    assert P.frame_plausibility(Vs, Fs, [cam], None, None, cam) == {}


@pytest.mark.parametrize("n, most, expected", [
    (1, 3, {0}), (2, 3, {0, 1}), (3, 3, {0, 1, 2}), (10, 3, {0, 4, 9}), (11, 3, {0, 5, 10}), (9, 5, {0, 2, 4, 6, 8}),
    (9, 2, {0, 8}), (0, 3, set()),
])
def test_coherence_frames_are_first_middle_last(n, most, expected):
    assert P.coherence_frames(n, most) == expected


def test_coherence_frames_default_is_three():
    assert P.coherence_frames(101) == {0, 50, 100}


# --- run_plausibility: the verdict ---------------------------------------------------------------------------------

def _frame(iou=None, coh=None, depth=None):
    return {k: v for k, v in (("silhouette_iou", iou), ("coherence", coh), ("depth", depth)) if v is not None}


THRESHOLDS = {"iou_warn": 0.85, "iou_refuse": 0.75, "coherence_warn": 0.9, "coherence_refuse": 0.8,
              "depth_coverage_refuse": 0.5, "depth_gap_refuse_m": 0.05,
              # trust4's band rule (a low IoU whose fit stays in the mask's band is the masks' noise)
              "tolerance_px_at_640": 3.0, "tolerant_precision_trust": 0.95, "tolerant_recall_trust": 0.65}
CHECK = "check S/calibration/cameras.json for a moved camera (re-calibrate) and the masks for another camera's files"


def test_thresholds_and_a_clean_run():
    assert (P.IOU_WARN, P.IOU_REFUSE, P.COHERENCE_WARN, P.COHERENCE_REFUSE, P.COHERENCE_OUTLIER) == \
        (0.85, 0.75, 0.9, 0.8, 0.15)
    assert (P.DEPTH_COVERAGE_REFUSE, P.DEPTH_GAP_REFUSE_M, P.DEPTH_RANGE_M) == (0.5, 0.05, (0.4, 5.0))
    r = P.run_plausibility([_frame({"a": 0.95, "b": 0.97}, {"a": 1.0, "b": 0.99})], "S")
    assert r == {"thresholds": THRESHOLDS, "camera_iou": {"a": 0.95, "b": 0.97},
                 "camera_coherence": {"a": 1.0, "b": 0.99}, "warnings": [], "problems": [], "ok": True}
    assert P.run_plausibility([]) == {"thresholds": THRESHOLDS, "warnings": [], "problems": [], "ok": True}


def test_per_camera_figures_are_the_median_over_frames():
    """Per camera the median over the frames that have it; frames without the figure are skipped; the cameras
    are the first such frame's."""
    frames = [_frame({"a": 0.9, "b": 0.95}, {"b": 0.95}), _frame({"a": 0.7}), {}, _frame({"a": 0.8, "b": 0.99}),
              _frame(coh={"b": 0.97}), _frame({}, {})]
    r = P.run_plausibility(frames)
    assert r["camera_iou"] == {"a": 0.8, "b": pytest.approx(0.97)} and r["camera_coherence"] == {"b": 0.96}
    assert r["ok"] and r["warnings"] == ["camera a agree less with the fit or the other cameras (silhouette IoU "
                                         "a 0.80; coherence -); the calibration or masks may be off"]


@pytest.mark.parametrize("iou, coh, verdict", [
    (0.85, 0.9, "ok"), (0.8499, 0.95, "warn"), (0.95, 0.8999, "warn"),
    (0.75, 0.95, "warn"), (0.7499, 0.95, "refuse"), (0.95, 0.8, "warn"), (0.95, 0.7999, "refuse"),
])
def test_threshold_boundaries_warn_versus_refuse(iou, coh, verdict):
    """At a threshold the camera is on the better side: IoU 0.85 / coherence 0.9 pass, 0.75 / 0.8 warn."""
    r = P.run_plausibility([_frame({"a": iou, "b": 0.99}, {"a": coh, "b": 1.0, "c": 1.0})], "S")
    assert r["ok"] == (verdict != "refuse")
    assert bool(r["warnings"]) == (verdict == "warn") and bool(r["problems"]) == (verdict == "refuse")
    if verdict == "warn":
        assert r["warnings"][0].startswith("camera a agree less")


def test_a_weak_camera_is_named_in_a_warning():
    r = P.run_plausibility([_frame({"a": 0.8, "b": 0.97}, {"a": 1.0, "b": 0.85})], "S")
    assert r["warnings"] == ["cameras a, b agree less with the fit or the other cameras (silhouette IoU a 0.80, "
                             "b 0.97; coherence a 1.00, b 0.85); the calibration or masks may be off"]
    assert r["problems"] == [] and r["ok"]


def test_the_fit_is_blamed_when_the_cameras_agree_with_each_other():
    """Low IoU but every view's coherence >= 0.9 (0.9 exactly included): the inputs are consistent, the fit is
    wrong; the low cameras listed worst first."""
    r = P.run_plausibility([_frame({"a": 0.7, "b": 0.97, "c": 0.6}, {"a": 1.0, "b": 0.9, "c": 0.93})], "S")
    assert r["problems"] == [
        "the fit does not explain the silhouettes although the cameras agree with each other (the fit's silhouette "
        "IoU c 0.60, a 0.70, trusted >= 0.75; the share of each mask the other cameras' visual hull explains "
        "0.90..1.00, consistent views ~1.0): it did not converge or started from wrong joints; raise "
        "--outer/--inner, check the joints (--joints)"]
    assert r["warnings"] == [] and not r["ok"]
    # just below 0.9 coherence somewhere: the cameras are blamed instead
    r = P.run_plausibility([_frame({"a": 0.7, "b": 0.97, "c": 0.6}, {"a": 1.0, "b": 0.8999, "c": 0.93})], "S")
    assert r["problems"][0].startswith("the cameras disagree with each other (") and r["problems"][0].endswith(CHECK)


def test_a_bumped_camera_is_named_by_its_coherence():
    """A camera below min(0.8, the views' median - 0.15) is the one that disagrees."""
    r = P.run_plausibility([_frame({"a": 0.7, "b": 0.97, "c": 0.9, "d": 0.9}, {"a": 0.5, "b": 0.95, "c": 0.93,
                                                                               "d": 0.94})], "S")
    assert r["problems"] == [
        "camera a disagrees with the other cameras (the fit's silhouette IoU a 0.70, trusted >= 0.75; the share of "
        f"each mask the other cameras' visual hull explains a 0.50, the others' median 0.94, consistent views ~1.0): "
        f"{CHECK}"]
    # two of them, worst first, without an IoU below the refusal
    r = P.run_plausibility([_frame({"a": 0.9, "b": 0.97, "c": 0.9, "d": 0.9, "e": 0.9},
                                   {"a": 0.5, "b": 0.45, "c": 0.93, "d": 0.94, "e": 0.95})])
    assert r["problems"] == [
        "cameras b, a disagree with the other cameras (the share of each mask the other cameras' visual hull "
        "explains b 0.45, a 0.50, the others' median 0.93, consistent views ~1.0): check calibration/cameras.json "
        "for a moved camera (re-calibrate) and the masks for another camera's files"]


def test_the_outlier_rule_at_its_boundaries():
    """Median 0.9: a camera is named below 0.75 (= 0.9 - 0.15), not at 0.75; with a median of 0.85 the bound
    is 0.7; the bound is never above the refusal 0.8 (median 1.0: named below 0.8)."""
    def named(coh):
        r = P.run_plausibility([_frame({c: 0.9 for c in coh}, coh)])
        return r["problems"][0].split(" (")[0]

    assert named({"a": 0.7499, "b": 0.9, "c": 0.9}) == "camera a disagrees with the other cameras"
    assert named({"a": 0.75, "b": 0.9, "c": 0.9}) == "the cameras disagree with each other"
    assert named({"a": 0.7, "b": 0.85, "c": 0.85}) == "the cameras disagree with each other"
    assert named({"a": 0.6999, "b": 0.85, "c": 0.85}) == "camera a disagrees with the other cameras"
    assert named({"a": 0.7999, "b": 1.0, "c": 1.0}) == "camera a disagrees with the other cameras"


def test_swapped_masks_blame_no_single_camera():
    r = P.run_plausibility([_frame({"a": 0.7, "b": 0.72}, {"a": 0.79, "b": 0.85, "c": 0.9})], "S")
    assert r["problems"] == [
        "the cameras disagree with each other (the fit's silhouette IoU a 0.70, b 0.72, trusted >= 0.75; the share "
        "of each mask the other cameras' visual hull explains 0.79..0.90, consistent views ~1.0): " + CHECK]


def test_at_most_three_low_cameras_are_listed():
    r = P.run_plausibility([_frame({"a": 0.7, "b": 0.6, "c": 0.5, "d": 0.4, "e": 0.99})], "S")
    assert r["problems"] == ["the cameras disagree with each other (the fit's silhouette IoU d 0.40, c 0.50, "
                             "b 0.60 ..., trusted >= 0.75): " + CHECK]
    assert "camera_coherence" not in r
    r = P.run_plausibility([_frame({"b": 0.6, "c": 0.5, "d": 0.4, "e": 0.99})], "S")
    assert r["problems"][0].startswith("the cameras disagree with each other (the fit's silhouette IoU d 0.40, "
                                       "c 0.50, b 0.60, trusted >= 0.75)")


def test_depth_in_another_unit_is_refused_with_its_ratio():
    mm = {"coverage": 0.0, "gap_m": math.inf, "ratio": 1000.0, "pixels": 5}
    r = P.run_plausibility([_frame({"a": 0.95}, None, mm)], "S")
    assert r["depth"] == {"coverage": 0.0, "gap_m": math.inf, "ratio": 1000.0}
    assert r["problems"] == [
        "the Kinect depth does not fit the body the silhouettes give (the readings are 1e+03x the fitted body's "
        "distance, 0% of its pixels usable, median gap inf m): check the unit of S/kinect/depth (re-import with "
        "the right --depth-scale) and S/kinect/calibration.json, or use --constraints silhouette"]
    nothing = {"coverage": 0.0, "gap_m": math.inf, "ratio": float("nan"), "pixels": 0}
    r = P.run_plausibility([_frame(depth=nothing)])
    assert r["problems"] == [
        "the Kinect depth does not fit the body the silhouettes give (no depth reading where the body is, 0% of its "
        "pixels usable, median gap inf m): check the unit of kinect/depth (re-import with the right --depth-scale) "
        "and kinect/calibration.json, or use --constraints silhouette"]
    assert math.isnan(r["depth"]["ratio"])


@pytest.mark.parametrize("coverage, gap, ok", [(0.5, 0.05, True), (0.4999, 0.01, False), (0.9, 0.0501, False)])
def test_depth_boundaries(coverage, gap, ok):
    r = P.run_plausibility([_frame(depth={"coverage": coverage, "gap_m": gap, "ratio": 1.0, "pixels": 9})])
    assert r["ok"] == ok and len(r["problems"]) == (0 if ok else 1)


def test_depth_figures_are_medians_over_frames_with_depth_and_finite_ratios():
    d = [{"coverage": 0.9, "gap_m": 0.01, "ratio": 1.0}, {"coverage": 0.2, "gap_m": 0.2, "ratio": float("nan")},
         {"coverage": 0.95, "gap_m": 0.02, "ratio": 1.2}, {"coverage": 0.8, "gap_m": 0.03, "ratio": 1.1}]
    r = P.run_plausibility([_frame(depth=x) for x in d] + [_frame({"a": 0.99})])
    assert r["depth"] == {"coverage": pytest.approx(0.85), "gap_m": pytest.approx(0.025),
                          "ratio": pytest.approx(1.1)}
    assert r["ok"]
