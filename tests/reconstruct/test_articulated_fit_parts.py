"""The parts of the hull fit (:mod:`bodystudio.reconstruct.articulated_fit`, Rapid Skin Sec. IV) around its
Gauss-Newton loops, each on inputs whose answer is known by hand (issue 17's mutation tests of the module's rest):
the fitted bones and their subtrees, the Huber weights, the symmetric surface distance of two cubes, the A-pose at
the hull, the facing direction, an arm raised about the facing axis, the scaled template, the joint error, the
pelvis anchors, the hull data term on a plane; and the search around the fits (warm start and its fallback, the yaw
and arm-raise hypotheses, the refinement kept only when better) with the fit itself stood in.

And ``pose_template``'s sparse posing (pose_init, Eq. 12 of Rapid Skin): equal to the dense blend over every
non-zero weight, for weights with more influences than MakeHuman's six. Seconds (the 2k template once); the fits on
exact data are tests/reconstruct/test_articulated_fit_exact.py.
"""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.body.pose import Pose
from bodystudio.errors import InputError
from bodystudio.reconstruct import articulated_fit as af


@pytest.fixture(scope="module")
def body():
    from bodystudio.body import build_body

    return build_body(resolution="2k")


# --- pose_init.pose_template: the sparse LBS ---------------------------------------------------------------------

def _random_transforms(rng, B):
    T = np.tile(np.eye(4), (B, 1, 1))
    T[:, :3, :3] = Rotation.from_rotvec(rng.normal(scale=0.4, size=(B, 3))).as_matrix() * rng.uniform(0.9, 1.1,
                                                                                                      (B, 1, 1))
    T[:, :3, 3] = rng.normal(scale=0.2, size=(B, 3))
    return T


def test_pose_template_is_the_dense_blend_over_every_influence(body):
    """Weights with up to 9 influences per vertex (more than the mirror's 6): the posed vertices are
    ``sum_b w_ib T_b v_i`` over all of them; heads and tails posed by their own bone; the scale kept."""
    from bodystudio.body.kinect import kinect_joints
    from bodystudio.reconstruct.pose_init import pose_template

    rng = np.random.default_rng(5)
    B = body.skeleton.n_bones
    W = np.zeros((40, B))
    for i in range(40):
        cols = rng.choice(B, size=1 + i % 9, replace=False)
        W[i, cols] = rng.uniform(0.1, 1.0, len(cols))
    W /= W.sum(axis=1, keepdims=True)
    V0 = rng.normal(size=(40, 3))
    tiny = SimpleNamespace(skeleton=body.skeleton, vertices=V0, weights=W)
    T = _random_transforms(rng, B)
    dense = np.einsum("nb,bij,nj->ni", W, T[:, :3, :3], V0) + W @ T[:, :3, 3]
    out = pose_template(tiny, T, 1.25, "v2")
    np.testing.assert_allclose(out.vertices, dense, atol=1e-12)
    np.testing.assert_array_equal(out.bone_transforms, T)
    heads = np.einsum("bij,bj->bi", T[:, :3, :3], body.skeleton.heads) + T[:, :3, 3]
    tails = np.einsum("bij,bj->bi", T[:, :3, :3], body.skeleton.tails) + T[:, :3, 3]
    np.testing.assert_allclose(out.joints, kinect_joints(body.skeleton, heads, tails, "v2"), atol=1e-12)
    assert out.global_scale == 1.25
    # other rest vertices in the same topology (the fitted rest shape)
    V1 = V0 * 1.1 + 0.05
    out = pose_template(tiny, T.tolist(), rest_vertices=V1.tolist())
    np.testing.assert_allclose(out.vertices, np.einsum("nb,bij,nj->ni", W, T[:, :3, :3], V1) + W @ T[:, :3, 3],
                               atol=1e-12)
    assert out.global_scale == 1.0
    assert out.joints.shape == (25, 3)


def test_pose_template_of_the_template_and_the_v1_joints(body):
    from bodystudio.body.kinect import kinect_joints
    from bodystudio.reconstruct.pose_init import pose_template

    T = _random_transforms(np.random.default_rng(6), body.skeleton.n_bones)
    out = pose_template(body, T, version="v1")
    dense = np.einsum("nb,bij,nj->ni", body.weights, T[:, :3, :3], body.vertices) + body.weights @ T[:, :3, 3]
    np.testing.assert_allclose(out.vertices, dense, atol=1e-12)
    heads = np.einsum("bij,bj->bi", T[:, :3, :3], body.skeleton.heads) + T[:, :3, 3]
    tails = np.einsum("bij,bj->bi", T[:, :3, :3], body.skeleton.tails) + T[:, :3, 3]
    np.testing.assert_allclose(out.joints, kinect_joints(body.skeleton, heads, tails, "v1"), atol=1e-12)
    # float32 transforms are kept as float64 (the PoseInit's transforms feed the refinement in float64)
    out32 = pose_template(body, T.astype(np.float32))
    assert out32.bone_transforms.dtype == np.float64 and out32.vertices.dtype == np.float64


# --- bones, subtrees, weights --------------------------------------------------------------------------------------

def test_fit_bones_are_the_game_engine_rigs_and_a_rig_without_them_is_refused(body):
    skel = body.skeleton
    idx = af._fit_bone_indices(skel)
    assert idx.tolist() == [skel.bone_names.index(b) for b in af.FIT_BONES] and idx[0] == 0
    fake = SimpleNamespace(bone_names=[b for b in skel.bone_names if b not in ("neck_01", "calf_r")])
    with pytest.raises(InputError, match=r"^articulated fit needs the game_engine rig; bones neck_01, calf_r are "
                                         r"missing$"):
        af._fit_bone_indices(fake)


def test_subtree_matrix_of_a_small_tree():
    """Bones 0 (root) -> 1 -> 2, 0 -> 3 -> 4, 3 -> 5: the subtrees of bones 1, 3 and 4, each with itself."""
    skel = SimpleNamespace(n_bones=6, parents=np.array([-1, 0, 1, 0, 3, 3]))
    D = af._subtree_matrix(skel, np.array([1, 3, 4]))
    want = np.zeros((6, 3))
    want[[1, 2], 0] = 1
    want[[3, 4, 5], 1] = 1
    want[4, 2] = 1
    np.testing.assert_array_equal(D, want)
    assert D.dtype == np.float64
    np.testing.assert_array_equal(af._subtree_matrix(skel, np.array([0]))[:, 0], np.ones(6))


def test_huber_weights():
    r = np.array([0.0, 0.03, -0.03, 0.06, -0.12, 0.01])
    np.testing.assert_allclose(af._huber_weights(r, 0.03), [1, 1, 1, 0.5, 0.25, 1], atol=1e-15)
    np.testing.assert_array_equal(af._huber_weights(np.zeros(2), 0.0), [1.0, 1.0])
    np.testing.assert_allclose(af._huber_weights(np.array([1e-13]), 1e-14), [0.01], rtol=1e-12)  # |r| floored at 1e-12


def _cube(half):
    V = np.array([[x, y, z] for x in (-half, half) for y in (-half, half) for z in (-half, half)], float)
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return V, F


def test_symmetric_hull_distance_of_two_cubes():
    """A cube of half-size 0.55 around one of 0.5: its corners are sqrt(3) * 0.05 from the small cube, the small
    cube's corners 0.05 from the big one's faces; the mean of both means."""
    V, F = _cube(0.55)
    hv, hf = _cube(0.5)
    hull = SimpleNamespace(vertices=hv, faces=hf)
    assert af.symmetric_hull_distance(V, F, hull) == pytest.approx(0.5 * (np.sqrt(3) * 0.05 + 0.05), abs=1e-12)
    assert af.symmetric_hull_distance(hv, hf, hull) == pytest.approx(0.0, abs=1e-12)


# --- the A-pose, the facing direction, a raised arm, the scaled template -----------------------------------------

def _hull_at(c):
    return SimpleNamespace(centroid=np.asarray(c, float))


@pytest.mark.parametrize("yaw", [0.0, 90.0, -30.0])
def test_a_pose_at_the_hull_is_the_rest_pose_turned_and_centred(body, yaw):
    c = np.array([0.3, 0.9, -0.2])
    pose = af.a_pose_at_hull(body, _hull_at(c), yaw)
    V, _ = body.pose(pose)
    np.testing.assert_allclose(V.mean(axis=0), c, atol=1e-9)
    facing = af.body_facing(body, pose)
    np.testing.assert_allclose(facing, [np.sin(np.radians(yaw)), 0.0, np.cos(np.radians(yaw))], atol=1e-9)
    assert np.count_nonzero(pose.rotations[1:]) == 0
    # the whole template turned rigidly about the vertical through its mean
    R = Rotation.from_euler("y", yaw, degrees=True).as_matrix()
    np.testing.assert_allclose(V - c, (body.vertices - body.vertices.mean(axis=0)) @ R.T, atol=1e-9)


def test_a_pose_default_yaw_is_zero_and_facing_of_the_rest_pose(body):
    pose = af.a_pose_at_hull(body, _hull_at([0.0, 1.0, 0.0]))
    np.testing.assert_allclose(pose.rotations, 0.0, atol=1e-12)
    np.testing.assert_allclose(pose.translation, np.array([0.0, 1.0, 0.0]) - body.vertices.mean(axis=0), atol=1e-12)
    np.testing.assert_allclose(af.body_facing(body, Pose.rest(body.skeleton.n_bones)), [0, 0, 1], atol=1e-12)


@pytest.mark.parametrize("side, yaw", [("l", 0.0), ("r", 0.0), ("l", 90.0), ("r", -60.0)])
def test_raise_arm_turns_the_upper_arm_about_the_facing_axis(body, side, yaw):
    """The left arm (on +x facing +z) rises by a positive turn about the facing axis, the right by a negative
    one: the elbow turns by exactly that rotation about the shoulder; the rest of the pose stays."""
    from bodystudio.body.skinning import posed_joints

    skel = body.skeleton
    base = af.a_pose_at_hull(body, _hull_at([0.0, 1.0, 0.0]), yaw)
    rot = base.rotations.copy()
    rot[skel.index("lowerarm_l")] = [0.0, 0.0, 0.3]
    base = Pose(rot, base.translation + 0.1)
    keep = base.rotations.copy()
    out = af.raise_arm(body, base, side, 35.0)
    np.testing.assert_array_equal(base.rotations, keep)  # the input pose is left alone
    j = skel.index(f"upperarm_{side}")
    h0, t0 = posed_joints(skel, base)
    h1, t1 = posed_joints(skel, out)
    sign = 1.0 if side == "l" else -1.0
    R = Rotation.from_rotvec(sign * np.radians(35.0) * af.body_facing(body, base)).as_matrix()
    np.testing.assert_allclose(h1[j], h0[j], atol=1e-12)
    np.testing.assert_allclose(t1[j] - h1[j], R @ (t0[j] - h0[j]), atol=1e-9)
    other = np.ones(skel.n_bones, bool)
    other[j] = False
    np.testing.assert_array_equal(out.rotations[other], base.rotations[other])
    np.testing.assert_array_equal(out.translation, base.translation)
    if side == "l":
        assert t1[j][1] > t0[j][1]  # up
    assert out.rotations.dtype == np.float64


def test_scaled_body_scales_vertices_and_joints_about_the_origin(body):
    s = af.scaled_body(body, 1.2)
    np.testing.assert_allclose(s.vertices, body.vertices * 1.2)
    np.testing.assert_allclose(s.skeleton.heads, body.skeleton.heads * 1.2)
    np.testing.assert_allclose(s.skeleton.tails, body.skeleton.tails * 1.2)
    assert s.faces is body.faces and s.weights is body.weights and s.skeleton.parents is body.skeleton.parents
    assert s.skeleton.bone_names == body.skeleton.bone_names


def test_joint_error_over_the_major_joints_or_the_named_ones():
    from bodystudio.body.kinect import kinect_joint_names

    names = kinect_joint_names("v2")
    G = np.tile([0.5, 1.0, -0.2], (25, 1))
    J = G.copy()
    J[names.index("ElbowLeft")] += [0.03, 0.04, 0.0]  # 5 cm
    J[names.index("HandLeft")] += [1.0, 0.0, 0.0]  # not a major joint
    assert af.joint_error_m(J, G) == pytest.approx(0.05 / len(af.MAJOR_JOINTS), abs=1e-15)
    assert af.joint_error_m(J.tolist(), G.tolist(), ("ElbowLeft", "HandLeft")) == pytest.approx(0.525, abs=1e-15)
    assert af.joint_error_m(J, G, ("ElbowLeft",)) == pytest.approx(0.05, abs=1e-15)
    with pytest.raises(InputError, match=r"^unknown Kinect v2 joint\(s\): Elbow, Knee$"):
        af.joint_error_m(J, G, ("Elbow", "SpineBase", "Knee"))
    assert len(af.MAJOR_JOINTS) == 17


# --- anchors and the hull data term --------------------------------------------------------------------------------

def test_pelvis_anchors_are_the_placed_heads_of_the_pelvis_bones(body):
    skel = body.skeleton
    T = _random_transforms(np.random.default_rng(8), skel.n_bones)
    ids, rest, targets, w = af.pelvis_anchors(body, T, weight=3.0)
    assert ids.tolist() == [skel.index(b) for b in af.PELVIS_BONES] and af.PELVIS_BONES == ("pelvis", "thigh_l",
                                                                                             "thigh_r")
    np.testing.assert_array_equal(rest, skel.heads[ids])
    np.testing.assert_allclose(targets, [T[b, :3, :3] @ skel.heads[b] + T[b, :3, 3] for b in ids], atol=1e-12)
    assert w == 3.0 and isinstance(w, float)
    ids, _, _, w = af.pelvis_anchors(body, T.tolist(), bones=("calf_l",))
    assert ids.tolist() == [skel.index("calf_l")] and w == 1.0
    with pytest.raises(InputError, match=r"^pose refinement: the template has no pelvis bone\(s\) hip, waist$"):
        af.pelvis_anchors(body, T, bones=("pelvis", "hip", "waist"))


def test_merge_anchors_concatenates_and_spreads_the_weights():
    b = (np.array([1]), np.ones((1, 3)), np.zeros((1, 3)), 2.0)
    assert af._merge_anchors(None, b) is b
    a = (np.array([4, 5]), np.full((2, 3), 3.0), np.full((2, 3), 4.0), np.array([0.5, 0.25]))
    m = af._merge_anchors(a, b)
    np.testing.assert_array_equal(m[0], [4, 5, 1])
    np.testing.assert_array_equal(m[1], [[3, 3, 3], [3, 3, 3], [1, 1, 1]])
    np.testing.assert_array_equal(m[2], [[4, 4, 4], [4, 4, 4], [0, 0, 0]])
    np.testing.assert_array_equal(m[3], [0.5, 0.25, 2.0])
    m = af._merge_anchors(b, (np.array([7, 8]), np.zeros((2, 3)), np.ones((2, 3)), 5.0))
    np.testing.assert_array_equal(m[3], [2.0, 5.0, 5.0])


def test_hull_data_term_on_a_plane():
    """A hull of points on y = 0 with normals +y: the residual is the height above it (inside: below, weighted
    0.5 by default), Huber beyond 3 cm, a template normal within 78 degrees of the hull's (cos > 0.2) or no weight;
    every template vertex is a row, the gradient the hull normal."""
    g = np.linspace(-1.0, 1.0, 21)
    P = np.array([[x, 0.1, z] for x in g for z in g])  # the plane y = 0.1
    hull = SimpleNamespace(vertices=P, normals=np.tile([0.0, 1.0, 0.0], (len(P), 1)))
    term = af.hull_data_term(hull, af.PoseRefineParams())
    V = np.array([[0.0, 0.12, 0.0], [0.1, 0.08, 0.1], [0.2, 0.16, 0.0], [0.3, 0.01, 0.0], [0.0, 0.11, 0.0],
                  [0.0, 0.11, 0.0], [0.0, 0.11, 0.0], [0.4, 0.1, 0.4]])
    up = [0.0, 1.0, 0.0]
    N = np.array([up, up, up, up, [1.0, 0.0, 0.0], [np.sqrt(1 - 0.21 ** 2), 0.21, 0.0], [np.sqrt(0.96), 0.2, 0.0],
                  up])
    rows, r, w, G = term(V, N)
    np.testing.assert_array_equal(rows, np.arange(8))
    np.testing.assert_allclose(r, [0.02, -0.02, 0.06, -0.09, 0.01, 0.01, 0.01, 0.0], atol=1e-15)
    # a normal exactly 0.2 from the hull's is not compatible; a point on the plane is not inside
    np.testing.assert_allclose(w, [1.0, 0.5, 0.5, 0.5 / 3, 0.0, 1.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_array_equal(G, np.tile(up, (8, 1)))
    term = af.hull_data_term(hull, af.PoseRefineParams(robust_m=0.1, inside_weight=0.2))
    np.testing.assert_allclose(term(V, N)[2], [1.0, 0.2, 1.0, 0.2, 0.0, 1.0, 0.0, 1.0], atol=1e-12)


# --- the wrappers: refine_bone_transforms, articulated_fit --------------------------------------------------------

def test_refine_bone_transforms_needs_data_and_adds_the_pelvis_anchors(body, monkeypatch):
    seen = {}

    def fake(b, T, data_term, params, anchors=None):
        assert b is body
        seen.update(T=T, data_term=data_term, params=params, anchors=anchors)
        return "OUT"

    monkeypatch.setattr(af, "_refine_bone_transforms", fake)
    T = np.tile(np.eye(4), (body.skeleton.n_bones, 1, 1)).astype(np.float32)
    with pytest.raises(InputError, match=r"^pose refinement needs a visual hull or a data term$"):
        af.refine_bone_transforms(body, T, None)
    term = object()
    assert af.refine_bone_transforms(body, T, None, data_term=term) == "OUT"
    assert seen["data_term"] is term and seen["T"].dtype == np.float64 and seen["anchors"] is None
    assert seen["params"] == af.PoseRefineParams()
    hull = SimpleNamespace(vertices=np.zeros((3, 3)), normals=np.tile([0.0, 1.0, 0.0], (3, 1)))
    af.refine_bone_transforms(body, T, hull, af.PoseRefineParams(robust_m=0.1))
    rows, r, w, G = seen["data_term"](np.array([[0.0, 0.2, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    assert r.tolist() == [pytest.approx(0.2)] and w.tolist() == [pytest.approx(0.5)]  # the hull's, with the params
    mine = (np.array([2]), np.zeros((1, 3)), np.ones((1, 3)), 4.0)
    af.refine_bone_transforms(body, T, None, af.PoseRefineParams(pelvis_weight=7.0), data_term=term, anchors=mine)
    a = seen["anchors"]
    pel = [body.skeleton.index(b) for b in af.PELVIS_BONES]
    assert a[0].tolist() == [2, *pel] and a[3].tolist() == [4.0, 7.0, 7.0, 7.0]
    af.refine_bone_transforms(body, T, None, af.PoseRefineParams(pelvis_weight=0.5, pelvis_bones=("pelvis",)),
                              data_term=term)
    assert seen["anchors"][0].tolist() == [body.skeleton.index("pelvis")] and seen["anchors"][3] == 0.5
    af.refine_bone_transforms(body, T, None, af.PoseRefineParams(pelvis_weight=0.0), data_term=term, anchors=mine)
    assert seen["anchors"] is mine


def test_articulated_fit_checks_the_scale_and_fills_the_defaults(monkeypatch):
    seen = {}
    monkeypatch.setattr(af, "_articulated_fit", lambda *a: seen.update(args=a) or "FIT")
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(InputError, match=r"^template scale must be positive, got "):
            af.articulated_fit("B", "H", "I", scale=bad)
    assert af.articulated_fit("B", "H", "I") == "FIT"
    assert seen["args"] == ("B", "H", "I", af.ArticulatedFitParams(), None, 1.0)
    p = af.ArticulatedFitParams(iterations=3)
    af.articulated_fit("B", "H", "I", p, iterations=5, scale=2)
    assert seen["args"] == ("B", "H", "I", p, 5, 2.0) and isinstance(seen["args"][5], float)


# --- the search around the fits ------------------------------------------------------------------------------------

def _fit(err, converged=True, scale=1.0, tag=""):
    return SimpleNamespace(fit_error_m=err, converged=converged, scale=scale, tag=tag,
                           pose=Pose(np.zeros((53, 3)), np.zeros(3)))


def test_warm_start_and_its_fallback(body, monkeypatch, caplog):
    calls = []

    def warm_fit(b, hull, init, params, iterations=None, scale=1.0):
        assert b is body and hull == "H" and isinstance(params, af.ArticulatedFitParams)
        calls.append(("warm", init, scale))
        return state["warm"]

    def cold_fit(b, hull, params):
        assert b is body and hull == "H" and isinstance(params, af.ArticulatedFitParams)
        calls.append(("cold", params))
        return state["cold"]

    state = {}
    monkeypatch.setattr(af, "articulated_fit", warm_fit)
    monkeypatch.setattr(af, "_fit_from_a_pose", cold_fit)
    prev = Pose.rest(body.skeleton.n_bones)
    P = af.ArticulatedFitParams
    # no previous pose: the A-pose search
    state.update(warm=_fit(0.01), cold=_fit(0.02, tag="cold"))
    assert af.fit_body_to_hull(body, "H").tag == "cold" and calls == [("cold", P())]
    # converged warm start: kept without the search
    calls.clear()
    assert af.fit_body_to_hull(body, "H", prev, previous_scale=1.3) is state["warm"]
    assert calls == [("warm", prev, 1.3)]
    calls.clear()
    af.fit_body_to_hull(body, "H", prev)
    assert calls == [("warm", prev, 1.0)]
    # unconverged: the better of both, the warm one on a tie
    for warm_err, cold_err, winner in ((0.01, 0.02, "warm"), (0.03, 0.02, "cold"), (0.02, 0.02, "warm")):
        state.update(warm=_fit(warm_err, converged=False, tag="warm"), cold=_fit(cold_err, tag="cold"))
        calls.clear()
        with caplog.at_level("DEBUG", logger="bodystudio.reconstruct.articulated_fit"):
            assert af.fit_body_to_hull(body, "H", prev).tag == winner
        assert [c[0] for c in calls] == ["warm", "cold"]
        assert caplog.records[-1].getMessage() == (f"hull fit: warm start did not converge ({warm_err:.4f} m), "
                                                   f"A-pose start {cold_err:.4f} m")
    # "always": the search even after a converged warm start; "never": not even after an unconverged one
    state.update(warm=_fit(0.03, tag="warm"), cold=_fit(0.02, tag="cold"))
    with caplog.at_level("DEBUG", logger="bodystudio.reconstruct.articulated_fit"):
        assert af.fit_body_to_hull(body, "H", prev, P(warm_fallback="always")).tag == "cold"
    assert caplog.records[-1].getMessage() == "hull fit: warm start converged (0.0300 m), A-pose start 0.0200 m"
    state.update(warm=_fit(0.03, converged=False, tag="warm"))
    calls.clear()
    assert af.fit_body_to_hull(body, "H", prev, P(warm_fallback="never")).tag == "warm"
    assert [c[0] for c in calls] == ["warm"]
    with pytest.raises(InputError, match=r"^unknown warm_fallback 'sometimes'; valid: never, unconverged, always$"):
        af.fit_body_to_hull(body, "H", prev, P(warm_fallback="sometimes"))
    with pytest.raises(InputError, match=r"^previous pose has 3 bones, the body 53$"):
        af.fit_body_to_hull(body, "H", Pose.rest(3))


def test_the_a_pose_search_keeps_the_best_yaw_then_better_arm_raises_then_the_refinement(body, monkeypatch, caplog):
    """Stood-in fits whose errors depend on the start: yaw 90 is best; raising the left arm 90 degrees (from
    the arm reset straight) improves on it, the right arm's raises do not; the refinement from the best is kept
    only when it is no worse."""
    skel = body.skeleton
    ul, ll = skel.index("upperarm_l"), skel.index("lowerarm_l")
    calls = []

    def a_pose(b, hull, yaw):
        assert b is body and hull == "H"
        rot = np.zeros((skel.n_bones, 3))
        rot[ul] = [0.1, 0.0, 0.0]
        rot[ll] = [0.2, 0.0, 0.0]
        return Pose(rot, [yaw, 0.0, 0.0])

    def raise_(b, pose, side, deg):
        assert b is body
        return Pose(pose.rotations, pose.translation + [0.0, {"l": 1.0, "r": 2.0}[side], deg])

    errors = {(90.0, 0.0, 0.0): 0.05, (0.0, 0.0, 0.0): 0.060001, (180.0, 0.0, 0.0): 0.07,
              (90.0, 1.0, 45.0): 0.05, (90.0, 1.0, 90.0): 0.04, (90.0, 3.0, 135.0): 0.04501,
              (90.0, 3.0, 180.0): 0.04}  # a tie with the best so far: not taken
    final = {"err": 0.03}

    def fit(b, hull, init, params, iterations=None, scale=1.0):
        assert b is body and hull == "H" and params is given
        key = tuple(float(x) for x in init.translation)
        calls.append((key, iterations, scale, init.rotations[[ul, ll]].copy()))
        err = final["err"] if iterations is None else errors[key]
        return SimpleNamespace(fit_error_m=err, pose=init, scale=scale + 0.01, key=key, refined=iterations is None)

    monkeypatch.setattr(af, "a_pose_at_hull", a_pose)
    monkeypatch.setattr(af, "raise_arm", raise_)
    monkeypatch.setattr(af, "articulated_fit", fit)
    params = given = af.ArticulatedFitParams(yaw_candidates_deg=(0.0, 90.0, 180.0), coarse_iterations=7)
    with caplog.at_level("DEBUG", logger="bodystudio.reconstruct.articulated_fit"):
        out = af._fit_from_a_pose(body, "H", params)
    assert [r.getMessage() for r in caplog.records if r.name == "bodystudio.reconstruct.articulated_fit"] == [
        "hull fit: yaw candidates (0.0, 90.0, 180.0) -> fit errors [0.06 0.05 0.07] m",
        "hull fit: arm l raise candidates -> fit errors [0.05 0.04] m",
        "hull fit: arm r raise candidates -> fit errors [0.045 0.04 ] m"]
    keys = [c[0] for c in calls]
    assert keys[:3] == [(0.0, 0.0, 0.0), (90.0, 0.0, 0.0), (180.0, 0.0, 0.0)]
    assert all(c[1] == 7 for c in calls[:7]) and calls[7][1] is None
    # the left arm's raises from the best yaw (reset straight), the right arm's from the left arm's best
    assert keys[3:5] == [(90.0, 1.0, 45.0), (90.0, 1.0, 90.0)]
    assert keys[5:7] == [(90.0, 3.0, 135.0), (90.0, 3.0, 180.0)]
    np.testing.assert_array_equal(calls[3][3], 0.0)  # the arm reset before raising
    assert calls[3][2] == pytest.approx(1.01) and calls[5][2] == pytest.approx(1.02)  # the best fit's scale
    assert keys[7] == (90.0, 1.0, 90.0) and calls[7][2] == pytest.approx(1.02)
    assert out.fit_error_m == 0.03 and out.refined
    # a refinement that comes out worse is dropped; an equal one is kept
    final["err"] = 0.0401
    calls.clear()
    out = af._fit_from_a_pose(body, "H", params)
    assert out.fit_error_m == 0.04 and out.key == (90.0, 1.0, 90.0) and not out.refined
    final["err"] = 0.04
    calls.clear()
    out = af._fit_from_a_pose(body, "H", params)
    assert out.key == (90.0, 1.0, 90.0) and out.refined and len(calls) == 8
    assert calls[-1][1] is None
    with pytest.raises(InputError, match=r"^articulated fit from the A-pose needs at least one root yaw candidate$"):
        af._fit_from_a_pose(body, "H", af.ArticulatedFitParams(yaw_candidates_deg=()))
    # the round to 4 decimals in the log
    errors[(0.0, 0.0, 0.0)] = 0.06004
    seen_before = len(caplog.records)
    with caplog.at_level("DEBUG", logger="bodystudio.reconstruct.articulated_fit"):
        af._fit_from_a_pose(body, "H", params)
    assert caplog.records[seen_before].getMessage().endswith("fit errors [0.06 0.05 0.07] m")


def test_hull_joints_carves_then_fits(monkeypatch):
    import bodystudio.reconstruct.articulated_fit as mod

    seen = {}
    monkeypatch.setattr(mod, "visual_hull", lambda cams, masks, bounds=None, voxel_m=0.0: seen.update(
        hull=(cams, masks, bounds, voxel_m)) or "HULL")
    monkeypatch.setattr(mod, "fit_body_to_hull", lambda b, h, prev, params, scale: seen.update(
        fit=(b, h, prev, params, scale)) or SimpleNamespace(joints="J", pose="P", fit_error_m=0.5))
    assert af.hull_joints("C", "M", "B") == ("J", "P", 0.5)
    assert seen["hull"] == ("C", "M", None, 0.015) and seen["fit"] == ("B", "HULL", None, None, 1.0)
    af.hull_joints("C", "M", "B", "PREV", 0.02, "PAR", "BOUNDS", 1.4)
    assert seen["hull"] == ("C", "M", "BOUNDS", 0.02) and seen["fit"] == ("B", "HULL", "PREV", "PAR", 1.4)
