"""The reconstruction's scores (reconstruct/evaluate.py: median / p90 / Hausdorff / area share, the visible
surface, silhouette IoU, regions, joints) against independent references: a brute-force closest point on each
triangle (Ericson's region test), hand-built scenes whose visibility is known by construction, per-pixel and
per-vertex loops written from the docstrings. Small inputs built once; the file runs in about a second.
"""

from functools import cache
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.geometry.camera import Camera
from bodystudio.reconstruct import evaluate as ev
from bodystudio.reconstruct.silhouette import silhouette_mask


def closest_point_on_triangle(p, a, b, c):
    """Closest point of triangle abc to p (Ericson, Real-Time Collision Detection 5.1.5): the Voronoi regions."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = ab @ ap, ac @ ap
    if d1 <= 0 and d2 <= 0:
        return a
    bp = p - b
    d3, d4 = ab @ bp, ac @ bp
    if d3 >= 0 and d4 <= d3:
        return b
    vc = d1 * d4 - d3 * d2
    if vc <= 0 and d1 >= 0 and d3 <= 0:
        return a + d1 / (d1 - d3) * ab
    cp = p - c
    d5, d6 = ab @ cp, ac @ cp
    if d6 >= 0 and d5 <= d6:
        return c
    vb = d5 * d2 - d1 * d6
    if vb <= 0 and d2 >= 0 and d6 <= 0:
        return a + d2 / (d2 - d6) * ac
    va = d3 * d6 - d5 * d4
    if va <= 0 and d4 - d3 >= 0 and d5 - d6 >= 0:
        return b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b)
    denom = 1.0 / (va + vb + vc)
    return a + ab * vb * denom + ac * vc * denom


def brute_distance_mm(P, V, F):
    """Per-point distance (mm) to the mesh: the minimum over every triangle, one point at a time."""
    out = np.empty(len(P))
    for i, p in enumerate(P):
        out[i] = min(np.linalg.norm(p - closest_point_on_triangle(p, *V[f])) for f in F)
    return 1000.0 * out


def barycentric_areas(V, F):
    """A third of each incident triangle's area, summed per vertex (by hand)."""
    out = np.zeros(len(V))
    for f in F:
        a = 0.5 * np.linalg.norm(np.cross(V[f[1]] - V[f[0]], V[f[2]] - V[f[0]]))
        for i in f:
            out[i] += a / 3.0
    return out


def grid(nx, ny, xs=None, ys=None):
    """A planar grid in z = 0 (vertex i*ny + j at (xs[i], ys[j], 0)) and its triangles."""
    xs = np.linspace(0, 1, nx) if xs is None else np.asarray(xs, float)
    ys = np.linspace(0, 1, ny) if ys is None else np.asarray(ys, float)
    V = np.array([[x, y, 0.0] for x in xs for y in ys])
    F = []
    for i in range(len(xs) - 1):
        for j in range(len(ys) - 1):
            a, b, c, d = i * len(ys) + j, (i + 1) * len(ys) + j, (i + 1) * len(ys) + j + 1, i * len(ys) + j + 1
            F += [[a, b, c], [a, c, d]]
    return V, np.array(F, np.int64)


@cache
def surfaces():
    """Ground truth: an uneven 5 x 4 grid (0.3 m across); the reconstruction: a 4 x 4 grid over a slightly different
    square, each vertex lifted by its own offset (0.5-40 mm, some downwards)."""
    V_gt, F_gt = grid(5, 4, xs=[0.0, 0.05, 0.12, 0.2, 0.3], ys=[0.0, 0.1, 0.17, 0.3])
    V, F = grid(4, 4, xs=[-0.01, 0.09, 0.2, 0.31], ys=[0.005, 0.1, 0.2, 0.29])
    lift = np.array([0.5, -3.0, 7.0, 12.0, -1.0, 2.5, 25.0, -9.0, 4.0, 40.0, -6.0, 15.0, 1.5, -11.0, 3.0, 8.5]) / 1000
    V = V.copy()
    V[:, 2] = lift
    return V, F, V_gt, F_gt


def test_point_to_surface_is_the_closest_point_over_every_triangle_in_mm():
    V, F, V_gt, F_gt = surfaces()
    rng = np.random.default_rng(3)
    P = np.r_[V, V_gt + [0.0, 0.0, 0.002], rng.uniform([-0.2, -0.2, -0.1], [0.5, 0.5, 0.1], (30, 3))]
    got = ev.point_to_surface_mm(P, V_gt, F_gt)
    assert got.shape == (len(P),)
    np.testing.assert_allclose(got, brute_distance_mm(P, V_gt, F_gt), rtol=1e-9, atol=1e-9)
    # a point on the surface is at 0 (the clamp of a rounding-negative square, not a shift)
    assert ev.point_to_surface_mm(V_gt[:3], V_gt, F_gt) == pytest.approx([0.0, 0.0, 0.0], abs=1e-9)


def test_point_to_surface_takes_float32_points_and_int32_faces():
    V, F, V_gt, F_gt = surfaces()
    got = ev.point_to_surface_mm(V.astype(np.float32), V_gt.astype(np.float32), F_gt.astype(np.int32))
    np.testing.assert_allclose(got, brute_distance_mm(V.astype(np.float32).astype(float), V_gt, F_gt), atol=1e-3)


def test_surface_error_pools_both_directions_and_weights_the_share_by_area():
    V, F, V_gt, F_gt = surfaces()
    to_gt, from_gt = brute_distance_mm(V, V_gt, F_gt), brute_distance_mm(V_gt, V, F)
    both = np.r_[to_gt, from_gt]
    area = barycentric_areas(V_gt, F_gt)
    share = 100.0 * sum(a for a, d in zip(area, from_gt, strict=True) if d < 10.0) / area.sum()
    assert 0 < share < 100  # some of the ground truth is farther than 10 mm, some closer
    e = ev.surface_error(V, F, V_gt, F_gt)
    assert e.median_mm == pytest.approx(np.sort(both)[len(both) // 2 - 1: len(both) // 2 + 1].mean(), abs=1e-9)
    ranked = np.sort(both)
    k = 0.9 * (len(both) - 1)  # numpy's linear percentile, by hand
    p90 = ranked[int(k)] + (k - int(k)) * (ranked[int(k) + 1] - ranked[int(k)])
    assert e.p90_mm == pytest.approx(p90, abs=1e-9)
    assert e.hausdorff_mm == pytest.approx(40.0, abs=1e-9)  # the 40 mm vertex, straight above the truth's plane
    assert e.hausdorff_mm == pytest.approx(ranked[-1], abs=1e-9)
    assert e.pct_under_10mm == pytest.approx(share, abs=1e-9)
    # without a visibility mask the visible figures are the pooled ones
    assert (e.visible_median_mm, e.visible_p90_mm) == (e.median_mm, e.p90_mm)
    d = e.as_dict()
    assert list(d) == ["median_mm", "p90_mm", "hausdorff_mm", "pct_under_10mm", "visible_median_mm",
                       "visible_p90_mm"]
    assert all(type(v) is float for v in d.values()) and d["hausdorff_mm"] == e.hausdorff_mm


def test_visible_figures_keep_the_seen_truth_and_the_reconstruction_nearest_to_it():
    V, F, V_gt, F_gt = surfaces()
    to_gt, from_gt = brute_distance_mm(V, V_gt, F_gt), brute_distance_mm(V_gt, V, F)
    visible = np.zeros(len(V_gt), bool)
    visible[[0, 1, 2, 3, 5, 6, 9, 13, 17]] = True
    nearest = [int(np.argmin(np.linalg.norm(V_gt - v, axis=1))) for v in V]
    vis = np.r_[[d for d, n in zip(to_gt, nearest, strict=True) if visible[n]], from_gt[visible]]
    assert 0 < len(vis) < len(V) + len(V_gt)
    e = ev.surface_error(V, F, V_gt, F_gt, visible=visible)
    assert e.visible_median_mm == pytest.approx(np.median(vis), abs=1e-9)
    ranked = np.sort(vis)
    k = 0.9 * (len(vis) - 1)
    assert e.visible_p90_mm == pytest.approx(ranked[int(k)] + (k - int(k)) * (ranked[int(k) + 1] - ranked[int(k)]),
                                             abs=1e-9)
    full = ev.surface_error(V, F, V_gt, F_gt)
    assert (e.median_mm, e.p90_mm, e.hausdorff_mm, e.pct_under_10mm) == \
        (full.median_mm, full.p90_mm, full.hausdorff_mm, full.pct_under_10mm)
    assert e.visible_median_mm != full.median_mm


def _camera(name, centre_x=0.0, size=101):
    """A camera at (centre_x, 0, 0) looking down +z (OpenCV: x right, y down), fx = 100 px, no distortion."""
    K = [[100.0, 0.0, 50.0], [0.0, 100.0, 50.0], [0.0, 0.0, 1.0]]
    return Camera(name, K, None, np.eye(3), [-centre_x, 0.0, 0.0], size, size)


def _square(z, half, x0=0.0, y0=0.0):
    return np.array([[x0 - half, y0 - half, z], [x0 + half, y0 - half, z], [x0 + half, y0 + half, z],
                     [x0 - half, y0 + half, z]])


def _at_pixel(u, v, z):
    """The world point camera ``_camera('a')`` sees at pixel (u, v) and depth z."""
    return [(u - 50.0) * z / 100.0, (v - 50.0) * z / 100.0, z]


@cache
def occlusion_scene():
    """A wall at depth 3 filling camera a's image, a 0.4 m square at depth 2 in front of its centre, a small
    patch at depth 0.8, and probe vertices (in no triangle) whose visibility is known by construction."""
    quads = [_square(3.0, 2.0), _square(2.0, 0.2), _square(0.8, 0.05, x0=-0.2, y0=0.2)]
    V = np.vstack(quads)
    F = np.array([[4 * q, 4 * q + 1, 4 * q + 2] for q in range(3)] + [[4 * q, 4 * q + 2, 4 * q + 3] for q in range(3)])
    probes = {  # name: (point, seen by a, seen by b)
        "wall column 0": (_at_pixel(0.2, 50, 3.0), True, False),
        "wall column W-1": (_at_pixel(100.3, 50, 3.0), True, True),
        "wall row 0": (_at_pixel(50, 0.2, 3.0), True, True),
        "wall row H-1": (_at_pixel(50, 100.3, 3.0), True, True),
        "past column W-1": (_at_pixel(100.7, 50, 3.0), False, True),
        "past row H-1": (_at_pixel(20, 100.7, 3.0), False, False),
        "left of column 0": (_at_pixel(-0.7, 50, 3.0), False, False),
        "wall behind the square": (_at_pixel(50, 50, 3.0), False, True),
        "square centre": (_at_pixel(50, 50, 2.0), True, True),
        "5 mm behind the square": (_at_pixel(52, 47, 2.005), True, True),
        "30 mm behind the square": (_at_pixel(47, 52, 2.03), False, False),
        "in front of the wall": (_at_pixel(20, 30, 2.5), True, False),
        "behind the wall": (_at_pixel(20, 30, 3.5), False, False),
        "half a metre from the camera": (_at_pixel(75, 20, 0.5), True, False),
        "on the near patch": (_at_pixel(25, 75, 0.8), True, False),
        "behind the camera": ([0.0, 0.0, -1.0], False, False),
        # camera b sees no surface at its pixel (95, 50): an empty pixel's depth 0 is no surface, however near
        "5 mm from camera b, nothing behind": ([1.0 + 45 * 0.005 / 100, 0.0, 0.005], False, False),
    }
    P = np.array([p for p, _, _ in probes.values()])
    return np.r_[V, P], F, len(V), probes


def test_visible_vertices_z_buffer_test_in_one_camera():
    V, F, n_mesh, probes = occlusion_scene()
    seen = ev.visible_vertices(V, F, [_camera("a")])
    assert seen.dtype == bool and seen.shape == (len(V),)
    got = dict(zip(probes, seen[n_mesh:].tolist(), strict=True))
    assert got == {k: a for k, (_, a, _) in probes.items()}
    # tighter tolerance: 5 mm behind the square is hidden
    tight = ev.visible_vertices(V, F, [_camera("a")], tolerance_m=0.001)
    assert dict(zip(probes, tight[n_mesh:].tolist(), strict=True)) == \
        {k: a and k != "5 mm behind the square" for k, (_, a, _) in probes.items()}


def test_visible_vertices_is_the_union_over_cameras():
    V, F, n_mesh, probes = occlusion_scene()
    b = _camera("b", centre_x=1.0)
    only_b = ev.visible_vertices(V, F, [b])
    assert dict(zip(probes, only_b[n_mesh:].tolist(), strict=True)) == {k: s for k, (_, _, s) in probes.items()}
    for order in ([_camera("a"), b], [b, _camera("a")]):
        both = ev.visible_vertices(V, F, order)
        assert dict(zip(probes, both[n_mesh:].tolist(), strict=True)) == \
            {k: a or s for k, (_, a, s) in probes.items()}
    assert not ev.visible_vertices(V, F, []).any()


def test_silhouette_iou_counts_pixels_per_view():
    V, F, n_mesh, _ = occlusion_scene()
    V, F = V[4:8], np.array([[0, 1, 2], [0, 2, 3]])  # the 0.4 m square alone: pixels 40-60 in camera a
    a, b = _camera("a"), _camera("b", centre_x=0.25)
    ref_a = np.zeros((101, 101), np.uint8)
    ref_a[45:70, 30:55] = 1  # a 0 / 1 mask: 1 is foreground
    ref_b = np.zeros((101, 101))
    ref_b[10:20, 10:20] = 0.5  # any positive value is foreground
    ref_b[0:5, :] = -1.0  # negative is background
    out = ev.silhouette_iou(V, F, [a, b], {"a": ref_a, "b": ref_b, "unused": None})
    assert list(out) == ["a", "b"]
    for cam, ref in ((a, ref_a), (b, ref_b)):
        mine = silhouette_mask(V, F, cam)
        inter = union = 0
        for i in range(101):
            for j in range(101):
                inter += bool(mine[i, j]) and ref[i, j] > 0
                union += bool(mine[i, j]) or ref[i, j] > 0
        assert type(out[cam.name]) is float and out[cam.name] == pytest.approx(inter / union, abs=1e-12)
    assert 0.1 < out["a"] < 0.9 and out["b"] == 0.0
    # nothing seen and nothing in the mask: a perfect 1, not a division by zero
    away = Camera("away", _camera("x").K, None, np.eye(3), [0.0, 0.0, -10.0], 101, 101)
    assert ev.silhouette_iou(V - [0, 0, 20.0], F, [away], {"away": np.zeros((101, 101))}) == {"away": 1.0}


BONES = ("Root", "pelvis", "spine_01", "head", "neck_01", "upperarm_l", "lowerarm_r", "hand_l", "index_01_l",
         "thumb_02_r", "pinky_03_l", "middle_01_r", "ring_02_l", "thigh_l", "thigh_r", "calf_l", "foot_r", "ball_l",
         "breast_l", "clavicle_r")


@cache
def stand_in_body():
    """A body stand-in: bones (some of REGIONS' missing, e.g. spine_02, hand_r), hips at (+-0.1, 1, 0) and
    vertices on a grid around them with random skin weights."""
    rng = np.random.default_rng(5)
    heads = rng.normal(size=(len(BONES), 3))
    heads[BONES.index("thigh_l")] = [0.13, 1.0, 0.02]
    heads[BONES.index("thigh_r")] = [-0.09, 1.0, -0.02]  # hips' midpoint (0.02, 1.0, 0)
    g = np.linspace(-0.16, 0.16, 9)
    V = np.array([[0.02 + x, 1.0 + y, z] for x in g for y in g for z in (-0.04, 0.03)])
    W = rng.random((len(V), len(BONES))) ** 8
    return SimpleNamespace(vertices=V, weights=W, skeleton=SimpleNamespace(bone_names=BONES, heads=heads))


def reference_regions(body):
    out = []
    hips = 0.5 * (body.skeleton.heads[BONES.index("thigh_l")] + body.skeleton.heads[BONES.index("thigh_r")])
    for v, w in zip(body.vertices, body.weights, strict=True):
        bone = BONES[int(np.argmax(w))]
        region = "other"
        for r, bones in ev.REGIONS.items():
            if bone in bones:
                region = r
        if bone.split("_")[0] in ("index", "middle", "pinky", "ring", "thumb"):
            region = "hands"
        if np.linalg.norm(v - hips) < 0.12 and v[1] < hips[1] and abs(v[0] - hips[0]) < 0.06:
            region = "crotch"
        out.append(region)
    return np.array(out, dtype=object)


def test_vertex_regions_follow_the_dominant_bone_and_the_crotch_ball():
    body = stand_in_body()
    got = ev.vertex_regions(body)
    want = reference_regions(body)
    assert got.dtype == object and got.tolist() == want.tolist()
    names = set(want.tolist())
    assert {"head", "torso", "arms", "hands", "legs", "feet", "crotch", "other"} <= names
    assert 5 < (want == "crotch").sum() < 40
    # every finger family and a hand bone count as hands
    hands = {BONES[int(np.argmax(w))] for w, r in zip(body.weights, want, strict=True) if r == "hands"}
    assert {"hand_l", "index_01_l", "thumb_02_r", "pinky_03_l", "middle_01_r", "ring_02_l"} <= hands


def test_region_errors_are_per_region_median_p90_and_count():
    V, F, V_gt, F_gt = surfaces()
    regions = np.array(["torso", "legs", "crotch", "torso", "legs", "torso", "legs", "legs", "head", "torso",
                        "torso", "legs", "torso", "head", "legs", "torso"], dtype=object)
    d = brute_distance_mm(V, V_gt, F_gt)
    out = ev.region_errors(V, V_gt, F_gt, regions)
    assert list(out) == ["crotch", "head", "legs", "torso"]
    for r, entry in out.items():
        sel = [x for x, name in zip(d, regions, strict=True) if name == r]
        ranked = np.sort(sel)
        k = 0.9 * (len(sel) - 1)
        p90 = ranked[int(k)] + (k - int(k)) * (ranked[min(int(k) + 1, len(sel) - 1)] - ranked[int(k)])
        assert entry == pytest.approx({"median_mm": float(np.median(sel)), "p90_mm": p90, "n_vertices": len(sel)},
                                      abs=1e-9)
        assert type(entry["n_vertices"]) is int and type(entry["median_mm"]) is float


def test_joint_error_is_the_mean_over_joints_finite_in_both():
    J_gt = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.5, 0.2, 0.1], [2.0, 0.0, 0.0], [0.0, 3.0, 0.0]])
    J = J_gt + np.array([[0.003, 0.004, 0.0], [0.0, 0.0, 0.01], [np.nan, 0, 0], [0.0, 0.02, 0.0], [0, 0, 0]])
    J_gt = J_gt.copy()
    J_gt[4, 1] = np.inf
    # joints 0, 1, 3: 5, 10 and 20 mm
    assert ev.joint_error_mm(J, J_gt) == pytest.approx((5.0 + 10.0 + 20.0) / 3, abs=1e-9)
    assert ev.joint_error_mm(J_gt[[0, 1, 3]], J[[0, 1, 3]]) == pytest.approx(35.0 / 3, abs=1e-9)
    assert np.isnan(ev.joint_error_mm(J[[2]], J_gt[[2]]))
    assert np.isnan(ev.joint_error_mm(J[[2, 4]], J_gt[[2, 4]]))
    assert type(ev.joint_error_mm(J, J_gt)) is float
