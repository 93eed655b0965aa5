"""bodystudio.reconstruct.visual_hull against references independent of it (issue 17, mutation testing): the
coarse-to-fine carving of a box seen by four small cameras equals a brute-force voxel-centre test over the whole grid
(every voxel projected by the camera model, looked up in every mask), the marching-cubes surface of voxel blocks
half a voxel outside their centres, hand-placed points in and around a one-voxel hull, the virtual Kinect's pose, and
every refusal word for word."""

from functools import cache

import numpy as np
import pytest
import trimesh

from bodystudio.capture.render import render
from bodystudio.errors import InputError
from bodystudio.geometry.camera import Camera
from bodystudio.reconstruct import visual_hull as vh

BOUNDS = ((-0.4, 0.3, -0.4), (0.4, 1.5, 0.4))


@cache
def _scene():
    """A 0.4 x 0.8 x 0.3 m box centred at y = 0.9 and its masks in four 64 x 48 cameras."""
    box = trimesh.creation.box(extents=(0.4, 0.8, 0.3))
    box.apply_translation((0.05, 0.9, 0.0))
    V, F = np.asarray(box.vertices), np.asarray(box.faces)
    eyes = [(0.0, 0.9, 3.0), (3.0, 1.0, 0.0), (-2.0, 1.2, -2.0), (0.3, 4.0, 0.5)]
    cams = [Camera.look_at(f"c{i}", eye, (0.0, 0.9, 0.0), fx=50.0, width=64, height=48)
            for i, eye in enumerate(eyes)]
    masks = {c.name: render(V, F, c).mask for c in cams}
    return V, F, cams, masks


@cache
def _close_scene():
    """The box's scene plus two cameras 0.6 m in front of it whose images the silhouette overflows (top and bottom,
    then left and right: the second is turned a quarter): voxels near their borders straddle the image edges."""
    V, F, cams, masks = _scene()
    close = Camera.look_at("c4", (0.0, 0.9, 0.75), (0.0, 0.9, 0.0), fx=60.0, width=64, height=48)
    turned = Camera.look_at("c5", (0.0, 0.9, 0.75), (0.0, 0.9, 0.0), up=(1.0, 0.0, 0.0), fx=60.0, width=48,
                            height=64)
    m4, m5 = render(V, F, close).mask, render(V, F, turned).mask
    assert m4[0].any() and m4[-1].any() and m5[:, 0].any() and m5[:, -1].any()
    return V, F, cams + [close, turned], {**masks, "c4": m4, "c5": m5}


def _brute_force(cams, masks, voxel_m, levels, max_missing=0):
    """Every fine voxel centre of the carving's grid projected into every view and looked up in its mask."""
    lo, hi = (np.asarray(b, float) for b in BOUNDS)
    coarse = 2 ** levels
    shape = np.ceil((hi - lo) / (voxel_m * coarse)).astype(int) * coarse
    origin = lo + 0.5 * voxel_m
    ijk = np.indices(shape).reshape(3, -1).T
    P = origin + voxel_m * ijk
    missed = np.zeros(len(P), int)
    for cam in cams:
        uv, z = cam.project_with_depth(P)
        col, row = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
        inside = (z > 0) & (col >= 0) & (col < cam.width) & (row >= 0) & (row < cam.height)
        hit = np.zeros(len(P), bool)
        hit[inside] = masks[cam.name][row[inside], col[inside]]
        missed += ~hit
    return (missed <= max_missing).reshape(shape), origin


@pytest.mark.parametrize("close, levels, max_missing", [(False, 2, 0), (False, 3, 0), (False, 2, 1), (False, 0, 0),
                                                        (True, 3, 0), (True, 2, 1)])
def test_carving_equals_the_brute_force_voxel_centre_test(close, levels, max_missing):
    _, _, cams, masks = _close_scene() if close else _scene()
    occ, origin = vh.carve_occupancy(cams, masks, BOUNDS, 0.04, max_missing, levels=levels)
    ref, ref_origin = _brute_force(cams, masks, 0.04, levels, max_missing)
    np.testing.assert_allclose(origin, ref_origin, atol=1e-15)
    assert occ.shape == ref.shape and occ.dtype == bool
    assert ref.sum() > 50
    np.testing.assert_array_equal(occ, ref)


def test_the_masks_may_be_a_list_in_camera_order_and_default_bounds_are_the_studio():
    _, _, cams, masks = _scene()
    as_list, _ = vh.carve_occupancy(cams, [masks[c.name] for c in cams], BOUNDS, 0.04)
    as_dict, _ = vh.carve_occupancy(cams, masks, BOUNDS, 0.04)
    np.testing.assert_array_equal(as_list, as_dict)
    studio, origin = vh.carve_occupancy(cams, np.stack([masks[c.name] for c in cams]), None, 0.1, levels=1)
    np.testing.assert_allclose(origin, np.array(vh.DEFAULT_BOUNDS[0]) + 0.05, atol=1e-15)
    assert studio.shape == (22, 24, 22)


def test_the_default_voxel_is_1_5_cm():
    _, _, cams, masks = _scene()
    occ, _ = vh.carve_occupancy(cams, masks, BOUNDS, levels=0)
    assert occ.shape == (54, 80, 54)  # 0.8 x 1.2 x 0.8 m in 1.5 cm voxels, rounded up
    assert vh.visual_hull(cams, masks, BOUNDS).voxel_m == 0.015


def test_visual_hull_crops_to_the_occupied_box_plus_one_voxel():
    V, _, cams, masks = _scene()
    full, origin = vh.carve_occupancy(cams, masks, BOUNDS, 0.04)
    hull = vh.visual_hull(cams, masks, BOUNDS, 0.04)
    idx = np.argwhere(full)
    lo, hi = idx.min(0) - 1, idx.max(0) + 2
    assert (lo >= 0).all() and (hi <= full.shape).all()
    np.testing.assert_array_equal(hull.occupancy, full[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]])
    np.testing.assert_allclose(hull.origin, origin + 0.04 * lo, atol=1e-15)
    assert hull.voxel_m == 0.04 and type(hull.voxel_m) is float
    assert hull.occupancy.flags.c_contiguous
    # the surface lies half a voxel outside the outermost occupied centres
    centres = hull.origin + 0.04 * np.argwhere(hull.occupancy)
    np.testing.assert_allclose(hull.vertices.min(0), centres.min(0) - 0.02, atol=1e-12)
    np.testing.assert_allclose(hull.vertices.max(0), centres.max(0) + 0.02, atol=1e-12)
    assert hull.contains([[0.05, 0.9, 0.0]]).all() and not hull.contains([[0.05, 0.9, 0.38]]).any()


def test_visual_hull_passes_the_missing_views_on_and_logs_its_size(caplog):
    import logging

    _, _, cams, masks = _close_scene()
    full, _ = vh.carve_occupancy(cams, masks, BOUNDS, 0.04, max_missing_views=1)
    with caplog.at_level(logging.DEBUG, logger="bodystudio.reconstruct.visual_hull"):
        hull = vh.visual_hull(cams, masks, BOUNDS, 0.04, max_missing_views=1)
    assert hull.n_occupied == full.sum() > vh.visual_hull(cams, masks, BOUNDS, 0.04).n_occupied
    n = int(full.sum())
    assert caplog.records[-1].getMessage() == (f"visual hull: {n} voxels of 0.040 m, {n * 0.04 ** 3:.4f} m^3, "
                                               f"{len(hull.vertices)} surface vertices")


def test_a_hull_touching_the_grid_edge_is_not_cropped_past_it():
    _, _, cams, masks = _scene()
    tight = ((-0.12, 0.6, -0.1), (-0.02, 0.7, 0.0))  # an 8-voxel cube inside the box: every voxel occupied
    full, origin = vh.carve_occupancy(cams, masks, tight, 0.02)
    assert full.shape == (8, 8, 8) and full.all()
    hull = vh.visual_hull(cams, masks, tight, 0.02)
    np.testing.assert_array_equal(hull.occupancy, full)
    np.testing.assert_allclose(hull.origin, origin, atol=1e-15)


def test_block_surfaces_and_their_orientation():
    occ = np.zeros((3, 4, 2), bool)
    occ[1:3, 1:4, 0:2] = True
    origin = np.array([0.5, -1.0, 2.0])
    V, F = vh.hull_surface(occ, origin, 0.1)
    centres = origin + 0.1 * np.argwhere(occ)
    np.testing.assert_allclose(V.min(0), centres.min(0) - 0.05, atol=1e-12)
    np.testing.assert_allclose(V.max(0), centres.max(0) + 0.05, atol=1e-12)
    assert vh._signed_volume(V, F) > 0 and F.flags.c_contiguous
    empty_V, empty_F = vh.hull_surface(np.zeros((2, 2, 2), bool), origin, 0.1)
    assert len(empty_F) == 0
    tet = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    Ft = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    assert vh._signed_volume(tet, Ft) == pytest.approx(1 / 6, abs=1e-15)
    assert vh._signed_volume(tet, Ft[:, ::-1]) == pytest.approx(-1 / 6, abs=1e-15)
    assert vh._signed_volume(tet + [2.0, 3.0, -1.0], Ft) == pytest.approx(1 / 6, abs=1e-12)


def _one_voxel():
    occ = np.zeros((3, 3, 3), bool)
    occ[1, 1, 1] = True
    origin = np.array([1.0, 2.0, 3.0])
    V, F = vh.hull_surface(occ, origin, 0.1)
    return vh.VisualHull(occ, origin, 0.1, V, F)


def test_contains_and_coverage_of_hand_placed_points():
    hull = _one_voxel()
    centre = np.array([1.1, 2.1, 3.1])
    P = np.array([centre, centre + [0.04, -0.04, 0.04], centre + [0.1, 0, 0], centre + [0.1, 0.1, -0.1],
                  centre + [0.2, 0, 0], centre - [0.2, 0.2, 0.2], centre + [0, 0.3, 0], centre - [0.15, 0, 0]])
    np.testing.assert_array_equal(hull.contains(P), [1, 1, 0, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(hull.contains(P, 1), [1, 1, 1, 1, 0, 0, 0, 1])
    np.testing.assert_array_equal(hull.contains(P, 2), [1, 1, 1, 1, 1, 1, 0, 1])
    np.testing.assert_array_equal(hull.contains(P, -3), hull.contains(P))
    np.testing.assert_array_equal(hull.contains(P.tolist(), 1.7), hull.contains(P, 1))  # voxels are whole
    assert hull.contains(P).dtype == bool

    assert vh.hull_coverage(hull, P, dilate_voxels=0) == pytest.approx(2 / 8)
    assert vh.hull_coverage(hull, P) == pytest.approx(5 / 8)  # one voxel of dilation by default
    assert vh.hull_coverage(hull, P.ravel().tolist(), 2) == pytest.approx(7 / 8)
    assert np.isnan(vh.hull_coverage(hull, np.zeros((0, 3))))


def test_dilation_is_the_3x3x3_cube_and_voxel_zero_counts():
    occ = np.zeros((7, 7, 7), bool)
    occ[3, 3, 3] = occ[0, 0, 0] = True
    hull = vh.VisualHull(occ, np.zeros(3), 0.1, np.zeros((0, 3)), np.zeros((0, 3), int))
    c = np.array([0.3, 0.3, 0.3])
    steps = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    one = np.r_[c + 0.1 * steps, c - 0.1 * steps, [c + [0.1, -0.1, 0.1]]]
    two = np.r_[c + 0.2 * steps, c - 0.2 * steps]
    assert hull.contains(one, 1).all() and not hull.contains(one).any()
    assert not hull.contains(two, 1).any() and hull.contains(two, 2).all()
    assert hull.contains([[0.0, 0.0, 0.0], [0.04, -0.04, 0.0]]).all()  # the voxel at index 0
    assert not hull.contains([[-0.1, 0.0, 0.0], [0.0, 0.7, 0.0]]).any()  # beyond either end of the grid


def test_the_virtual_kinect_looks_at_the_centroid_from_the_facing_side():
    hull = _one_voxel()
    centroid = np.array([1.1, 2.1, 3.1])
    cam = vh.virtual_depth_camera(hull, facing=(3, 5, 0))  # integers
    np.testing.assert_allclose(cam.center, centroid + [2.5, 0.0, 0.0], atol=1e-12)
    assert (cam.width, cam.height, cam.fx, cam.fy) == (512, 424, 365.0, 365.0)
    np.testing.assert_allclose(cam.project(centroid[None])[0], cam.K[:2, 2], atol=1e-9)  # on the optical axis
    assert cam.name == "virtual_depth"
    default = vh.virtual_depth_camera(hull, distance_m=1.5, intrinsics={"width": 100, "fx": 90.0})
    np.testing.assert_allclose(default.center, centroid + [0.0, 0.0, 1.5], atol=1e-12)
    assert (default.width, default.height, default.fx) == (100, 424, 90.0)
    facing = [0.0, 1.0, 0.0]
    with pytest.raises(InputError) as err:
        vh.virtual_depth_camera(hull, facing=facing)
    assert str(err.value) == "virtual depth camera: facing direction [0.0, 1.0, 0.0] has no horizontal component"
    assert facing == [0.0, 1.0, 0.0]  # the caller's direction is not changed


def test_the_hull_depth_map_sees_the_front_of_the_box():
    _, _, cams, masks = _scene()
    hull = vh.visual_hull(cams, masks, BOUNDS, 0.04)
    cam = vh.virtual_depth_camera(hull)
    depth = vh.hull_depth_map(hull, cam)
    assert depth.shape == (424, 512)
    # the hull surface hit by the optical axis: Moeller-Trumbore against every triangle
    forward = hull.centroid - cam.center
    forward /= np.linalg.norm(forward)
    a, b, c = (hull.vertices[hull.faces[:, i]] for i in range(3))
    e1, e2, s = b - a, c - a, cam.center - a
    p = np.cross(forward, e2)
    det = np.einsum("ij,ij->i", e1, p)
    with np.errstate(divide="ignore", invalid="ignore"):
        u_ = np.einsum("ij,ij->i", s, p) / det
        q = np.cross(s, e1)
        v_ = (q @ forward) / det
        t = np.einsum("ij,ij->i", e2, q) / det
        hit = (np.abs(det) > 1e-15) & (u_ >= 0) & (v_ >= 0) & (u_ + v_ <= 1) & (t > 0)
    near = t[hit].min()
    u, v = np.rint(cam.K[:2, 2]).astype(int)
    assert depth[v, u] == pytest.approx(near, abs=2e-3)
    assert depth[0, 0] == 0.0 and depth.dtype == np.float32


def test_refusals():
    _, _, cams, masks = _scene()
    cases = [
        (lambda: vh.carve_occupancy([], masks, BOUNDS), "visual hull needs at least one camera"),
        (lambda: vh.carve_occupancy(cams, {"c0": masks["c0"], "c2": masks["c2"]}, BOUNDS),
         "visual hull: no mask for camera(s) c1, c3"),
        (lambda: vh.carve_occupancy(cams, [masks["c0"]] * 3, BOUNDS), "visual hull: 3 masks for 4 cameras"),
        (lambda: vh.carve_occupancy(cams, 7, BOUNDS),
         "visual hull: masks must be a mapping camera name -> (H, W) mask or a list"),
        (lambda: vh.carve_occupancy(cams, {**masks, "c1": np.ones((48, 63), bool)}, BOUNDS),
         "visual hull: mask of camera c1 is (48, 63), camera image is (48, 64)"),
        (lambda: vh.carve_occupancy(cams, {**masks, "c2": np.zeros((48, 64), bool)}, BOUNDS),
         "visual hull: the mask of camera c2 is empty (no foreground); check the silhouettes of that view"),
        (lambda: vh.carve_occupancy(cams, masks, BOUNDS, voxel_m=0.0), "voxel size must be positive, got 0.0"),
        (lambda: vh.carve_occupancy(cams, masks, BOUNDS, max_missing_views=4),
         "max_missing_views must be in [0, 3], got 4"),
        (lambda: vh.carve_occupancy(cams, masks, BOUNDS, max_missing_views=-1),
         "max_missing_views must be in [0, 3], got -1"),
        (lambda: vh.carve_occupancy(cams, masks, ((0, 0, 0), (1, 0, 1))),
         "visual hull bounds must be (min xyz, max xyz) with max > min, got ((0, 0, 0), (1, 0, 1))"),
        (lambda: vh.carve_occupancy(cams, masks, ((0, 0), (1, 1))),
         "visual hull bounds must be (min xyz, max xyz) with max > min, got ((0, 0), (1, 1))"),
        (lambda: vh.carve_occupancy(cams, masks, ((0, 0, 0), (1, 1, 1, 1))),
         "visual hull bounds must be (min xyz, max xyz) with max > min, got ((0, 0, 0), (1, 1, 1, 1))"),
        (lambda: vh.visual_hull(cams, masks, ((2.0, 2.0, 2.0), (2.5, 2.5, 2.5)), 0.1),
         "visual hull is empty: the silhouettes share no common volume inside the capture bounds; check the "
         "calibration and the masks"),
    ]
    for call, message in cases:
        with pytest.raises(InputError) as err:
            call()
        assert str(err.value) == message
    vh.carve_occupancy(cams, masks, BOUNDS, 0.1, max_missing_views=3, levels=1)  # all but one view may miss


def test_points_beyond_one_and_a_half_corner_radii_are_not_folded_into_the_image():
    """A barrel lens whose distortion folds back to the principal point at 1.5 corner radii (docstring of
    _consistent_views): points just inside that radius land near the centre and hit an all-foreground mask, points
    just beyond it (folded onto the same pixels) are dropped. The principal point is off centre and fx != fy, so the
    radius depends on which of cx, cy, width - cx, height - cy, fx, fy it is built from."""
    w, h, cx, cy, fx, fy = 64, 40, 40.0, 22.0, 50.0, 70.0
    r_max = 1.5 * np.hypot(max(cx, w - cx) / fx, max(cy, h - cy) / fy)  # the docstring's rule, by hand
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    cam = Camera("barrel", K, [-1.0 / r_max ** 2, 0.0, 0.0, 0.0, 0.0], np.eye(3), np.zeros(3), w, h)
    mask = np.ones((h, w), bool)
    directions = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0], [0.6, 0.8]])
    P, expected = [], []
    for d in directions:
        for scale, inside in ((0.99, True), (1.01, False)):
            xy = scale * r_max * d
            P.append([xy[0] * 2.0, xy[1] * 2.0, 2.0])  # 2 m in front of the camera
            expected.append(inside)
    P = np.array(P)
    uv, _ = cam.project_with_depth(P)
    assert ((uv >= 0) & (uv < [w, h])).all()  # every point, inside or beyond, projects into the image
    for radius in (0.0, 0.01):
        np.testing.assert_array_equal(vh._consistent_views([cam], [mask], [vh._mask_distance(mask)], P, radius, 0),
                                      expected)


def test_the_coarse_test_keeps_a_cell_whose_sphere_may_reach_the_silhouette():
    """Three coarse cells on a 40 x 40 camera (f = 100 px) whose bounding spheres reach a one-pixel silhouette though
    their centres miss it: one left of the image, one above it (the silhouette 2 px in and 2 px along from the
    image edge: 5.4 px from the centre, the sphere 5.6 px), one 0.5 m in front of the camera (8 px away, the sphere
    10.2 px there; 5.6 px at 1 m). The test only prunes: each must be kept."""
    K = np.array([[100.0, 0.0, 20.0], [0.0, 100.0, 20.0], [0.0, 0.0, 1.0]])
    cam = Camera("flat", K, None, np.eye(3), np.zeros(3), 40, 40)
    mask = np.zeros((40, 40), bool)
    mask[12, 2] = mask[2, 12] = mask[20, 28] = True
    pixels_depths = [((-3, 10), 1.0), ((10, -3), 1.0), ((20, 20), 0.5)]
    P = np.array([[(u - 20) / 100 * z, (v - 20) / 100 * z, z] for (u, v), z in pixels_depths])
    np.testing.assert_allclose(cam.project(P), [uv for uv, _ in pixels_depths], atol=1e-9)
    radius = 4.6 / 100  # r_px = 100 * R / z + 1 = 5.6 px at 1 m
    dist = vh._mask_distance(mask)
    np.testing.assert_array_equal(vh._consistent_views([cam], [mask], [dist], P, radius, 0), [True, True, True])
    np.testing.assert_array_equal(vh._consistent_views([cam], [mask], [dist], P, 0.0, 0), [False, False, False])
