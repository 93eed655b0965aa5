"""Fast checks of the pieces of bodystudio/mirror/refine.py that its reference comparison shares (issue 17).

tests/mirror/test_pose_refine_analytic.py pins the fast refinement to MIR12b's numpy implementation
(tests/mirror/refine_reference.py), but both read the same plan (:func:`refine_plan`), the same distance
transform (:func:`silhouette_distance`) and the same bilinear sampler (:func:`_sample`): a bug there moves both
alike. These pin each of them to its definition: the plan's subset, skin weights, subtree weights and Kinect joint
moves computed from the skeleton by hand; its cached rest products against the body's own forward kinematics;
the distance transform against OpenCV's over the whole image; the sampler against scipy's bilinear interpolation;
:func:`apply_update`'s turns as exact rigid motions of the posed skeleton.
"""

import cv2
import numpy as np
import pytest
from scipy.ndimage import map_coordinates
from scipy.spatial.transform import Rotation

from bodystudio.body import Phenotype, Pose, build_body
from bodystudio.body.kinect import KINECT_JOINT_SETS, kinect_joint_names
from bodystudio.body.skinning import posed_joints, skinning_transforms
from bodystudio.errors import InputError
from bodystudio.geometry.mesh import vertex_normals
from bodystudio.mirror import refine as rf


def _body():
    return build_body(Phenotype(), resolution="2k")


@pytest.fixture(scope="module")
def body():
    return _body()


def _pose(sk, seed=4):
    rng = np.random.default_rng(seed)
    return Pose(rng.normal(0, 0.3, (sk.n_bones, 3)), np.array([0.1, -0.05, 0.2]))


def _subtree(parents, j):
    """Bones whose chain of parents reaches ``j`` (j included), by walking up from each bone."""
    out = set()
    for b in range(len(parents)):
        a = b
        while a >= 0:
            if a == j:
                out.add(b)
                break
            a = parents[a]
    return out


def test_the_plan_is_its_definition(body):
    sk = body.skeleton
    plan = rf.refine_plan(body.vertices, body.faces, body.weights, sk)
    n = len(body.vertices)
    np.testing.assert_array_equal(plan.subset, np.arange(0, n, 2))
    np.testing.assert_array_equal(plan.rest_vertices, body.vertices[::2])
    np.testing.assert_allclose(plan.rest_normals, vertex_normals(body.vertices, body.faces)[::2], atol=1e-12)
    names = sk.bone_names
    assert list(plan.bones) == [names.index("Root")] + [names.index(b) for b in rf.SWING_BONES]
    W = body.weights[::2]
    # the six largest weights hold all of a MakeHuman vertex's weight: the blend is the dense one
    dense = np.zeros_like(W)
    np.put_along_axis(dense, plan.weight_idx, plan.weight_val, 1)
    np.testing.assert_allclose(dense, W / W.sum(1, keepdims=True), atol=1e-12)
    assert plan.weight_idx.shape == (len(W), 6)
    assert np.all(np.diff(np.take_along_axis(W, plan.weight_idx, 1), axis=1) <= 0)  # largest first
    parents = list(sk.parents)
    for c, j in enumerate(plan.bones):
        sub = sorted(_subtree(parents, j))
        np.testing.assert_allclose(plan.subtree_weight[:, c], W[:, sub].sum(1), atol=1e-12)
        # Kinect joint k moves with bone j by the weights of its bone ends that turn with j: tails in j's
        # subtree, heads of the bones below j
        for k, name in enumerate(kinect_joint_names("v2")):
            want = sum(w for b, end, w in KINECT_JOINT_SETS["v2"][name]
                       if names.index(b) in sub and (end == "tail" or names.index(b) != j))
            assert abs(plan.joint_moves[k, c] - want) < 1e-12, (name, names[j])
    assert plan.joint_moves.shape == (len(kinect_joint_names("v2")), len(plan.bones))
    assert plan.joint_moves.max() > 0.99 and plan.joint_moves[:, 0].min() > 0.99  # the root moves every joint
    # other strides and bone sets; v1's joints
    for stride, want in ((1, np.arange(n)), (3, np.arange(0, n, 3)), (0, np.arange(n))):
        np.testing.assert_array_equal(rf.refine_plan(body.vertices, body.faces, body.weights, sk,
                                                     stride=stride).subset, want)
    few = rf.refine_plan(body.vertices, body.faces, body.weights, sk, "v1", swing_bones=("thigh_l", "calf_l"))
    assert list(few.bones) == [names.index("Root"), names.index("thigh_l"), names.index("calf_l")]
    assert few.joint_moves.shape == (len(kinect_joint_names("v1")), 3)


def test_a_rig_without_a_swing_bone_is_a_one_line_error_naming_it(body):
    sk = body.skeleton
    with pytest.raises(InputError, match="bone 'no_such_bone' is missing"):
        rf.refine_plan(body.vertices, body.faces, body.weights, sk, swing_bones=("spine_01", "no_such_bone"))


def test_the_cached_forward_kinematics_are_the_bodys(body):
    sk = body.skeleton
    plan = rf.refine_plan(body.vertices, body.faces, body.weights, sk)
    pose = _pose(sk)
    M, transforms = rf._forward_kinematics(plan, sk.parents, pose)
    heads, tails = posed_joints(sk, pose)
    np.testing.assert_allclose(M[:, :3, 3], heads, atol=1e-12)
    np.testing.assert_allclose(M[:, :3, 3] + M[:, :3, 1] * sk.lengths[:, None], tails, atol=1e-12)
    np.testing.assert_allclose(transforms, skinning_transforms(sk, pose)[:, :3], atol=1e-12)
    V, N = rf._skin(plan, transforms)
    T = skinning_transforms(sk, pose)
    dense = np.einsum("nb,bij->nij", body.weights[::2], T)
    np.testing.assert_allclose(V, np.einsum("nij,nj->ni", dense[:, :3, :3], plan.rest_vertices) + dense[:, :3, 3],
                               atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(N, axis=1), 1.0, atol=1e-12)


def test_apply_update_turns_are_rigid_motions_of_the_posed_skeleton(body):
    sk = body.skeleton
    plan = rf.refine_plan(body.vertices, body.faces, body.weights, sk)
    pose = _pose(sk, 5)
    M, _ = rf._forward_kinematics(plan, sk.parents, pose)
    world, heads, axes = rf._bone_frames(M, np.ascontiguousarray(sk.rest_rotations), plan.bones)
    h0, t0 = posed_joints(sk, pose)
    n_par = 6 + 2 * (len(plan.bones) - 1)
    # the root: translation added, rotation (world axes) about its head turns every joint
    delta = np.zeros(n_par)
    delta[:3] = [0.1, -0.2, 0.05]
    delta[3:6] = [0.3, -0.2, 0.4]
    turned = rf.apply_update(sk, pose, delta, plan.bones, axes, world)
    R = Rotation.from_rotvec(delta[3:6]).as_matrix()
    h1, t1 = posed_joints(sk, turned)
    root = plan.bones[0]
    for a, b in ((h0, h1), (t0, t1)):
        np.testing.assert_allclose(b, (a - h0[root]) @ R.T + h0[root] + delta[:3], atol=1e-9)
    # a swing of one bone (two angles about its axes) turns its subtree about its head, nothing else
    for c in (1, 9, len(plan.bones) - 1):
        j = plan.bones[c]
        delta = np.zeros(n_par)
        delta[6 + 2 * (c - 1)], delta[7 + 2 * (c - 1)] = 0.25, -0.4
        turned = rf.apply_update(sk, pose, delta, plan.bones, axes, world)
        R = Rotation.from_rotvec(0.25 * axes[c - 1, 0] - 0.4 * axes[c - 1, 1]).as_matrix()
        h1, t1 = posed_joints(sk, turned)
        sub = sorted(_subtree(list(sk.parents), j))
        rest = np.setdiff1d(np.arange(sk.n_bones), sub)
        np.testing.assert_allclose(t1[sub], (t0[sub] - h0[j]) @ R.T + h0[j], atol=1e-9)
        np.testing.assert_allclose(h1[rest], h0[rest], atol=1e-12)
        np.testing.assert_allclose(t1[rest], t0[rest], atol=1e-12)
        # a swing: the axes are perpendicular to the bone, so the bone's length and head stay
        np.testing.assert_allclose(h1[j], h0[j], atol=1e-12)
        assert abs(axes[c - 1, 0] @ M[j, :3, 1]) < 1e-12 and abs(axes[c - 1, 1] @ M[j, :3, 1]) < 1e-12
        assert abs(axes[c - 1, 0] @ axes[c - 1, 1]) < 1e-12


def test_sample_is_bilinear_and_clamped_at_the_border():
    rng = np.random.default_rng(0)
    image = rng.uniform(0, 10, (30, 40)).astype(np.float32)
    uv = np.r_[rng.uniform(0, 39, (200, 2)) * [1, 29 / 39], [[-3.0, 5.2], [45.0, 29.7], [10.5, -2.0]]]
    want = map_coordinates(image.astype(np.float64), [uv[:, 1], uv[:, 0]], order=1, mode="nearest")
    got = rf._sample(image, uv)
    assert got.dtype == np.float64 and got.shape == (len(uv),)
    np.testing.assert_allclose(got, want, atol=2e-3)  # OpenCV's 5-bit interpolation weights


def test_silhouette_distance_is_the_whole_image_transform_over_the_grown_box():
    mask = np.zeros((200, 300), np.uint8)
    cv2.ellipse(mask, (150, 90), (30, 50), 20.0, 0, 360, 1, -1)
    cv2.rectangle(mask, (250, 170), (299, 199), 1, -1)  # touching the image's corner: the box is clipped
    whole = cv2.distanceTransform((1 - mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)
    for m in (mask, mask.astype(bool)):  # uint8 masks are read as bool
        dist, origin = rf.silhouette_distance(m)
        y0, y1, x0, x1 = rf.mask_box(mask.astype(bool), 40)
        assert dist.shape == (y1 - y0, x1 - x0) and dist.dtype == np.float32
        np.testing.assert_array_equal(origin, [x0, y0])
        # the chamfer transform of the crop is the whole image's where the nearest mask pixel is within it
        np.testing.assert_allclose(dist, whole[y0:y1, x0:x1], atol=1e-4)
    # the margin: the box grown by it, clipped to the image
    ys, xs = np.nonzero(mask)
    dist, origin = rf.silhouette_distance(mask, 10)
    np.testing.assert_array_equal(origin, [xs.min() - 10, ys.min() - 10])
    assert dist.shape == (200 - (ys.min() - 10), 300 - (xs.min() - 10))
    # the caller's box is used as given
    dist, origin = rf.silhouette_distance(mask, 40, (5, 150, 20, 260))
    np.testing.assert_array_equal(origin, [20, 5])
    assert dist.shape == (145, 240)
    # an empty mask: one pixel at the margin's distance, origin 0
    dist, origin = rf.silhouette_distance(np.zeros((50, 60), bool), 25)
    assert dist.shape == (1, 1) and dist[0, 0] == 25.0 and dist.dtype == np.float32
    np.testing.assert_array_equal(origin, [0.0, 0.0])
    assert origin.shape == (2,)


def test_mask_box_grows_and_clips():
    mask = np.zeros((50, 60), bool)
    mask[10:20, 30:35] = True
    assert rf.mask_box(mask, 0) == (10, 20, 30, 35)
    assert rf.mask_box(mask, 5) == (5, 25, 25, 40)
    assert rf.mask_box(mask, 40) == (0, 50, 0, 60)
    assert rf.mask_box(np.zeros((5, 5), np.uint8), 3) is None
    mask[:] = False
    mask[0, 59] = True
    assert rf.mask_box(mask.astype(np.uint8), 2) == (0, 3, 57, 60)


def test_the_distance_window_holds_the_mask_for_points_on_any_one_side():
    """Points in one margin of the box only, and a window grown one side at a time: the values read there are
    the whole box's (the window must hold the mask's own box: the nearest mask pixel of a point far out)."""
    mask = np.zeros((240, 320), np.uint8)
    cv2.ellipse(mask, (170, 110), (30, 45), 30.0, 0, 360, 1, -1)
    allowed = mask.astype(bool)
    box = rf.mask_box(allowed, 40)
    sil = rf.mask_box(allowed, 0)
    whole, _ = rf.silhouette_distance(allowed, 40, box)
    h, w = whole.shape
    rng = np.random.default_rng(5)
    offsets = np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1]])
    sides = {"left": ([1, 1], [25, h - 2.001]), "right": ([w - 27, 1], [w - 2.001, h - 2.001]),
             "top": ([1, 1], [w - 2.001, 25]), "bottom": ([1, h - 27], [w - 2.001, h - 2.001]),
             "upper left": ([1, 1], [20, 20]), "lower right": ([w - 22, h - 22], [w - 2.001, h - 2.001])}

    def check(dist, points):
        probes = (points[None] + offsets[:, None]).reshape(-1, 2)
        np.testing.assert_allclose(rf._sample(dist, probes), rf._sample(whole, probes), atol=1e-4)

    for lo, hi in sides.values():
        points = rng.uniform(lo, hi, (60, 2))
        dist = np.full_like(whole, np.nan)
        rf._distance_where_needed(dist, allowed, box, sil, points, None)
        check(dist, points)
    # grown to one side from points on the mask (a fresh window each time): the earlier values stay, the new are
    # the whole box's; then every side in turn
    inside = np.c_[np.nonzero(allowed[box[0]:box[1], box[2]:box[3]])[::-1]].astype(float)[::50]
    for lo, hi in sides.values():
        dist = np.full_like(whole, np.nan)
        done = rf._distance_where_needed(dist, allowed, box, sil, inside, None)
        points = rng.uniform(lo, hi, (40, 2))
        rf._distance_where_needed(dist, allowed, box, sil, points, done)
        check(dist, np.r_[inside, points])
    dist = np.full_like(whole, np.nan)
    done = rf._distance_where_needed(dist, allowed, box, sil, inside, None)
    seen = [inside]
    for lo, hi in sides.values():
        points = rng.uniform(lo, hi, (40, 2))
        done = rf._distance_where_needed(dist, allowed, box, sil, points, done)
        seen.append(points)
        check(dist, np.concatenate(seen))
    assert done == (0, h, 0, w)
    # a mask high in the image and points only below-left of it: their nearest mask pixels lie above them, so the
    # window must reach up to the mask's own box
    high = np.zeros((300, 300), bool)
    high[160:200, 120:250] = True
    high[200:230, 200:250] = True
    box2, sil2 = rf.mask_box(high, 40), rf.mask_box(high, 0)
    whole2, _ = rf.silhouette_distance(high, 40, box2)
    points = rng.uniform([1, 80], [70, whole2.shape[0] - 2.001], (60, 2))
    dist = np.full_like(whole2, np.nan)
    rf._distance_where_needed(dist, high, box2, sil2, points, None)
    probes = (points[None] + offsets[:, None]).reshape(-1, 2)
    np.testing.assert_allclose(rf._sample(dist, probes), rf._sample(whole2, probes), atol=1e-4)
    # nothing new needed: the same window, nothing recomputed
    dist[:] = -1.0
    assert rf._distance_where_needed(dist, allowed, box, sil, inside, done) == done
    assert np.all(dist == -1.0)


# --- the refinement itself against MIR12b's reference, in cases test_pose_refine_analytic.py does not cover -------

def _case(shift=0.0):
    from bodystudio.geometry.camera import Camera
    from bodystudio.mirror.track import skin_vertices

    body = _body()
    sk = body.skeleton
    rng = np.random.default_rng(4)
    rot = rng.normal(0, 0.08, (sk.n_bones, 3))
    for arm, sign in (("upperarm_l", 1), ("upperarm_r", -1)):
        rot[sk.index(arm)] = Rotation.from_euler("z", sign * 0.5).as_rotvec()
    true = Pose(rot, np.array([shift, 0.0, 0.0]))
    camera = Camera.look_at("kinect", eye=(0.3, 1.0, 2.6), target=(0.0, 0.95, 0.0), fx=525.0)
    V = skin_vertices(body.vertices, body.weights, sk, true)
    mask = np.zeros((camera.height, camera.width), np.uint8)
    for tri in np.round(camera.project(V)[body.faces] * 16).astype(np.int32):
        cv2.fillConvexPoly(mask, tri, 1, lineType=cv2.LINE_8, shift=4)
    N = vertex_normals(V, body.faces)
    front = np.einsum("ij,ij->i", N, camera.center - V) > 0
    plan = rf.refine_plan(body.vertices, body.faces, body.weights, sk)
    return body, plan, camera, true, mask.astype(bool), V[front]


@pytest.fixture(scope="module")
def case():
    return _case()


def _planted(sk, true, offset, spine_deg=10.0):
    rot = true.rotations.copy()
    j = sk.index("spine_01")
    rot[j] = (Rotation.from_rotvec(rot[j]) * Rotation.from_euler("x", spine_deg, degrees=True)).as_rotvec()
    return Pose(rot, true.translation + np.asarray(offset, float))


@pytest.mark.parametrize("variant", ["v1 joints", "term weights", "far off", "cut by the border", "uint8 mask",
                                     "few samples"])
def test_the_fast_refinement_gives_the_reference_pose_in_more_cases(case, variant):
    from refine_reference import refine_pose_reference

    from bodystudio.mirror.track import posed_kinect_joints

    body, plan, camera, true, mask, points = case
    sk = body.skeleton
    offset, version, w, fg = (0.04, -0.02, 0.05), "v2", rf.RefineWeights(), mask
    if variant == "cut by the border":  # the body moved left: it crosses the image's left border
        body, plan, camera, true, fg, points = _case(shift=-1.35)
        assert fg[:, 0].any() and fg[:, 1:].any()
    if variant == "far off":  # 25 cm sideways: many body points beyond the distance transform's 40 px box
        offset = (0.25, 0.0, 0.0)
    if variant == "term weights":
        w = rf.RefineWeights(sil_weight=0.5, depth_weight=2.0, joint_weight=3.0, sil_px=3.0, depth_m=0.02,
                             joint_m=0.05, prior_rad=0.5, prior_m=0.3)
    if variant == "few samples":
        w = rf.RefineWeights(sil_samples=50, depth_samples=30)
    if variant == "v1 joints":
        version = "v1"
        plan = rf.refine_plan(body.vertices, body.faces, body.weights, sk, "v1")
    ik = _planted(sk, true, offset)
    joints = posed_kinect_joints(sk, true, version) + np.random.default_rng(5).normal(0, 0.015, (
        len(kinect_joint_names(version)), 3))
    tracked = np.ones(len(joints), bool)
    tracked[2] = False
    args = dict(kinect_positions=joints, tracked=tracked, depth_points=points, version=version, weights=w)
    fast = rf.refine_pose(plan, sk, ik, camera, fg.astype(np.uint8) if variant == "uint8 mask" else fg, **args)
    reference = refine_pose_reference(plan, sk, ik, camera, fg, **args)
    assert np.abs(reference.translation - ik.translation).max() > 1e-3
    np.testing.assert_allclose(fast.rotations, reference.rotations, atol=1e-6)
    np.testing.assert_allclose(fast.translation, reference.translation, atol=1e-6)


def test_an_empty_foreground_drops_the_silhouette_terms_and_the_edge_cases_return_the_input(case):
    from bodystudio.mirror.track import posed_kinect_joints

    body, plan, camera, true, mask, points = case
    sk = body.skeleton
    ik = _planted(sk, true, (0.04, -0.02, 0.05))
    joints = posed_kinect_joints(sk, true)
    many = rf.RefineWeights(depth_samples=10 ** 6)
    empty = rf.refine_pose(plan, sk, ik, camera, np.zeros_like(mask), joints, None, points, weights=many)
    no_sil = rf.refine_pose(plan, sk, ik, camera, mask, joints, None, points,
                            weights=rf.RefineWeights(depth_samples=10 ** 6, sil_weight=0.0))
    assert np.abs(empty.translation - ik.translation).max() > 1e-3
    np.testing.assert_allclose(empty.rotations, no_sil.rotations, atol=1e-9)
    np.testing.assert_allclose(empty.translation, no_sil.translation, atol=1e-9)
    # no steps: the input; a pose that cannot be refined (not finite): the input itself
    assert rf.refine_pose(plan, sk, ik, camera, mask, joints, None, points, iterations=0) is ik
    rot = ik.rotations.copy()
    rot[sk.index("spine_02")] = np.nan
    bad = Pose(rot, ik.translation)
    assert rf.refine_pose(plan, sk, bad, camera, mask, joints, None, points) is bad
    # the default: one step (ITERATIONS), the v2 joint set
    one = rf.refine_pose(plan, sk, ik, camera, mask, joints, None, points)
    again = rf.refine_pose(plan, sk, ik, camera, mask, joints, None, points, iterations=1, version="v2")
    np.testing.assert_array_equal(one.rotations, again.rotations)
    assert rf.ITERATIONS == 1
