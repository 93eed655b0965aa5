"""Fast, exact checks of bodystudio/mirror/shape_refine.py (issue 17: its mutants).

tests/mirror/test_shape_refine_analytic.py checks the whole refinement on a planted shape (seconds per test);
these check each piece against what it must equal, in well under a second each on the 2k model:

* the projection Jacobian and the pose Jacobian against finite differences of the projection and of the
  skinned body turned by :func:`mirror.refine.apply_update` (the parameters of ``refine_pose``);
* one frame's rows: the depth residuals of points planted at a known distance along the vertex normals
  (Eq. 2 in the posed frame: point-to-plane, scaled by ``1 / (depth_m sqrt(N))``) and their rows
  ``n . dV/dc``; ``E_out``'s residuals and rows against a whole-image distance transform sampled by scipy;
  ``E_cover``'s residuals against the outline pixels and the projected rim;
* the Gauss-Newton step of :func:`refine_shape_to_silhouettes` with stand-in rows that are linear in the
  shape and in each frame's pose change: the step must be the minimiser of the energy of the module docstring
  (data terms averaged over the frames, each frame's pose change damped, the Gaussian prior, the stature and
  mass holds), found here by one stacked least-squares solve instead of the Schur complement;
* :func:`frame_pose`'s wiring (the IK on the shape's skeleton, then two refinement steps on the frame's data).
"""

import cv2
import numpy as np
import pytest
from scipy.ndimage import map_coordinates
from scipy.spatial.transform import Rotation

import bodystudio.mirror.shape_refine as sr
from bodystudio.body import Pose
from bodystudio.geometry.camera import Camera, pinhole_projection_jacobian
from bodystudio.geometry.mesh import vertex_normals
from bodystudio.mirror.refine import (
    _bone_frames,
    _descendants,
    _forward_kinematics,
    apply_update,
    mask_box,
    mask_outline,
    refine_plan,
)
from bodystudio.mirror.track import posed_kinect_joints, skin_vertices


def _case():
    from bodystudio.body.statistical import load_statistical_model

    m = load_statistical_model("2k", progress=False)
    rng = np.random.default_rng(2)
    c = rng.normal(0, 0.6, m.n_components) * m.stddev
    sk = m.skeleton(c)
    rot = rng.normal(0, 0.06, (sk.n_bones, 3))
    for arm, sign in (("upperarm_l", 1), ("upperarm_r", -1)):
        rot[sk.index(arm)] = Rotation.from_euler("z", sign * 0.5).as_rotvec()
    pose = Pose(rot, np.array([0.05, 0.0, -0.05]))
    camera = Camera.look_at("kinect", eye=(0.3, 1.0, 2.6), target=(0.0, 0.95, 0.0), fx=525.0)
    V = skin_vertices(m.vertices(c), m.weights, sk, pose)
    mask = np.zeros((camera.height, camera.width), np.uint8)
    for tri in np.round(camera.project(V)[m.faces] * 16).astype(np.int32):
        cv2.fillConvexPoly(mask, tri, 1, lineType=cv2.LINE_8, shift=4)
    return m, c, pose, camera, V, mask.astype(bool)


@pytest.fixture(scope="module")
def case():
    return _case()


def _view(mask, points, joints=None, others=None):
    return sr.SilhouetteView(mask, others, points, np.zeros((25, 3)) if joints is None else joints,
                             np.ones(25, bool), "v2")


def test_image_jacobian_is_the_derivative_of_the_projection():
    camera = Camera.look_at("kinect", eye=(0.3, 1.0, 2.6), target=(0.0, 0.95, 0.0), fx=525.0, fy=540.0)
    rng = np.random.default_rng(0)
    V = rng.uniform(-0.5, 0.5, (50, 3)) + [0.0, 1.0, 0.0]
    J = rng.normal(0, 1.0, (50, 3, 4))
    Ju = pinhole_projection_jacobian(camera, V, J)
    assert Ju.shape == (50, 2, 4)
    for k in range(4):
        h = 1e-6
        fd = (camera.project(V + h * J[:, :, k]) - camera.project(V - h * J[:, :, k])) / (2 * h)
        np.testing.assert_allclose(Ju[:, :, k], fd, rtol=1e-5, atol=1e-4)


def test_pose_jacobian_is_the_derivative_of_the_skinned_body_under_apply_update(case):
    m, c, pose, camera, V, _ = case
    sk = m.skeleton(c)
    plan = refine_plan(m.vertices(c), m.faces, m.weights, sk)
    ids = np.arange(0, len(V), 5)
    J = sr.pose_jacobian(plan, sk, pose, V[ids], m.weights[ids])
    S = len(plan.bones) - 1
    assert J.shape == (len(ids), 3, 6 + 2 * S)
    M, _ = _forward_kinematics(plan, sk.parents, pose)
    world, _, axes = _bone_frames(M, np.ascontiguousarray(sk.rest_rotations), plan.bones)
    inside = np.stack([_descendants(np.asarray(sk.parents), j) for j in plan.bones], axis=1).astype(float)
    s = m.weights[ids] @ inside
    col = [0] * 6 + [1 + b // 2 for b in range(2 * S)]
    h = 1e-6
    for p in [0, 1, 2, 3, 4, 5] + list(range(6, 6 + 2 * S, 3)) + [6 + 2 * S - 1]:
        delta = np.zeros(6 + 2 * S)
        delta[p] = h
        Vp = skin_vertices(m.vertices(c), m.weights, sk, apply_update(sk, pose, delta, plan.bones, axes, world))[ids]
        delta[p] = -h
        Vm = skin_vertices(m.vertices(c), m.weights, sk, apply_update(sk, pose, delta, plan.bones, axes, world))[ids]
        fd = (Vp - Vm) / (2 * h)
        # exact where the vertex is skinned wholly inside or outside the turned subtree (LBS is linear in the
        # bone transforms); a blended vertex turns about the head as its blend does, to first order
        whole = (np.abs(s[:, col[p]]) < 1e-9) | (np.abs(s[:, col[p]] - 1) < 1e-9)
        assert whole.sum() > 0.8 * len(ids)
        np.testing.assert_allclose(J[whole, :, p], fd[whole], atol=2e-6, err_msg=f"parameter {p}")
        assert np.abs(J[:, :, p] - fd).max() < 0.05 * np.abs(fd).max() + 1e-9


def test_the_depth_rows_are_point_to_plane_distances_scaled_by_the_sample_count(case):
    m, c, pose, camera, V, mask = case
    N = vertex_normals(V, m.faces)
    ray = V - camera.center
    cos = np.einsum("ij,ij->i", N, ray) / np.linalg.norm(ray, axis=1)
    # points 3 mm in front of every other vertex that faces the sensor by more than the limit (the subset's)
    ids = np.flatnonzero((np.arange(len(V)) % 2 == 0) & (cos < -0.5))
    points = V[ids] + 0.003 * N[ids]
    w = sr.ShapeWeights(sil_weight=0.0, depth_m=0.02, depth_weight=4.0, depth_samples=10 ** 6)
    big = np.ones_like(mask)  # every body point inside: no E_out rows; the outline is the image's border
    A, r = sr.silhouette_shape_rows(m, c, pose, camera, _view(big, points), w)
    assert A.shape == (len(r), m.n_components)
    s = 4.0 ** 0.5 / (0.02 * len(points) ** 0.5)
    depth = r[-len(ids):]
    np.testing.assert_allclose(depth, -0.003 * s, rtol=1e-6)  # n . (V - p) = -3 mm on every point
    _, J = sr.posed_shape_jacobian(m, c, pose, ids)
    np.testing.assert_allclose(A[-len(ids):], s * np.einsum("nd,ndk->nk", N[ids], J), rtol=1e-6, atol=1e-9)
    # the sample cap draws depth_samples of them; a tighter facing limit takes fewer vertices
    w2 = sr.ShapeWeights(sil_weight=0.0, depth_samples=100)
    _, r2 = sr.silhouette_shape_rows(m, c, pose, camera, _view(big, points), w2)
    assert np.sum(np.abs(r2 + 0.003 / (0.01 * 10.0)) < 1e-9) == 100
    w3 = sr.ShapeWeights(sil_weight=0.0, depth_samples=10 ** 6, min_facing_cos=0.9)
    _, r3 = sr.silhouette_shape_rows(m, c, pose, camera, _view(big, points), w3)
    assert 0 < np.sum(np.abs(r3) > 1e-12) < 0.8 * len(ids)


def _expected_out(m, c, pose, camera, V, fg):
    """E_out by hand: every other vertex projecting inside the image (1 px in) onto a pixel more than 0.5 px
    outside ``fg`` (whole-image distance transform, bilinear), its residual min(d, 30) and its gradient."""
    dist = cv2.distanceTransform((~fg).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5).astype(np.float64)
    uv = camera.project(V)
    sub = np.arange(len(V)) % 2 == 0
    ok = sub & (uv[:, 0] >= 1) & (uv[:, 0] <= camera.width - 2) & (uv[:, 1] >= 1) & (uv[:, 1] <= camera.height - 2)
    # within the mask's box grown by 40 px (farther points have no gradient there and are left out)
    y0, y1, x0, x1 = mask_box(fg, 40)
    ok &= (uv[:, 0] >= x0 + 1) & (uv[:, 1] >= y0 + 1) & (uv[:, 0] < x1 - 2) & (uv[:, 1] < y1 - 2)

    def at(p):
        return map_coordinates(dist, [p[:, 1], p[:, 0]], order=1, mode="nearest")

    d = np.zeros(len(V))
    d[ok] = at(uv[ok])
    out = np.flatnonzero(ok & (d > 0.5))
    p = uv[out]
    grad = np.c_[at(p + [1, 0]) - at(p - [1, 0]), at(p + [0, 1]) - at(p - [0, 1])] / 2.0
    return out, np.minimum(d[out], 30.0), grad


def test_the_outside_rows_pull_points_down_the_distance_transform(case):
    m, c, pose, camera, V, mask = case
    # the person's mask shrunk by 6 px and cut at the thighs: points 0.5..30 px outside and farther than 30 px
    fg = cv2.erode(mask.astype(np.uint8), np.ones((13, 13), np.uint8)).astype(bool)
    uv = camera.project(V)
    fg[int(np.percentile(uv[:, 1], 80)):] = False
    out, d, grad = _expected_out(m, c, pose, camera, V, fg)
    assert np.sum(d >= 30.0) > 20 and np.sum(d < 10) > 50
    w = sr.ShapeWeights(depth_weight=0.0, sil_weight=9.0, sil_px=3.0)
    A, r = sr.silhouette_shape_rows(m, c, pose, camera, _view(fg, np.zeros((0, 3))), w)
    n_outline = len(mask_outline(fg))
    s = 3.0 / (3.0 * max(len(out), min(n_outline, 800)) ** 0.5)
    np.testing.assert_allclose(r[:len(out)], s * d, rtol=1e-4, atol=1e-4 * s)
    _, J = sr.posed_shape_jacobian(m, c, pose, out)
    rows = s * np.einsum("nd,ndk->nk", grad, pinhole_projection_jacobian(camera, V[out], J))
    np.testing.assert_allclose(A[:len(out)], rows, rtol=1e-3, atol=1e-3 * np.abs(rows).max())


def test_the_cover_rows_pull_outline_pixels_onto_the_rim_along_its_normal(case):
    m, c, pose, camera, V, mask = case
    # the person's mask moved 4 px right: the outline lies ~4 px off the projected rim, along x
    fg = np.zeros_like(mask)
    fg[:, 4:] = mask[:, :-4]
    outline = mask_outline(fg)
    w = sr.ShapeWeights(depth_weight=0.0, sil_samples=10 ** 6)
    A, r = sr.silhouette_shape_rows(m, c, pose, camera, _view(fg, np.zeros((0, 3))), w)
    out, _, _ = _expected_out(m, c, pose, camera, V, fg)
    cover = r[len(out):] * 2.0 * len(outline) ** 0.5  # pixels
    assert 0.5 * len(outline) < len(cover) <= len(outline)
    assert np.all(np.abs(cover) <= 25.0 + 1e-9)
    assert 2.0 < np.median(np.abs(cover)) < 6.0, np.median(np.abs(cover))
    # with the outline where the body projects, the residuals are the rasterisation's (~1 px)
    A0, r0 = sr.silhouette_shape_rows(m, c, pose, camera, _view(mask, np.zeros((0, 3))), w)
    assert np.median(np.abs(r0)) * 2.0 * len(mask_outline(mask)) ** 0.5 < 1.5
    # the rows: one Gauss-Newton step of E_cover alone in the shape moves the outline's residual down
    step = np.linalg.lstsq(A[len(out):], -r[len(out):], rcond=None)[0]
    assert np.linalg.norm(A[len(out):] @ step + r[len(out):]) < 0.8 * np.linalg.norm(r[len(out):])
    assert A.shape[1] == m.n_components


def test_with_a_plan_the_rows_carry_the_pose_columns(case):
    m, c, pose, camera, V, mask = case
    sk = m.skeleton(c)
    plan = refine_plan(m.vertices(c), m.faces, m.weights, sk)
    N = vertex_normals(V, m.faces)
    ray = V - camera.center
    cos = np.einsum("ij,ij->i", N, ray) / np.linalg.norm(ray, axis=1)
    ids = np.flatnonzero((np.arange(len(V)) % 2 == 0) & (cos < -0.5))
    points = V[ids] + 0.003 * N[ids]
    w = sr.ShapeWeights(sil_weight=0.0, depth_samples=10 ** 6)
    A, r = sr.silhouette_shape_rows(m, c, pose, camera, _view(np.ones_like(mask), points), w, plan=plan)
    k = m.n_components
    assert A.shape == (len(r), k + 6 + 2 * (len(plan.bones) - 1))
    s = 1.0 / (0.01 * len(points) ** 0.5)
    Jp = sr.pose_jacobian(plan, sk, pose, V[ids], m.weights[ids])
    np.testing.assert_allclose(A[-len(ids):, k:], s * np.einsum("nd,ndk->nk", N[ids], Jp), rtol=1e-6, atol=1e-9)
    # no data at all: no rows, the right number of columns
    A0, r0 = sr.silhouette_shape_rows(m, c, pose, camera, _view(np.ones_like(mask), np.zeros((0, 3))),
                                      sr.ShapeWeights(), plan=plan)
    assert A0.shape == (0, A.shape[1]) and r0.shape == (0,)


# --- the Gauss-Newton step with stand-in rows ----------------------------------------------------------------

def _stand_in(monkeypatch, m, F, P, seed=0):
    """Rows linear in the shape and the pose change: frame f's residual ``Ac_f (c - a_f) + r0_f`` (pose
    columns ``Ap_f`` when a plan is given); records every call."""
    rng = np.random.default_rng(seed)
    k = m.n_components
    data = [(rng.normal(0, 1, (40, k)) / m.stddev, rng.normal(0, 1, (40, P)), rng.normal(0, 0.5, k) * m.stddev,
             rng.normal(0, 0.1, 40)) for _ in range(F)]
    calls = {"pose": [], "rows": [], "plan": []}

    def frame_pose(model, coeffs, camera, view, previous=None, plan=None):
        assert model is m and camera == "camera" and view is not None
        calls["pose"].append((np.array(coeffs), view, previous, plan))
        return ("pose", len(calls["pose"]))

    def rows(model, coeffs, pose, camera, view, weights, seed=0, plan=None):
        assert model is m and camera == "camera" and view is calls["pose"][-1][1]
        calls["rows"].append((np.array(coeffs), pose, view, seed, plan))
        Ac, Ap, a, r0 = data[seed]
        r = Ac @ (coeffs - a) + r0
        return (np.c_[Ac, Ap] if plan is not None else Ac), r

    def plan_of(vertices, faces, weights, skeleton, version):
        assert faces is m.faces and weights is m.weights
        calls["plan"].append((vertices, skeleton, version))
        return ("plan", len(calls["plan"]))

    monkeypatch.setattr(sr, "frame_pose", frame_pose)
    monkeypatch.setattr(sr, "silhouette_shape_rows", rows)
    monkeypatch.setattr(sr, "refine_plan", plan_of)
    return data, calls


def _minimiser(m, c, c0, data, w, joint):
    """The step minimising the linearised energy at ``c``: one stacked least-squares solve over the shape step
    and every frame's pose change (no Schur complement)."""
    k, F = m.n_components, len(data)
    P = data[0][1].shape[1] if joint else 0
    blocks, rhs = [], []
    for f, (Ac, Ap, a, r0) in enumerate(data):
        row = np.zeros((len(r0), k + F * P))
        row[:, :k] = Ac
        if joint:
            row[:, k + f * P:k + (f + 1) * P] = Ap
        blocks.append(row / F ** 0.5)
        rhs.append(-(Ac @ (c - a) + r0) / F ** 0.5)
        if joint:
            damp = np.zeros((P, k + F * P))
            d = np.r_[np.full(3, 1 / w.pose_prior_m), np.full(P - 3, 1 / w.pose_prior_rad)]
            damp[:, k + f * P:k + (f + 1) * P] = np.diag(d) / F ** 0.5
            blocks.append(damp)
            rhs.append(np.zeros(P))
    prior = np.zeros((k, k + F * P))
    prior[:, :k] = np.diag(w.prior ** 0.5 / m.stddev)
    blocks.append(prior)
    rhs.append(-w.prior ** 0.5 * c / m.stddev)
    if w.stature_mm:
        s = m.coeffs_to_attribute_map[:-1, m.attribute_names.index("stature_m")]
        row = np.zeros((1, k + F * P))
        row[0, :k] = s / (1e-3 * w.stature_mm)
        blocks.append(row)
        rhs.append([-(s @ (c - c0)) / (1e-3 * w.stature_mm)])
    if w.mass_kg:
        mass, grad = sr.mass_and_gradient(m, c)
        row = np.zeros((1, k + F * P))
        row[0, :k] = grad / w.mass_kg
        blocks.append(row)
        rhs.append([-(mass - sr.mass_and_gradient(m, c0)[0]) / w.mass_kg])
    x = np.linalg.lstsq(np.vstack(blocks), np.concatenate(rhs), rcond=None)[0]
    return x[:k]


@pytest.mark.parametrize("weights", [
    sr.ShapeWeights(stature_mm=0.0, mass_kg=0.0, max_step_sigma=100.0),
    sr.ShapeWeights(max_step_sigma=100.0),
    sr.ShapeWeights(stature_mm=0.0, mass_kg=0.0, joint_pose=False, max_step_sigma=100.0),
    sr.ShapeWeights(prior=0.3, pose_prior_m=0.05, pose_prior_rad=0.2, stature_mm=5.0, mass_kg=0.0,
                    max_step_sigma=100.0),
    sr.ShapeWeights(stature_mm=0.0, mass_kg=2.0, max_step_sigma=100.0),
], ids=["free", "holds", "shape alone", "tight priors and stature", "mass"])
def test_one_step_is_the_minimiser_of_the_linearised_energy(case, monkeypatch, weights):
    m = case[0]
    F, P = 3, 6 + 2 * 19
    data, calls = _stand_in(monkeypatch, m, F, P)
    c0 = case[1].copy()
    views = [_view(None, None) for _ in range(F)]
    c1 = sr.refine_shape_to_silhouettes(m, c0, views, "camera", iterations=1, weights=weights)
    expected = c0 + _minimiser(m, c0, c0, data, weights, weights.joint_pose)
    np.testing.assert_allclose(c1, expected, rtol=1e-7, atol=1e-9 * np.abs(expected).max())
    assert np.abs(c1 - c0).max() > 1e-3 * np.abs(c0).max()  # the step moves
    # wiring: every frame posed (no previous pose yet) and its rows taken with its own seed and the plan
    assert [call[2] for call in calls["pose"]] == [None] * F
    assert [call[1] for call in calls["pose"]] == [view for view in views]
    assert [call[3] for call in calls["rows"]] == list(range(F))
    assert [call[1] for call in calls["rows"]] == [("pose", f + 1) for f in range(F)]
    assert all(call[3] == ("plan", 1) for call in calls["pose"])
    assert all(call[4] == (("plan", 1) if weights.joint_pose else None) for call in calls["rows"])
    vertices, skeleton, version = calls["plan"][0]
    np.testing.assert_allclose(vertices, m.vertices(c0))
    np.testing.assert_allclose(skeleton.heads, m.skeleton(c0).heads)
    assert version == "v2"


def test_the_second_step_starts_from_the_first_with_the_previous_poses(case, monkeypatch, caplog):
    import logging

    m = case[0]
    w = sr.ShapeWeights(max_step_sigma=100.0)
    data, calls = _stand_in(monkeypatch, m, 2, 44)
    c0 = case[1].copy()
    views = [_view(None, None) for _ in range(2)]
    with caplog.at_level(logging.DEBUG, logger="bodystudio.mirror.shape_refine"):
        c2 = sr.refine_shape_to_silhouettes(m, c0, views, "camera", iterations=2, weights=w)
    steps = [r.getMessage() for r in caplog.records if r.name == "bodystudio.mirror.shape_refine"]
    largest = np.max(np.abs(_minimiser(m, c0, c0, data, w, True)) / m.stddev)
    assert len(steps) == 2 and steps[0] == f"shape step 0: largest change {largest:.2f} sigma", steps
    assert steps[1].startswith("shape step 1: largest change ")
    c1 = c0 + _minimiser(m, c0, c0, data, w, True)
    np.testing.assert_allclose(c2, c1 + _minimiser(m, c1, c0, data, w, True), rtol=1e-7,
                               atol=1e-9 * np.abs(c1).max())
    assert [call[2] for call in calls["pose"]] == [None, None, ("pose", 1), ("pose", 2)]
    np.testing.assert_allclose(calls["rows"][2][0], c1, rtol=1e-9, atol=1e-12 * np.abs(c1).max())
    np.testing.assert_allclose(calls["plan"][1][0], m.vertices(c1))
    assert len(calls["plan"]) == 2
    # the default: SHAPE_ITERATIONS steps; no views or no steps: the start
    calls["plan"].clear()
    sr.refine_shape_to_silhouettes(m, c0, views, "camera", weights=w)
    assert len(calls["plan"]) == sr.SHAPE_ITERATIONS == 3
    np.testing.assert_array_equal(sr.refine_shape_to_silhouettes(m, c0, [], "camera"), c0)
    np.testing.assert_array_equal(sr.refine_shape_to_silhouettes(m, c0, views, "camera", iterations=0), c0)


def test_a_step_is_capped_at_max_step_sigma(case, monkeypatch):
    m = case[0]
    data, _ = _stand_in(monkeypatch, m, 2, 44, seed=3)
    c0 = case[1].copy()
    free = sr.ShapeWeights(stature_mm=0.0, mass_kg=0.0, max_step_sigma=100.0, prior=1e-6)
    views = [_view(None, None) for _ in range(2)]
    step = sr.refine_shape_to_silhouettes(m, c0, views, "camera", iterations=1, weights=free) - c0
    largest = np.max(np.abs(step) / m.stddev)
    assert largest > 0.5
    for cap in (0.1, 0.5 * largest):
        capped = sr.refine_shape_to_silhouettes(m, c0, views, "camera", iterations=1, weights=sr.ShapeWeights(
            stature_mm=0.0, mass_kg=0.0, max_step_sigma=cap, prior=1e-6)) - c0
        np.testing.assert_allclose(capped, step * cap / largest, rtol=1e-9)
    assert sr.ShapeWeights().max_step_sigma == 1.0


def test_frame_pose_is_the_ik_on_the_shapes_skeleton_then_two_refinement_steps(case, monkeypatch):
    m, c, pose, camera, V, mask = case
    sk = m.skeleton(c)
    joints = posed_kinect_joints(sk, pose)
    tracked = np.ones(25, bool)
    tracked[3] = False
    points = V[::7]
    others = np.zeros_like(mask)
    view = sr.SilhouetteView(mask, others, points, joints, tracked, "v2")
    seen = {}

    def ik(skeleton, kinect_positions, tracked, version, previous=None):
        seen["ik"] = (skeleton, kinect_positions, tracked, version, previous)
        return "ik pose"

    def refine(*args, **kwargs):
        seen["refine"] = (args, kwargs)
        return "refined"

    monkeypatch.setattr(sr, "ik_pose", ik)
    monkeypatch.setattr(sr, "refine_pose", refine)
    assert sr.frame_pose(m, c, camera, view, previous="last", plan="the plan") == "refined"
    skeleton, kp, tr, version, previous = seen["ik"]
    np.testing.assert_allclose(skeleton.heads, sk.heads)
    assert kp is joints and tr is tracked and version == "v2" and previous == "last"
    args, kwargs = seen["refine"]
    assert args[0] == "the plan" and args[2] == "ik pose" and args[3] is camera and args[4] is mask
    np.testing.assert_allclose(args[1].heads, sk.heads)
    assert args[5] is joints and args[6] is tracked and args[7] is points and args[8] is others and args[9] == "v2"
    assert kwargs == {"iterations": 2}
    # without a plan, the shape's own, for the view's Kinect version
    from bodystudio.body.kinect import kinect_joint_names

    sr.frame_pose(m, c, camera, sr.SilhouetteView(mask, others, points, joints[:20], tracked[:20], "v1"))
    plan = seen["refine"][0][0]
    assert plan.joint_moves.shape[0] == len(kinect_joint_names("v1")) == 20
    ref = refine_plan(m.vertices(c), m.faces, m.weights, sk)
    np.testing.assert_allclose(plan.rest_vertices, ref.rest_vertices)
    np.testing.assert_array_equal(plan.bones, ref.bones)
    assert seen["ik"][4] is None


def test_the_shape_jacobian_and_the_mass_gradient_are_the_derivatives(case):
    m, c, pose, *_ = case
    ids = np.arange(0, len(m.mean), 53)
    V0, J = sr.posed_shape_jacobian(m, c, pose, ids)
    np.testing.assert_allclose(V0, skin_vertices(m.vertices(c), m.weights, m.skeleton(c), pose)[ids], atol=1e-12)
    mass, grad = sr.mass_and_gradient(m, c)
    for k in (0, 7, m.n_components - 1):
        h = 1e-3 * m.stddev[k]
        cp, cm = c.copy(), c.copy()
        cp[k] += h
        cm[k] -= h
        Vp = skin_vertices(m.vertices(cp), m.weights, m.skeleton(cp), pose, subset=ids)
        Vm = skin_vertices(m.vertices(cm), m.weights, m.skeleton(cm), pose, subset=ids)
        # forward differences of 1e-3 sigma: the skinning is nearly linear in the shape
        np.testing.assert_allclose(J[:, :, k], (Vp - Vm) / (2 * h), atol=1e-3 * np.abs(J[:, :, k]).max())
        dm = (sr.mass_and_gradient(m, cp)[0] - sr.mass_and_gradient(m, cm)[0]) / (2 * h)
        assert abs(grad[k] - dm) < 1e-4 * abs(dm) + 1e-6, (k, grad[k], dm)
    # the enclosed volume (divergence theorem) of the open template, times the density: the measured mass
    assert abs(mass - m.measure(c)["mass_kg"]) < 3.0, (mass, m.measure(c)["mass_kg"])


def test_other_players_pixels_allow_body_points_and_keep_the_outline_away(case):
    """Another player over part of the person: a body point projecting onto him may be occluded (no E_out row),
    and the person's outline next to him is not drawn by the body (no E_cover row there)."""
    m, c, pose, camera, V, mask = case
    fg = cv2.erode(mask.astype(np.uint8), np.ones((13, 13), np.uint8)).astype(bool)
    ys, xs = np.nonzero(mask)
    others = np.zeros_like(mask)
    others[ys.min():ys.min() + 120, xs.min() - 5:(xs.min() + xs.max()) // 2] = True
    fg &= ~others
    w = sr.ShapeWeights(depth_weight=0.0, sil_samples=10 ** 6)
    _, r = sr.silhouette_shape_rows(m, c, pose, camera, _view(fg, np.zeros((0, 3)), others=others), w)
    out, d, _ = _expected_out(m, c, pose, camera, V, fg | others)
    outline = mask_outline(fg, others)
    assert 0 < len(outline) < len(mask_outline(fg)) and len(out) < len(_expected_out(m, c, pose, camera, V, fg)[0])
    s = 1.0 / (2.0 * max(len(out), len(outline)) ** 0.5)
    np.testing.assert_allclose(r[:len(out)], s * d, rtol=1e-4, atol=1e-4 * s)
    cover = r[len(out):]
    assert 0.5 * len(outline) < len(cover) <= len(outline)
