"""§4 of Real-time Reshaping (the source-body initialisation) against answers known in closed form.

Each test builds a tiny noise-free case on the 2k statistical model (loaded in ~1 s) and runs in well under
a second: bone scaling stretches exactly the planted bone, inverse LBS undoes the LBS of the IK pose
exactly, unposed Kinect joints land on the rest skeleton's, the Eq. 2 normal equations equal a dense
least-squares solve (prior, translation, joint rows, repeated matches) and recover planted coefficients,
trimming drops planted outliers, Eq. 3 moves every joint with the mean displacement of its 12 nearest
vertices, and the whole initialisation recovers a planted shape from one noise-free frame.
"""

import functools
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial import cKDTree

from bodystudio.body import Pose
from bodystudio.body.kinect import kinect_joint_names, kinect_joints
from bodystudio.body.skinning import linear_blend_skinning, skinning_transforms
from bodystudio.errors import FileFormatError, InputError
from bodystudio.mirror import init as init_mod
from bodystudio.mirror.init import (
    BONE_SCALE_SEGMENTS,
    MIN_POINTS,
    SHAPE_JOINTS,
    InitObservation,
    SourceBody,
    _model_kinect_joints,
    _subsample,
    _vertex_normals,
    bone_scaled_body,
    check_model,
    fit_shape,
    initialise_from_observations,
    joint_neighbourhoods,
    load_source_body,
    refit_skeleton,
    refit_skeleton_from_vertices,
    save_source_body,
    transform_to_default_pose,
    unposed_kinect_joints,
)
from bodystudio.mirror.track import ik_pose, posed_kinect_joints, skin_vertices

NAMES = kinect_joint_names("v2")
IX = {n: i for i, n in enumerate(NAMES)}


@functools.lru_cache(maxsize=1)
def _model_2k():
    """Loaded once per process (a module-level cache, so mutation-testing forks inherit it)."""
    from bodystudio.body.statistical import load_statistical_model

    return load_statistical_model("2k", progress=False)


@pytest.fixture(scope="module")
def model():
    return _model_2k()


@pytest.fixture(scope="module")
def mean_body(model):
    return model.body(np.zeros(model.n_components))


def _pose(sk, seed=0, scale=0.2, translation=(0.1, 0.0, 2.0)):
    rng = np.random.default_rng(seed)
    return Pose(rng.normal(0.0, scale, (sk.n_bones, 3)), np.array(translation))


def _planted_coeffs(model, seed=1, scale=0.8):
    return np.random.default_rng(seed).normal(0.0, 1.0, model.n_components) * model.stddev * scale


# --- bone scaling (B_0^D) ------------------------------------------------------------------------------

def _stretch_left_thigh(K, factor):
    """Kinect joints with the left thigh (HipLeft -> KneeLeft) ``factor`` times longer, the shank and foot
    carried along unchanged."""
    K2 = K.copy()
    d = (factor - 1.0) * (K[IX["KneeLeft"]] - K[IX["HipLeft"]])
    for n in ("KneeLeft", "AnkleLeft", "FootLeft"):
        K2[IX[n]] += d
    return K2, d


def test_bone_scaling_of_the_rest_skeleton_is_the_identity(mean_body):
    sk = mean_body.skeleton
    K = kinect_joints(sk, sk.heads, sk.tails)
    B = bone_scaled_body(mean_body, K)
    np.testing.assert_allclose(B.vertices, mean_body.vertices, atol=1e-12)
    np.testing.assert_allclose(B.skeleton.heads, sk.heads, atol=1e-12)
    np.testing.assert_allclose(B.skeleton.tails, sk.tails, atol=1e-12)
    assert B.weights is mean_body.weights and B.faces is mean_body.faces


@pytest.mark.parametrize("factor, expect", [(1.2, 1.2), (1.1, 1.1), (0.9, 0.9), (2.0, 1.33), (0.5, 0.75)])
def test_bone_scaling_stretches_only_the_planted_bone_along_its_axis(mean_body, factor, expect):
    """The thigh takes the Kinect thigh's length (clipped to 0.75..1.33); the bones below are carried along
    rigidly, every other bone and vertex stays; a vertex on the thigh alone keeps its offset across the bone
    and scales its offset along it (the affine map of §4, "scaling the offsets ... along the bones")."""
    sk = mean_body.skeleton
    K = kinect_joints(sk, sk.heads, sk.tails)
    K2, _ = _stretch_left_thigh(K, factor)
    B = bone_scaled_body(mean_body, K2)
    s2 = B.skeleton
    ratio = s2.lengths / sk.lengths
    thigh = sk.index("thigh_l")
    np.testing.assert_allclose(ratio[thigh], expect, atol=1e-9)
    others = np.arange(sk.n_bones) != thigh
    np.testing.assert_allclose(ratio[others], 1.0, atol=1e-9)
    axis = (sk.tails[thigh] - sk.heads[thigh]) / sk.lengths[thigh]
    np.testing.assert_allclose(s2.heads[thigh], sk.heads[thigh], atol=1e-12)
    np.testing.assert_allclose((s2.tails[thigh] - s2.heads[thigh]) / s2.lengths[thigh], axis, atol=1e-12)
    shift = (expect - 1.0) * sk.lengths[thigh] * axis
    below = [sk.index(b) for b in ("calf_l", "foot_l", "ball_l")]
    for b in below:  # carried along: heads and tails shift with the thigh's tail
        np.testing.assert_allclose(s2.heads[b] - sk.heads[b], shift, atol=1e-12)
        np.testing.assert_allclose(s2.tails[b] - sk.tails[b], shift, atol=1e-12)
    rest = [b for b in range(sk.n_bones) if b not in below and b != thigh]
    np.testing.assert_allclose(s2.heads[rest], sk.heads[rest], atol=1e-12)
    np.testing.assert_allclose(s2.tails[rest], sk.tails[rest], atol=1e-12)
    W = mean_body.weights
    on_thigh = np.flatnonzero(W[:, thigh] > 1 - 1e-9)
    on_calf = np.flatnonzero(W[:, sk.index("calf_l")] > 1 - 1e-9)
    assert len(on_thigh) > 10 and len(on_calf) > 10
    off = mean_body.vertices[on_thigh] - sk.heads[thigh]
    off2 = B.vertices[on_thigh] - s2.heads[thigh]
    np.testing.assert_allclose(off2 @ axis, expect * (off @ axis), atol=1e-12)
    np.testing.assert_allclose(off2 - np.outer(off2 @ axis, axis), off - np.outer(off @ axis, axis), atol=1e-12)
    np.testing.assert_allclose(B.vertices[on_calf] - mean_body.vertices[on_calf], np.tile(shift, (len(on_calf), 1)),
                               atol=1e-12)
    untouched = W[:, [thigh] + below].sum(1) == 0
    np.testing.assert_allclose(B.vertices[untouched], mean_body.vertices[untouched], atol=1e-12)


def test_bone_scaling_each_segment_sets_its_bones(mean_body):
    """Every segment of BONE_SCALE_SEGMENTS: Kinect joints of a skeleton whose segment bones are 1.1x
    longer give those bones 1.1x their length (two-bone segments: both)."""
    sk = mean_body.skeleton
    K = kinect_joints(sk, sk.heads, sk.tails)
    for bones, a, b in BONE_SCALE_SEGMENTS:
        K2 = K.copy()
        K2[IX[b]] = K[IX[a]] + 1.1 * (K[IX[b]] - K[IX[a]])
        ratio = bone_scaled_body(mean_body, K2).skeleton.lengths / sk.lengths
        for bone in bones:
            np.testing.assert_allclose(ratio[sk.index(bone)], 1.1, atol=1e-9, err_msg=bone)


def test_bone_scaling_skips_untracked_and_missing_joints(mean_body):
    sk = mean_body.skeleton
    K = kinect_joints(sk, sk.heads, sk.tails)
    K2, _ = _stretch_left_thigh(K, 1.2)
    thigh = sk.index("thigh_l")
    tracked = np.ones(len(NAMES), bool)
    tracked[IX["KneeLeft"]] = False
    assert bone_scaled_body(mean_body, K2, tracked).skeleton.lengths[thigh] == pytest.approx(sk.lengths[thigh])
    K3 = K2.copy()
    K3[IX["HipLeft"]] = np.nan
    assert bone_scaled_body(mean_body, K3).skeleton.lengths[thigh] == pytest.approx(sk.lengths[thigh])
    assert bone_scaled_body(mean_body, K2).skeleton.lengths[thigh] == pytest.approx(1.2 * sk.lengths[thigh])


def test_bone_scaling_reads_kinect_v1_joint_names(mean_body):
    """v1 calls SpineBase/SpineMid/SpineShoulder HipCenter/Spine/ShoulderCenter: its spine segments scale too."""
    sk = mean_body.skeleton
    names1 = kinect_joint_names("v1")
    ix1 = {n: i for i, n in enumerate(names1)}
    K = kinect_joints(sk, sk.heads, sk.tails, "v1")
    # spine_01 is SpineBase -> SpineMid: move everything above SpineMid up with it
    K2 = K.copy()
    d = 0.1 * (K[ix1["Spine"]] - K[ix1["HipCenter"]])
    for n in names1:
        if n not in ("HipCenter", "HipLeft", "KneeLeft", "AnkleLeft", "FootLeft", "HipRight", "KneeRight",
                     "AnkleRight", "FootRight"):
            K2[ix1[n]] += d
    ratio = bone_scaled_body(mean_body, K2, None, "v1").skeleton.lengths / sk.lengths
    np.testing.assert_allclose(ratio[sk.index("spine_01")], 1.1, atol=1e-9)
    np.testing.assert_allclose(np.delete(ratio, sk.index("spine_01")), 1.0, atol=1e-9)


# --- vertex normals, transformation to the default pose ------------------------------------------------

def test_vertex_normals_are_area_weighted_face_normal_sums():
    # a vertex shared by a large triangle in the xy plane and a small one in the xz plane
    V = np.array([[0.0, 0, 0], [2, 0, 0], [0, 2, 0], [0, 0, -1], [1, 0, 0]])
    F = np.array([[0, 1, 2], [0, 3, 4]])
    N = _vertex_normals(V, F)
    big, small = np.array([0, 0, 4.0]), np.cross(V[3] - V[0], V[4] - V[0])
    expect = (big + small) / np.linalg.norm(big + small)
    np.testing.assert_allclose(N[0], expect, atol=1e-12)
    np.testing.assert_allclose(N[2], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(N[3], small / np.linalg.norm(small), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(N, axis=1), 1.0, atol=1e-12)


def test_inverse_lbs_undoes_the_lbs_of_the_ik_pose_exactly(mean_body):
    """Points on B^D posed by the IK's own pose: each matches its own vertex and returns to its rest position."""
    sk = mean_body.skeleton
    K = posed_kinect_joints(sk, _pose(sk))
    pose = ik_pose(sk, K, None, "v2")
    Vp = skin_vertices(mean_body.vertices, mean_body.weights, sk, pose)
    sub = np.arange(0, len(Vp), 3)
    cloud = transform_to_default_pose(Vp[sub], K, mean_body, scale_bones=False, details=True)
    np.testing.assert_array_equal(cloud.correspondence, sub)
    np.testing.assert_allclose(cloud.points, mean_body.vertices[sub], atol=1e-9)
    np.testing.assert_array_equal(cloud.candidates, np.arange(len(Vp)))
    np.testing.assert_allclose(cloud.pose.rotations, pose.rotations, atol=1e-12)
    assert cloud.body is mean_body
    # the plain call returns the same points
    np.testing.assert_array_equal(transform_to_default_pose(Vp[sub], K, mean_body, scale_bones=False), cloud.points)
    # the posed points themselves are far from the rest body
    assert np.median(np.linalg.norm(Vp[sub] - mean_body.vertices[sub], axis=1)) > 1.0


def test_default_pose_of_the_bone_scaled_body(mean_body):
    """With bone scaling (the default), P_0 lies on B_0^D (the Kinect skeleton's bone lengths), not on B_0^0."""
    sk = mean_body.skeleton
    K2, _ = _stretch_left_thigh(kinect_joints(sk, sk.heads, sk.tails), 1.25)
    BD = bone_scaled_body(mean_body, K2)
    # rotations that keep every Kinect segment's length (the whole body, single-bone limb segments)
    rot = np.zeros((sk.n_bones, 3))
    for bone, r in (("Root", (0.1, 0.5, -0.05)), ("thigh_l", (0.4, 0.0, 0.1)), ("calf_r", (-0.6, 0.0, 0.0)),
                    ("lowerarm_l", (0.0, 0.3, 0.5))):
        rot[sk.index(bone)] = r
    pose = Pose(rot, np.array([0.2, 0.0, 2.5]))
    K = posed_kinect_joints(BD.skeleton, pose)
    est = ik_pose(BD.skeleton, K, None, "v2")
    Vp = skin_vertices(BD.vertices, BD.weights, BD.skeleton, est)
    sub = np.arange(1, len(Vp), 4)
    cloud = transform_to_default_pose(Vp[sub], K, mean_body, details=True)
    np.testing.assert_allclose(cloud.body.vertices, BD.vertices, atol=1e-9)
    np.testing.assert_array_equal(cloud.correspondence, sub)
    np.testing.assert_allclose(cloud.points, BD.vertices[sub], atol=1e-9)
    assert np.abs(BD.vertices - mean_body.vertices).max() > 0.05


def test_points_off_the_body_are_rejected_and_back_vertices_are_not_candidates(mean_body):
    sk = mean_body.skeleton
    pose = Pose(np.zeros((sk.n_bones, 3)), np.array([0.0, 0.0, 0.0]))
    K = posed_kinect_joints(sk, pose)
    V = mean_body.vertices
    N = _vertex_normals(V, mean_body.faces)
    front = np.flatnonzero(N[:, 2] > 0.9)[:50]
    P = np.concatenate([V[front] + 0.06 * N[front], V[front] + 0.10 * N[front]])
    cloud = transform_to_default_pose(P, K, mean_body, scale_bones=False, details=True)
    # the pose is the rest pose: P_0 = P for the kept points
    kept = np.isfinite(cloud.points).all(1)
    assert kept[:50].all() and 20 < (~kept[50:]).sum() < 50
    np.testing.assert_array_equal(cloud.correspondence[~kept], -1)
    assert (cloud.correspondence[kept] >= 0).all()
    np.testing.assert_allclose(cloud.points[:50], P[:50], atol=1e-9)
    np.testing.assert_array_equal(kept, cKDTree(V).query(P)[0] <= 0.08)
    # a looser limit keeps them all
    loose = transform_to_default_pose(P, K, mean_body, scale_bones=False, max_distance_m=0.5)
    assert np.isfinite(loose).all()
    # a depth camera 3 m in front (+z): only vertices facing it are candidates; a point behind the body
    # matches a front vertex
    eye = np.array([0.0, 1.0, 3.0])
    cloud = transform_to_default_pose(P[:50], K, mean_body, scale_bones=False, view_point=eye, details=True)
    ray = eye - V
    cos = np.einsum("nd,nd->n", N, ray) / np.linalg.norm(ray, axis=1)
    np.testing.assert_array_equal(cloud.candidates, np.flatnonzero(cos > 0))
    assert 0.3 < len(cloud.candidates) / len(V) < 0.7
    tight = transform_to_default_pose(P[:50], K, mean_body, scale_bones=False, view_point=eye, details=True,
                                      min_facing_cos=0.5)
    np.testing.assert_array_equal(tight.candidates, np.flatnonzero(cos > 0.5))
    back = np.flatnonzero(N[:, 2] < -0.9)[:20]
    behind = transform_to_default_pose(V[back], K, mean_body, scale_bones=False, view_point=eye, details=True,
                                       max_distance_m=1.0)
    assert np.isin(behind.correspondence, cloud.candidates).all()
    assert not np.isin(back, cloud.candidates).any()
    with pytest.raises(InputError, match=r"must be \(N, 3\)"):
        transform_to_default_pose(P[:, :2], K, mean_body)


def test_unposed_kinect_joints_land_on_the_rest_skeletons(mean_body):
    sk = mean_body.skeleton
    pose = _pose(sk, seed=2)
    K = posed_kinect_joints(sk, pose)
    rest = kinect_joints(sk, sk.heads, sk.tails)
    tracked = np.ones(len(NAMES), bool)
    tracked[IX["KneeRight"]] = False
    K[IX["ElbowLeft"]] = np.nan
    out = unposed_kinect_joints(K, tracked, sk, pose)
    wanted = np.array([n in SHAPE_JOINTS for n in NAMES]) & tracked
    wanted[IX["ElbowLeft"]] = False
    np.testing.assert_allclose(out[wanted], rest[wanted], atol=1e-9)
    assert np.isnan(out[~wanted]).all()
    assert {NAMES[i] for i in np.flatnonzero(~wanted)} == {"KneeRight", "ElbowLeft", "HandLeft", "HandRight",
                                                         "HandTipLeft", "ThumbLeft", "HandTipRight", "ThumbRight"}
    # v1 names
    K1 = posed_kinect_joints(sk, pose, "v1")
    out1 = unposed_kinect_joints(K1, None, sk, pose, "v1")
    rest1 = kinect_joints(sk, sk.heads, sk.tails, "v1")
    names1 = kinect_joint_names("v1")
    for n in ("HipCenter", "Spine", "ShoulderCenter", "Head", "KneeLeft"):
        np.testing.assert_allclose(out1[names1.index(n)], rest1[names1.index(n)], atol=1e-9)


# --- Eq. 2 shape fit -----------------------------------------------------------------------------------

def _dense_eq2(model, P, m, prior, joint_rows=None):
    """Eq. 2 + the Gaussian prior as one dense least-squares problem over (coeffs, translation)."""
    k = model.n_components
    A = np.concatenate([model.basis[:, m].reshape(k, -1).T, np.tile(np.eye(3), (len(m), 1))], axis=1)
    b = (P - model.mean[m]).ravel()
    rows = [A, np.hstack([np.diag(np.sqrt(prior)), np.zeros((k, 3))])]
    rhs = [b, np.zeros(k)]
    if joint_rows is not None:
        rows.append(joint_rows[0])
        rhs.append(joint_rows[1])
    x = np.linalg.lstsq(np.concatenate(rows), np.concatenate(rhs), rcond=None)[0]
    return x[:k], x[k:]


def test_eq2_normal_equations_equal_the_dense_least_squares_solve(model):
    """Fixed matches, some vertices matched several times, a strong prior: the accumulated normal equations
    give the dense solve's coefficients and residual."""
    rng = np.random.default_rng(3)
    c_true = _planted_coeffs(model)
    m = np.concatenate([np.arange(0, len(model.mean), 5), rng.integers(0, len(model.mean), 300)])
    P = model.vertices(c_true)[m] + np.array([0.03, -0.02, 0.05]) + rng.normal(0, 0.01, (len(m), 3))
    sigma = 0.05
    c, residual = fit_shape(P, model, correspondence=m, iterations=1, point_sigma_m=sigma, return_residual=True)
    c_ref, t_ref = _dense_eq2(model, P, m, sigma**2 / model.stddev**2)
    np.testing.assert_allclose(c, c_ref, atol=1e-8 * model.stddev.max())
    r_ref = np.median(np.linalg.norm(P - t_ref - model.vertices(c_ref)[m], axis=1))
    assert residual == pytest.approx(r_ref, rel=1e-9)
    # the prior matters here: without it the coefficients differ
    c_free, _ = _dense_eq2(model, P, m, np.zeros(model.n_components))
    assert np.max(np.abs(c_free - c_ref) / model.stddev) > 0.5
    assert fit_shape(P, model, correspondence=m, iterations=1, point_sigma_m=sigma).shape == c.shape


def test_eq2_recovers_planted_coefficients_and_translation(model):
    c_true = _planted_coeffs(model, seed=5)
    t_true = np.array([0.02, -0.01, 0.03])
    P = model.vertices(c_true) + t_true
    m = np.arange(len(P))
    c, residual = fit_shape(P, model, correspondence=m, iterations=1, point_sigma_m=1e-7, return_residual=True)
    np.testing.assert_allclose(c, c_true, atol=1e-6 * model.stddev.max())
    assert residual < 1e-7
    # noise-free closest-point matching from the planted shape's own vertices (no correspondence given)
    c2 = fit_shape(P - t_true, model, init_coeffs=c_true, iterations=1, point_sigma_m=1e-7)
    np.testing.assert_allclose(c2, c_true, atol=1e-6 * model.stddev.max())
    # from the mean shape the first closest-point match is wrong: one iteration does not get there
    c3 = fit_shape(P - t_true, model, iterations=1, point_sigma_m=1e-7)
    assert np.abs(c3 - c_true).max() > 1e-3 * model.stddev.max()
    # the init coefficients are not modified
    c0 = c_true.copy()
    fit_shape(P - t_true, model, init_coeffs=c0, iterations=2)
    np.testing.assert_array_equal(c0, c_true)


def test_eq2_trims_outliers_after_the_first_match_and_drops_nan_and_unmatched(model):
    rng = np.random.default_rng(6)
    c_true = _planted_coeffs(model, seed=6)
    V = model.vertices(c_true)
    m = np.arange(0, len(V), 2)
    P = V[m].copy()
    P[::25] += rng.normal(0, 1, (len(P[::25]), 3)) * 0.02 + np.array([0.0, 0.0, 0.3])  # outliers 30 cm off
    given = m.copy()
    P[1] = np.nan
    given[3] = -1
    P[3] += 5.0  # an unmatched point would wreck the first solve
    c = fit_shape(P, model, init_coeffs=c_true, correspondence=given, iterations=5, point_sigma_m=1e-7,
                  trim_m=0.05)
    np.testing.assert_allclose(c, c_true, atol=1e-6 * model.stddev.max())
    # without trimming (a limit above the outliers' distance) the fit is pulled off
    c_loose = fit_shape(P, model, init_coeffs=c_true, correspondence=given, iterations=5, point_sigma_m=1e-7,
                        trim_m=1.0)
    assert np.abs(c_loose - c_true).max() > 0.01 * model.stddev.max()
    with pytest.raises(InputError, match="at least 10 points"):
        fit_shape(np.full((20, 3), np.nan), model)


def test_eq2_matches_only_candidate_vertices(model):
    c_true = _planted_coeffs(model, seed=7)
    V = model.vertices(c_true)
    cand = np.arange(0, len(V), 2)
    # points on the non-candidate vertices: their closest candidates are other vertices, so the exact answer
    # comes out only if the candidates are used to match ... and the candidate points themselves are exact
    c = fit_shape(V[cand], model, init_coeffs=c_true, candidates=cand, iterations=2, point_sigma_m=1e-7)
    np.testing.assert_allclose(c, c_true, atol=1e-6 * model.stddev.max())
    P = V[1::2]
    d_all = cKDTree(V).query(P)[0]
    assert d_all.max() < 1e-12
    c_odd = fit_shape(P, model, init_coeffs=c_true, candidates=cand, iterations=1, point_sigma_m=1e-7)
    assert np.abs(c_odd - c_true).max() > 1e-4 * model.stddev.max()


def test_eq2_joint_rows_weigh_joint_weight(model):
    """Unposed Kinect joints enter Eq. 2 as sqrt(w)-weighted rows of the (linear) model joints; NaN joints
    and frames are skipped."""
    rng = np.random.default_rng(8)
    c_true = _planted_coeffs(model, seed=8)
    m = np.arange(0, len(model.mean), 7)
    P = model.vertices(c_true)[m] + rng.normal(0, 0.01, (len(m), 3))
    Jm, Jb = _model_kinect_joints(model, "v2")
    # the joints are linear in the shape: mean + coeffs @ basis equals the skeleton's Kinect joints
    sk_true = model.skeleton(c_true)
    np.testing.assert_allclose(Jm + np.einsum("k,kjd->jd", c_true, Jb),
                               kinect_joints(sk_true, sk_true.heads, sk_true.tails), atol=1e-9)
    Jd = np.stack([Jm + np.einsum("k,kjd->jd", c_true, Jb) + 0.02 for _ in range(2)])
    Jd += rng.normal(0, 0.01, Jd.shape)
    Jd[0, 3] = np.nan
    Jd[1, :5] = np.nan
    w, sigma = 25.0, 0.03
    c = fit_shape(P, model, correspondence=m, iterations=1, joints_default=Jd, joint_weight=w,
                  point_sigma_m=sigma)
    f, j = np.nonzero(np.isfinite(Jd).all(2))
    k = model.n_components
    rows = np.sqrt(w) * np.hstack([Jb[:, j].reshape(k, -1).T, np.tile(np.eye(3), (len(j), 1))])
    rhs = np.sqrt(w) * (Jd[f, j] - Jm[j]).ravel()
    c_ref, _ = _dense_eq2(model, P, m, sigma**2 / model.stddev**2, (rows, rhs))
    np.testing.assert_allclose(c, c_ref, atol=1e-8 * model.stddev.max())
    c_none = fit_shape(P, model, correspondence=m, iterations=1, point_sigma_m=sigma)
    assert np.abs(c_none - c_ref).max() > 0.01 * model.stddev.max()
    # joint_weight 0 ignores them
    np.testing.assert_array_equal(fit_shape(P, model, correspondence=m, iterations=1, joints_default=Jd,
                                            joint_weight=0.0, point_sigma_m=sigma), c_none)
    # v1 joints: the v1 model joints
    Jm1, Jb1 = _model_kinect_joints(model, "v1")
    assert Jm1.shape == (len(kinect_joint_names("v1")), 3) and Jb1.shape[0] == k


def test_eq2_symmetric_term_pulls_unsupported_model_parts(model):
    """model -> data pairs (symmetric): candidate vertices within trim_m of a data point pull toward it; on
    exact data it changes nothing, on data missing a region it adds those pairs."""
    c_true = _planted_coeffs(model, seed=9)
    V = model.vertices(c_true)
    c = fit_shape(V, model, init_coeffs=c_true, symmetric=True, iterations=2, point_sigma_m=1e-7)
    np.testing.assert_allclose(c, c_true, atol=1e-6 * model.stddev.max())
    sub = np.arange(0, len(V), 3)
    a = fit_shape(V[sub] + 0.004, model, init_coeffs=c_true, iterations=2, point_sigma_m=0.02)
    b = fit_shape(V[sub] + 0.004, model, init_coeffs=c_true, iterations=2, point_sigma_m=0.02, symmetric=True)
    assert np.abs(a - b).max() > 1e-3 * model.stddev.max()


# --- Eq. 3 skeleton refit ------------------------------------------------------------------------------

def test_eq3_moves_each_joint_by_the_mean_displacement_of_its_12_nearest_vertices(model):
    sk0 = init_mod._default_skeleton(model)
    np.testing.assert_array_equal(sk0.heads, model.joint_mean_heads)
    heads_nb, tails_nb = joint_neighbourhoods(model.mean, sk0)
    assert heads_nb.shape == (sk0.n_bones, 12) and tails_nb.shape == (sk0.n_bones, 12)
    d = np.linalg.norm(model.mean[None] - sk0.heads[:, None], axis=2)
    np.testing.assert_allclose(np.sort(d, axis=1)[:, :12], np.take_along_axis(d, heads_nb, 1), atol=1e-12)
    dt = np.linalg.norm(model.mean[None] - sk0.tails[:, None], axis=2)
    np.testing.assert_allclose(np.sort(dt, axis=1)[:, :12], np.take_along_axis(dt, tails_nb, 1), atol=1e-12)
    # an affine displacement field D(v) = M v + d moves a joint by M mean(v_nb) + d
    M = np.array([[0.05, 0.01, 0.0], [0.0, -0.03, 0.02], [0.01, 0.0, 0.04]])
    off = np.array([0.1, -0.2, 0.3])
    V = model.mean + model.mean @ M.T + off
    sk = refit_skeleton_from_vertices(model.mean, sk0, V)
    np.testing.assert_allclose(sk.heads, sk0.heads + model.mean[heads_nb].mean(1) @ M.T + off, atol=1e-12)
    np.testing.assert_allclose(sk.tails, sk0.tails + model.mean[tails_nb].mean(1) @ M.T + off, atol=1e-12)
    assert sk.bone_names == sk0.bone_names and np.array_equal(sk.parents, sk0.parents)
    np.testing.assert_array_equal(sk.rolls, sk0.rolls)
    # refit_skeleton: the statistical model's shape, the default neighbourhoods
    c = _planted_coeffs(model, seed=10)
    D = model.vertices(c) - model.mean
    sk_c = refit_skeleton(model, c)
    np.testing.assert_allclose(sk_c.heads, sk0.heads + D[heads_nb].mean(1), atol=1e-12)
    np.testing.assert_allclose(sk_c.tails, sk0.tails + D[tails_nb].mean(1), atol=1e-12)
    np.testing.assert_allclose(refit_skeleton(model, np.zeros(model.n_components)).heads, sk0.heads, atol=1e-12)
    # a source body's neighbourhoods are its own
    src = SourceBody(c, model.vertices(c), sk_c, (0,), 1.0)
    hn, tn = src.joint_neighbourhoods
    np.testing.assert_array_equal(hn, joint_neighbourhoods(src.vertices, sk_c)[0])
    np.testing.assert_array_equal(tn, joint_neighbourhoods(src.vertices, sk_c)[1])


# --- the whole initialisation --------------------------------------------------------------------------

def _frame_of(model, c, pose, eye, keep_every=1, frame=0, version="v2"):
    """Noise-free depth of the planted body ``c`` in ``pose``: its vertices facing ``eye``, and its Kinect joints."""
    body = model.body(c)
    sk = body.skeleton
    V = skin_vertices(body.vertices, body.weights, sk, pose)
    N = _vertex_normals(V, body.faces)
    facing = np.einsum("nd,nd->n", N, eye - V) > 0.3 * np.linalg.norm(eye - V, axis=1)
    P = V[np.flatnonzero(facing)[::keep_every]]
    K = posed_kinect_joints(sk, pose, version)
    return InitObservation(frame, P, K, np.ones(len(K), bool), version)


def test_initialisation_recovers_a_planted_shape_from_noise_free_frames(model):
    """Two noise-free frames of a planted shape 8 cm (median vertex) from the mean: the second pass (matches
    from the first pass's shape, unposed joints) improves on the first."""
    c_true = _planted_coeffs(model, seed=14, scale=1.5)
    sk = model.skeleton(c_true)
    eye = np.array([0.0, 1.0, 3.0])
    obs = [_frame_of(model, c_true, Pose(np.random.default_rng(s).normal(0, 0.05, (sk.n_bones, 3)),
                                         np.array([0.0, 0.0, 0.2 * s])), eye, frame=s) for s in range(2)]
    truth = model.vertices(c_true)
    src = initialise_from_observations(obs, model, view_point=eye, passes=2)
    err = np.median(np.linalg.norm(src.vertices - truth, axis=1))
    one = initialise_from_observations(obs, model, view_point=eye, passes=1)
    err_one = np.median(np.linalg.norm(one.vertices - truth, axis=1))
    # measured (2k model, front only): 36.7 mm after two passes, 58.0 mm after one; the mean shape is 78.9 mm off
    assert err < 0.042 and err_one > 0.05
    assert np.median(np.linalg.norm(model.mean - truth, axis=1)) > 0.075
    np.testing.assert_allclose(src.vertices, model.vertices(src.coeffs), atol=1e-12)
    # the source body carries the model's own joints for its coefficients (tests/mirror/test_init_skeleton.py)
    np.testing.assert_allclose(src.skeleton.heads, model.skeleton(src.coeffs).heads, atol=1e-12)
    assert src.frames_used == (0, 1) and src.weights is model.weights and src.faces is model.faces
    # measured 11.0 mm (the unposed points of a body that is not B^D lie off its surface)
    assert 5.0 < src.residual_mm < 14.0


def test_initialisation_uses_the_frames_with_most_points_and_drops_the_floor(model):
    c_true = _planted_coeffs(model, seed=12)
    sk = model.skeleton(c_true)
    eye = np.array([0.0, 1.0, 3.0])
    rest = Pose(np.zeros((sk.n_bones, 3)), np.zeros(3))
    obs = [_frame_of(model, c_true, rest, eye, keep_every=k, frame=f) for f, k in zip((5, 6, 7, 8), (3, 1, 4, 2),
                                                                                     strict=True)]
    src = initialise_from_observations(obs, model, view_point=eye, passes=1, max_frames=2)
    assert src.frames_used == (6, 8)
    # a frame whose points all lie on the floor (below floor_y + margin) is not used
    floor = InitObservation(9, np.column_stack([np.linspace(-1, 1, 2000), np.full(2000, 0.01), np.ones(2000)]),
                            obs[0].joints, obs[0].tracked, "v2")
    src = initialise_from_observations([obs[0], floor], model, view_point=eye, passes=1)
    assert src.frames_used == (5,)
    with pytest.raises(InputError, match="stand fully in view"):
        initialise_from_observations([floor], model, passes=1)
    # floor_y None keeps them (and then they lie far from the body: refused with the calibration message)
    with pytest.raises(InputError, match="^no frame's depth points lie on a body fitted to the Kinect joints: check "
                       "that the depth and the joints come from the same sensor calibration$"):
        initialise_from_observations([floor], model, passes=1, floor_y=None)
    # a frame of fewer than MIN_POINTS finite points is not used
    few = InitObservation(3, obs[1].points[:MIN_POINTS - 1], obs[1].joints, obs[1].tracked, "v2")
    nan = InitObservation(4, np.full((MIN_POINTS + 5, 3), np.nan), obs[1].joints, obs[1].tracked, "v2")
    assert initialise_from_observations([few, nan, obs[0]], model, view_point=eye, passes=1).frames_used == (5,)


def test_subsample_is_a_seeded_subset():
    P = np.arange(300.0).reshape(100, 3)
    assert _subsample(P, 100, 0) is P
    a, b, c = _subsample(P, 10, 1), _subsample(P, 10, 1), _subsample(P, 10, 2)
    np.testing.assert_array_equal(a, b)
    assert len(a) == 10 and len({tuple(r) for r in a}) == 10 and not np.array_equal(a, c)
    assert np.isin(a[:, 0], P[:, 0]).all()
    most = _subsample(P, 95, 3)
    assert len(np.unique(most[:, 0])) == 95  # without replacement


def test_check_model_refuses_other_models_and_rigs(model, mean_body):
    assert check_model(model) is model
    with pytest.raises(InputError, match="needs a StatisticalBodyModel.*got BodyModel"):
        check_model(mean_body)
    import dataclasses

    with pytest.raises(InputError, match="game_engine rig.*got rig 'default'"):
        check_model(dataclasses.replace(model, rig="default"))


def test_source_body_poses_only_with_weights(model):
    c = np.zeros(model.n_components)
    src = SourceBody(c, model.vertices(c), refit_skeleton(model, c), (0,), 1.0)
    with pytest.raises(InputError, match="^this source body carries no skin weights; load it with its statistical "
                       "model$"):
        src.body()
    full = SourceBody(c, model.vertices(c), src.skeleton, (0,), 1.0, model.weights, model.faces)
    b = full.body()
    assert b.rig == "game_engine" and b.weights is model.weights and b.faces is model.faces
    assert b.skeleton is src.skeleton
    np.testing.assert_array_equal(b.vertices, full.vertices)


def test_source_body_file_round_trip_and_refusals(model, tmp_path):
    c = _planted_coeffs(model, seed=13)
    src = SourceBody(c, model.vertices(c), refit_skeleton(model, c), (3, 6, 9), 4.25)
    path = tmp_path / "src.npz"
    save_source_body(path, src)
    back = load_source_body(path)
    np.testing.assert_array_equal(back.coeffs, c)
    np.testing.assert_array_equal(back.vertices, src.vertices)
    for a in ("heads", "tails", "rolls", "parents"):
        np.testing.assert_array_equal(getattr(back.skeleton, a), getattr(src.skeleton, a))
    assert back.skeleton.bone_names == src.skeleton.bone_names
    assert back.frames_used == (3, 6, 9) and back.residual_mm == 4.25 and back.weights is None
    assert back.skeleton.parents.dtype == np.int64
    with_model = load_source_body(path, model)
    assert with_model.weights is model.weights and with_model.faces is model.faces
    np.testing.assert_array_equal(with_model.coeffs, c)
    np.testing.assert_array_equal(with_model.vertices, src.vertices)
    np.testing.assert_array_equal(with_model.skeleton.heads, src.skeleton.heads)
    assert with_model.frames_used == (3, 6, 9) and with_model.residual_mm == 4.25

    def write(name, **changes):
        sk = src.skeleton
        arrays = dict(version=np.array(1), coeffs=c, vertices=src.vertices, bone_names=np.array(sk.bone_names),
                      parents=sk.parents, heads=sk.heads, tails=sk.tails, rolls=sk.rolls,
                      frames_used=np.array([3]), residual_mm=np.array(1.0))
        arrays.update(changes)
        p = tmp_path / name
        np.savez(p, **arrays)
        return p

    assert load_source_body(write("ok.npz")).frames_used == (3,)
    with pytest.raises(FileFormatError, match=r"nope\.npz: source body not found; run 'bodystudio mirror init SESSION' "
                       "first$"):
        load_source_body(tmp_path / "nope.npz")
    # a pickled (object) array is never unpickled
    with pytest.raises(FileFormatError, match="not a readable source body"):
        load_source_body(write("pickled.npz", bone_names=np.array(list(src.skeleton.bone_names), dtype=object)))
    # a destination without the .npz extension still gets one zip file (numpy appends .npz to bare names)
    save_source_body(tmp_path / "source_body", src)
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(("source_body", ".source_body"))] == ["source_body"]
    np.testing.assert_array_equal(load_source_body(tmp_path / "source_body").coeffs, c)
    with pytest.raises(FileFormatError, match="version 2, expected 1"):
        load_source_body(write("v2.npz", version=np.array(2)))
    with pytest.raises(FileFormatError, match="not a readable source body"):
        load_source_body(_drop(write("k.npz"), "heads"))
    bad = {"vertices": src.vertices[:, :2], "heads": src.skeleton.heads[:-1], "tails": src.skeleton.tails[:-1],
           "parents": src.skeleton.parents[:-1], "rolls": src.skeleton.rolls[:-1]}
    for key, value in bad.items():
        with pytest.raises(FileFormatError, match="inconsistent"):
            load_source_body(write(f"bad_{key}.npz", **{key: value}))
    nan_v = src.vertices.copy()
    nan_v[0, 0] = np.nan
    nan_c = c.copy()
    nan_c[0] = np.inf
    for name, kw in (("nan_v.npz", {"vertices": nan_v}), ("nan_c.npz", {"coeffs": nan_c})):
        with pytest.raises(FileFormatError, match="inconsistent"):
            load_source_body(write(name, **kw))
    with pytest.raises(InputError, match="another statistical model.*3 coefficients"):
        load_source_body(write("fewc.npz", coeffs=c[:3]), model)
    with pytest.raises(InputError, match="another statistical model"):
        load_source_body(write("fewv.npz", vertices=src.vertices[:-1]), model)
    renamed = np.array(list(src.skeleton.bone_names[:-1]) + ["other"])
    with pytest.raises(InputError, match="another statistical model"):
        load_source_body(write("names.npz", bone_names=renamed), model)


def _drop(path, key):
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files if k != key}
    np.savez(path, **arrays)
    return path


def test_lbs_round_trip_helper_is_exact(mean_body):
    """The inverse LBS used by §4 undoes linear_blend_skinning (the identity the initialisation rests on)."""
    from bodystudio.body.skinning import inverse_linear_blend_skinning

    sk = mean_body.skeleton
    S = skinning_transforms(sk, _pose(sk, seed=5))
    Vp = linear_blend_skinning(mean_body.vertices, mean_body.weights, S)
    np.testing.assert_allclose(inverse_linear_blend_skinning(Vp, mean_body.weights, S), mean_body.vertices,
                               atol=1e-9)


# --- reading a session (collect_observations) with stand-in frames ----------------------------------------

class _Session:
    def __init__(self, n, kinect=True):
        self.path = "SESSION"
        self.frame_ids = list(range(n))
        self.kinect = SimpleNamespace(depth=SimpleNamespace(center=np.array([0.0, 1.0, 3.0]))) if kinect else None


def _fake_frames(monkeypatch, frames, n_points=MIN_POINTS):
    """Make read_mirror_frame / point_cloud serve ``frames`` {index: (bodies, depth)}; returns the read log."""
    from bodystudio.mirror import frames as frames_mod

    reads = []

    def read(session, i):
        assert isinstance(session, _Session)
        reads.append(i)
        bodies, depth = frames.get(i, ([], np.ones((2, 2))))
        player = np.zeros(np.shape(depth), np.uint8)  # the SDK's player mask: every body's label in one row
        player.flat[: len(bodies)] = [b.player for b in bodies]
        return SimpleNamespace(index=i, bodies=bodies, depth_m=depth, player=player)

    def cloud(frame, sensor, player):
        assert sensor is not None and sensor.depth is not None
        n = n_points(frame.index) if callable(n_points) else n_points
        return np.full((n, 3), float(frame.index) + 0.01 * player)

    monkeypatch.setattr(frames_mod, "read_mirror_frame", read)
    monkeypatch.setattr(frames_mod, "point_cloud", cloud)
    return reads


def _tracked_body(player=1, version="v2", all_nan=False):
    names = kinect_joint_names(version)
    K = np.full((len(names), 3), np.nan) if all_nan else np.arange(3.0 * len(names)).reshape(-1, 3) + player
    tracked = np.ones(len(names), bool)
    if not all_nan:  # one joint not reported (the SDK's NaN) does not make the body unusable
        K[-1] = np.nan
        tracked[-1] = False
    return SimpleNamespace(player=player, names=tuple(names), positions=K, tracked=tracked)


def test_collect_observations_reads_every_stride_th_frame_from_the_first_seen(monkeypatch):
    from bodystudio.mirror.init import collect_observations

    frames = {i: ([_tracked_body(1), _tracked_body(2)], np.ones((2, 2))) for i in range(2, 30)}
    reads = _fake_frames(monkeypatch, frames)
    obs, sensor = collect_observations(_Session(30), n_frames=7, stride=3)
    assert [o.frame for o in obs] == [2, 5, 8] and reads == [0, 1, 2, 5, 8]
    assert sensor is not None and all(o.version == "v2" for o in obs)
    np.testing.assert_array_equal(obs[0].joints, _tracked_body(1).positions)
    np.testing.assert_array_equal(obs[0].tracked, _tracked_body(1).tracked)
    np.testing.assert_array_equal(obs[0].points, np.full((MIN_POINTS, 3), 2.01))
    # the SDK's player mask in the depth image: this player's pixels, and the other players' (MIR12i)
    np.testing.assert_array_equal(obs[0].player_mask, [[True, False], [False, False]])
    np.testing.assert_array_equal(obs[0].others_depth, [[False, True], [False, False]])
    # another player, and exactly the given frames (no stride, no window)
    reads.clear()
    obs, _ = collect_observations(_Session(30), frames=[3, 4, 20], player=2, n_frames=2, stride=5)
    assert [o.frame for o in obs] == [3, 4, 20] and reads == [3, 4, 20]
    np.testing.assert_array_equal(obs[1].points, np.full((MIN_POINTS, 3), 4.02))
    np.testing.assert_array_equal(obs[1].joints, _tracked_body(2).positions)
    np.testing.assert_array_equal(obs[1].player_mask, [[False, True], [False, False]])
    np.testing.assert_array_equal(obs[1].others_depth, [[True, False], [False, False]])
    # stride 0 or negative reads every frame
    obs, _ = collect_observations(_Session(30), n_frames=4, stride=0)
    assert [o.frame for o in obs] == [2, 3, 4, 5]
    # the defaults: 90 frames, every third
    obs, _ = collect_observations(_Session(30))
    assert [o.frame for o in obs] == list(range(2, 30, 3))


def test_collect_observations_skips_frames_and_says_why_none_was_usable(monkeypatch):
    from bodystudio.mirror.init import collect_observations

    ok = ([_tracked_body(1)], np.ones((2, 2)))
    frames = {0: ([_tracked_body(2)], np.ones((2, 2))),  # only another player: no joints for ours
              1: ([_tracked_body(1, all_nan=True)], np.ones((2, 2))),  # no joints
              2: ([_tracked_body(1)], None),  # no depth
              3: ([_tracked_body(1)], np.zeros((2, 2))),  # no depth
              4: ok, 5: ok}
    _fake_frames(monkeypatch, frames, n_points=lambda i: MIN_POINTS - 1 if i == 5 else MIN_POINTS)
    obs, _ = collect_observations(_Session(6), frames=range(6))
    assert [o.frame for o in obs] == [4]
    # a frame of too few points does not end the window
    _fake_frames(monkeypatch, {i: ok for i in range(6)}, n_points=lambda i: MIN_POINTS - 1 if i == 1 else MIN_POINTS)
    assert [o.frame for o in collect_observations(_Session(6), stride=1)[0]] == [0, 2, 3, 4, 5]
    nobody = ([], np.ones((2, 2)))
    few = ok
    person = "player 1 is in none of the frames \\(no tracked body or too few depth pixels in its player mask\\)"
    joints = "no frame has tracked Kinect joints for player 1"
    depth = "no frame has depth measurements"
    # the most frequent reason is named (ties: person, joints, depth in that order)
    cases = [([nobody], person),
             ([frames[1]] * 4, joints),
             ([frames[0]] * 4, joints),
             ([frames[2], frames[3], frames[0]], depth),
             ([few] * 2, person),
             ([few], person),
             ([nobody, nobody, frames[2], frames[2]], person),
             ([frames[1], frames[1], frames[2], frames[2]], joints),
             ([frames[0], frames[0], frames[2], frames[2]], joints),
             ([frames[1], frames[2], frames[2]], depth),
             ([frames[0], frames[2]], joints),
             ([frames[2], nobody], person),
             ([few, few, frames[2], frames[2]], person),
             ([few, frames[2], frames[2]], depth)]
    for content, phrase in cases:
        _fake_frames(monkeypatch, dict(enumerate(content)), n_points=lambda i: MIN_POINTS - 1)
        with pytest.raises(InputError, match=f"^SESSION: cannot initialise the source body: {phrase}; record the "
                           "actor standing in view, or pick --frames/--player$"):
            collect_observations(_Session(len(content)), frames=range(len(content)))
    with pytest.raises(InputError, match="^SESSION: no Kinect calibration \\(kinect/calibration.json\\); the mirror "
                       "needs a Kinect RGB-D session$"):
        collect_observations(_Session(4, kinect=False))
    with pytest.raises(InputError, match="no frames to initialise from"):
        collect_observations(_Session(4), frames=[])
    with pytest.raises(InputError, match=r"frame\(s\) \[7, 9\] not in the session \(it has 4 frames\)"):
        collect_observations(_Session(4), frames=[9, 1, 7])
    with pytest.raises(InputError, match=r"frame\(s\) \[4, 5, 6, 7, 8\] not in"):
        collect_observations(_Session(4), frames=range(10))


def test_session_version_from_the_joint_names(monkeypatch):
    from bodystudio.mirror.init import _session_version, collect_observations

    assert _session_version(kinect_joint_names("v2")) == "v2"
    assert _session_version(tuple(kinect_joint_names("v1"))) == "v1"
    with pytest.raises(InputError, match=r"named \['a', 'b', 'c'\]\.\.\. match neither"):
        _session_version(["a", "b", "c", "d"])
    _fake_frames(monkeypatch, {0: ([_tracked_body(1, "v1")], np.ones((2, 2)))})
    obs, _ = collect_observations(_Session(1))
    assert obs[0].version == "v1"


def test_initialise_source_body_passes_the_depth_camera_and_passes(monkeypatch, model):
    calls = {}

    def collect(session, frames, player, n_frames, silhouettes=False):
        calls["collect"] = (frames, player, n_frames)
        calls["silhouettes"] = silhouettes
        return ["obs"], session.kinect

    def fit(obs, m, view_point=None, passes=3, camera=None, silhouette_frames=0, depth_camera=None,
            bone_length_weight=None, trunk_refit=None, unpose_posture_bones=None, bone_length_pairs="unset",
            knee_frames=None):
        calls["fit"] = (obs, m, view_point, passes)
        calls["bone_length_pairs"] = bone_length_pairs
        calls["knee_frames"] = knee_frames
        calls["trunk_refit"] = trunk_refit
        calls["unpose_posture_bones"] = unpose_posture_bones
        calls["silhouette"] = (camera, silhouette_frames)
        calls["depth_camera"] = depth_camera
        calls["bone_length_weight"] = bone_length_weight
        return "source"

    monkeypatch.setattr(init_mod, "collect_observations", collect)
    monkeypatch.setattr(init_mod, "initialise_from_observations", fit)
    monkeypatch.setattr(init_mod, "knee_joint_frames", lambda session, obs: ("joints of", obs))
    session = _Session(3)
    assert init_mod.initialise_source_body(session, model, frames=[1], player=2, n_frames=5, passes=1) == "source"
    assert calls["knee_frames"] == ("joints of", ["obs"])  # mir12ac: the knee angle over the window's joints files
    assert calls["collect"] == ([1], 2, 5)
    assert calls["fit"][0] == ["obs"] and calls["fit"][1] is model and calls["fit"][3] == 1
    np.testing.assert_array_equal(calls["fit"][2], [0.0, 1.0, 3.0])
    assert calls["depth_camera"] is session.kinect.depth  # the refined unposing's camera (MIR12i)
    assert calls["silhouettes"] is False and calls["silhouette"] == (None, 0)  # MIR12c's refinement off by default
    assert calls["bone_length_weight"] == 0.0  # MIR12o's joint distances off by default
    assert calls["bone_length_pairs"] is None  # every pair when the term is asked for (mir12ad's pairs: an option)
    assert calls["trunk_refit"] is False  # MIR12r's trunk refit off by default
    # mir12v's posture: on by default since mir12y, off when asked
    assert calls["unpose_posture_bones"] == ("spine_02", "neck_01", "head") == init_mod.UNPOSE_POSTURE_BONES
    init_mod.initialise_source_body(session, model, unpose_posture=True)
    assert calls["unpose_posture_bones"] == ("spine_02", "neck_01", "head") == init_mod.POSTURE_BONES
    init_mod.initialise_source_body(session, model, unpose_posture=False)
    assert calls["unpose_posture_bones"] == ()
    init_mod.initialise_source_body(session, model, bone_length_weight=1.5)
    assert calls["bone_length_weight"] == 1.5
    init_mod.initialise_source_body(session, model, bone_length_weight=3.0,
                                    bone_length_pairs=init_mod.STATURE_BONE_PAIRS)
    assert calls["bone_length_weight"] == 3.0 and calls["bone_length_pairs"] == init_mod.STATURE_BONE_PAIRS
    init_mod.initialise_source_body(session, model, trunk_refit=True)
    assert calls["trunk_refit"] is True
    monkeypatch.setattr(init_mod, "KNEE_HINGE_WEIGHT", 0.0)  # no knee rows: no joints files read
    init_mod.initialise_source_body(session, model)
    assert calls["knee_frames"] is None
    monkeypatch.setattr(init_mod, "KNEE_HINGE_WEIGHT", 3000.0)
    init_mod.initialise_source_body(session, model)
    assert calls["collect"] == (None, 1, init_mod.DEFAULT_INIT_FRAMES) and calls["fit"][3] == init_mod.INIT_PASSES == 5
    session.kinect.color = "colour camera"
    init_mod.initialise_source_body(session, model, silhouette_shape=True)
    assert calls["silhouettes"] is True and calls["silhouette"] == ("colour camera", init_mod.SILHOUETTE_FRAMES)
    with pytest.raises(InputError, match="StatisticalBodyModel"):
        init_mod.initialise_source_body(session, "not a model")


def test_time_init_and_track_reports_per_frame_means(monkeypatch, model):
    """With a stand-in clock: the initialisation's seconds and the IK / skinning milliseconds per frame."""
    c = np.zeros(model.n_components)
    source = SourceBody(c, model.mean, refit_skeleton(model, c), (0, 3, 6), 1.0, model.weights, model.faces)

    def clocks(wall, cpu):
        wall, cpu = iter(wall), iter(cpu)
        monkeypatch.setattr(init_mod, "time", SimpleNamespace(perf_counter=lambda: next(wall),
                                                              process_time=lambda: next(cpu)))

    got = {}

    def fake_init(obs, m, view_point=None, passes=3, depth_camera=None):
        got["init"] = (obs, m, view_point, passes)
        got["depth_camera"] = depth_camera
        return source

    monkeypatch.setattr(init_mod, "initialise_from_observations", fake_init)
    ik_calls = []
    real_ik = init_mod.ik_pose

    def ik(sk, joints, tracked, version, previous=None):
        ik_calls.append((joints[0, 0], tracked, version, previous))
        return real_ik(sk, joints, tracked, version, previous)

    monkeypatch.setattr(init_mod, "ik_pose", ik)
    sk = source.skeleton
    tracked = np.ones(len(NAMES), bool)
    tracked[-1] = False
    obs = [InitObservation(f, None, posed_kinect_joints(sk, _pose(sk, seed=f, scale=0.05)), tracked, "v2")
           for f in range(3)]
    clocks([100.0, 102.0, 110.0, 113.0, 120.0, 124.0, 130.0, 131.5],
           [50.0, 51.0, 55.0, 55.5, 56.0, 58.5, 60.0, 60.75])
    out = init_mod.time_init_and_track(obs, model, view_point="eye", track_frames=5, passes=2, depth_camera="depth")
    assert got["init"] == (obs, model, "eye", 2) and got["depth_camera"] == "depth"
    assert out == {"init_s": 2.0, "init_cpu_s": 1.0, "init_frames": 3, "ik_ms": 1000 * 3.0 / 5,
                   "ik_cpu_ms": 1000 * 0.5 / 5, "skin_ms": 1000 * 4.0 / 5, "skin_cpu_ms": 1000 * 2.5 / 5,
                   "bodies_ms": 1000 * 1.5 / 5, "bodies_cpu_ms": 1000 * 0.75 / 5}
    assert [j for j, *_ in ik_calls] == [obs[i % 3].joints[0, 0] for i in range(5)]
    assert all(t is tracked and v == "v2" for _, t, v, _ in ik_calls)
    assert ik_calls[0][3] is None and all(prev is not None for *_, prev in ik_calls[1:])
    # the defaults: 90 frames, five passes, no depth camera; no frames: the per-frame figures are the totals
    ik_calls.clear()
    clocks([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0] * 2, [0.0] * 16)
    out = init_mod.time_init_and_track(obs, model)
    assert len(ik_calls) == 90 and got["init"][2:] == (None, 5) and got["depth_camera"] is None
    assert out["ik_ms"] == pytest.approx(1000 / 90)
    out = init_mod.time_init_and_track(obs, model, track_frames=0)
    assert out["ik_ms"] == 1000.0 and out["skin_ms"] == 1000.0 and out["bodies_ms"] == 1000.0


def test_initialise_source_body_loads_the_6k_model_by_default(monkeypatch, model):
    import bodystudio.body.statistical as statistical

    asked = []

    def load(resolution="6k", *args, progress=True, **kw):
        asked.append((resolution, progress))
        return model

    monkeypatch.setattr(statistical, "load_statistical_model", load)
    monkeypatch.setattr(init_mod, "collect_observations", lambda *a, **kw: (["obs"], SimpleNamespace(
        depth=SimpleNamespace(center=np.zeros(3)))))
    monkeypatch.setattr(init_mod, "initialise_from_observations", lambda obs, m, view_point=None, passes=3, **kw: m)
    monkeypatch.setattr(init_mod, "knee_joint_frames", lambda session, obs: [])
    assert init_mod.initialise_source_body(SimpleNamespace()) is model
    assert asked == [("6k", False)]


def test_initialisation_wires_the_passes(monkeypatch, model):
    """The steps each pass hands on (a stand-in Eq. 2 fit): bone scaling only in the first pass, the outlier
    limits, 40/20/20 closest-point iterations, the unposed joints from the second pass on (frames of the first
    frame's Kinect version only), the pooled cloud subsampled with a fixed seed, the shape carried between
    passes, and the last fit returned."""
    from bodystudio.mirror.init import FIT_TRIM_M, INIT_CORRESPONDENCE_M, INIT_FACING_COS, JOINT_WEIGHT, MAX_POINTS

    c_true = _planted_coeffs(model, seed=12)
    sk = model.skeleton(c_true)
    eye = np.array([0.0, 1.0, 3.0])
    rest = Pose(np.zeros((sk.n_bones, 3)), np.zeros(3))
    base = _frame_of(model, c_true, rest, eye)
    rng = np.random.default_rng(0)
    big = np.repeat(base.points, 3, axis=0) + rng.normal(0, 1e-4, (3 * len(base.points), 3))
    assert len(big) > MAX_POINTS
    v1 = _frame_of(model, c_true, rest, eye, frame=2, version="v1")
    far = InitObservation(3, np.r_[base.points[:250], base.points[:200] + [0.0, 0.0, 1.0]], base.joints,
                          base.tracked, "v2")
    tracked = base.tracked.copy()
    tracked[IX["ElbowLeft"]] = False  # unposed as NaN
    obs = [InitObservation(0, big, base.joints, tracked, "v2"), v1, InitObservation(1, base.points, base.joints,
                                                                                  tracked, "v2"), far]
    calls = {"tdp": [], "fit": []}
    real_tdp = init_mod.transform_to_default_pose

    def tdp(P, joints, body, tracked, version, **kw):
        cloud = real_tdp(P, joints, body, tracked, version, **kw)
        calls["tdp"].append(SimpleNamespace(P=P, body=body, version=version, kw=kw, cloud=cloud, tracked=tracked))
        return cloud

    def fit(P0, m, coeffs, **kw):
        calls["fit"].append(SimpleNamespace(P0=P0, init=None if coeffs is None else np.array(coeffs), kw=kw))
        return np.full(m.n_components, 0.1 * len(calls["fit"])) * m.stddev, 0.004 * len(calls["fit"])

    monkeypatch.setattr(init_mod, "transform_to_default_pose", tdp)
    monkeypatch.setattr(init_mod, "fit_shape", fit)
    src = initialise_from_observations(obs, model, view_point=eye, passes=3)
    assert len(calls["fit"]) == 3 and len(calls["tdp"]) == 12
    for p, f in enumerate(calls["fit"]):
        t = calls["tdp"][4 * p: 4 * p + 4]
        assert all(c.kw == dict(view_point=eye, scale_bones=p == 0, max_distance_m=INIT_CORRESPONDENCE_M,
                                details=True, min_facing_cos=INIT_FACING_COS, pose=None) for c in t)
        assert [c.version for c in t] == ["v2", "v1", "v2", "v2"]
        assert [c.tracked for c in t] == [tracked, v1.tracked, tracked, base.tracked]
        expect_c = np.zeros(model.n_components) if p == 0 else 0.1 * p * model.stddev
        np.testing.assert_allclose(f.init, expect_c, atol=1e-12)
        np.testing.assert_allclose(t[0].body.vertices, model.vertices(expect_c), atol=1e-12)
        np.testing.assert_allclose(t[0].body.skeleton.heads, refit_skeleton(model, expect_c).heads, atol=1e-12)
        assert t[0].body.resolution == model.resolution and t[0].body.rig == model.rig
        assert t[0].body.vertex_ids is model.vertex_ids
        ok = [c.cloud.correspondence >= 0 for c in t]
        assert ok[3].sum() < MIN_POINTS <= min(o.sum() for o in ok[:3])  # the far frame is not pooled
        np.testing.assert_array_equal(f.P0, np.concatenate([c.cloud.points[o] for c, o in zip(t[:3], ok[:3],
                                                                                               strict=True)]))
        np.testing.assert_array_equal(f.kw["correspondence"], np.concatenate(
            [c.cloud.correspondence[o] for c, o in zip(t[:3], ok[:3], strict=True)]))
        np.testing.assert_array_equal(f.kw["candidates"],
                                      np.unique(np.concatenate([c.cloud.candidates for c in t[:3]])))
        assert f.kw["iterations"] == (40, 20, 20)[p] and f.kw["joint_weight"] == JOINT_WEIGHT
        assert f.kw["version"] == "v2" and f.kw["trim_m"] == FIT_TRIM_M and f.kw["return_residual"] is True
        if p == 0:
            assert f.kw["joints_default"] is None
        else:  # the two v2 frames' unposed joints (the v1 frame has another joint set)
            expect_j = [unposed_kinect_joints(obs[i].joints, obs[i].tracked, c.cloud.body.skeleton,
                                              c.cloud.pose, "v2") for i, c in ((0, t[0]), (2, t[2]))]
            np.testing.assert_array_equal(f.kw["joints_default"], np.array(expect_j))
            assert np.isnan(f.kw["joints_default"][:, IX["ElbowLeft"]]).all()
    # each frame's points: finite, above the floor, at most MAX_POINTS (a subset seeded by the frame)
    above = big[:, 1] > 0.02
    assert not above.all()
    np.testing.assert_array_equal(calls["tdp"][0].P, _subsample(big[above], MAX_POINTS, 0))
    np.testing.assert_array_equal(calls["tdp"][2].P, base.points[base.points[:, 1] > 0.02])
    np.testing.assert_allclose(src.coeffs, 0.3 * model.stddev, atol=1e-12)
    np.testing.assert_allclose(src.vertices, model.vertices(src.coeffs), atol=1e-12)
    assert src.residual_mm == pytest.approx(12.0) and src.frames_used == (0, 2, 1, 3)
    # a Kinect v1 session: the unposed joints are v1's
    calls["fit"].clear()
    initialise_from_observations([v1], model, view_point=eye, passes=2)
    assert calls["fit"][1].kw["version"] == "v1"
    assert calls["fit"][1].kw["joints_default"].shape == (1, len(kinect_joint_names("v1")), 3)
    # one pass; passes below 1 run one pass
    calls["fit"].clear()
    initialise_from_observations(obs[:2], model, view_point=eye, passes=0, joint_weight=2.0, trim_m=0.2,
                                 max_distance_m=0.3, min_facing_cos=0.1)
    assert len(calls["fit"]) == 1 and calls["fit"][0].kw["trim_m"] == 0.2
    assert calls["tdp"][-1].kw["max_distance_m"] == 0.3 and calls["tdp"][-1].kw["min_facing_cos"] == 0.1
    calls["fit"].clear()
    initialise_from_observations(obs[:2], model, view_point=eye, passes=2, joint_weight=2.0)
    assert [f.kw["iterations"] for f in calls["fit"]] == [40, 20] and calls["fit"][1].kw["joint_weight"] == 2.0


def test_initialisation_pools_at_most_max_pooled_points_with_a_fixed_seed(monkeypatch, model):
    from bodystudio.mirror.init import MAX_POOLED_POINTS

    c_true = _planted_coeffs(model, seed=12)
    sk = model.skeleton(c_true)
    eye = np.array([0.0, 1.0, 3.0])
    base = _frame_of(model, c_true, Pose(np.zeros((sk.n_bones, 3)), np.zeros(3)), eye)
    obs = [InitObservation(f, base.points + [0.0, 0.0, 0.001 * f], base.joints, base.tracked, "v2")
           for f in range(7)]
    pooled, seen = [], []
    real_tdp = init_mod.transform_to_default_pose

    def tdp(*a, **kw):
        cloud = real_tdp(*a, **kw)
        seen.append(cloud.points[cloud.correspondence >= 0])
        return cloud

    monkeypatch.setattr(init_mod, "transform_to_default_pose", tdp)
    monkeypatch.setattr(init_mod, "fit_shape", lambda P0, m, c, **kw: pooled.append(P0) or (np.zeros(m.n_components),
                                                                                            0.0))
    # the random subset (the weighted pool, the default since mir12y, pools every point: test_init_pass_settle.py)
    initialise_from_observations(obs, model, view_point=eye, passes=1, max_frames=7, weighted_pool=False)
    everything = np.concatenate(seen)
    assert len(everything) > MAX_POOLED_POINTS and len(pooled[0]) == MAX_POOLED_POINTS
    pick = np.random.default_rng(0).choice(len(everything), MAX_POOLED_POINTS, replace=False)
    np.testing.assert_array_equal(pooled[0], everything[pick])


def test_initialisation_keeps_the_frames_with_most_points_stably(monkeypatch, model):
    """Of 40 usable frames (20 of 600 points, then 20 of 500) the 25 largest are the 20 big ones and the first
    five of the others; a frame of exactly MIN_POINTS points is usable, a point exactly at the floor margin is not."""
    c_true = _planted_coeffs(model, seed=12)
    sk = model.skeleton(c_true)
    eye = np.array([0.0, 1.0, 3.0])
    base = _frame_of(model, c_true, Pose(np.zeros((sk.n_bones, 3)), np.zeros(3)), eye)
    monkeypatch.setattr(init_mod, "fit_shape", lambda P0, m, c, **kw: (np.zeros(m.n_components), 0.0))
    obs = [InitObservation(f, base.points[: 500 if f < 20 else 600], base.joints, base.tracked, "v2")
           for f in range(40)]
    src = initialise_from_observations(obs, model, view_point=eye, passes=1, max_frames=25)
    assert src.frames_used == tuple(range(5)) + tuple(range(20, 40))
    P = base.points[:MIN_POINTS].copy()
    exact = InitObservation(50, P, base.joints, base.tracked, "v2")
    assert initialise_from_observations([exact], model, view_point=eye, passes=1).frames_used == (50,)
    P2 = P.copy()
    P2[0, 1] = 0.02  # exactly floor_y + floor_margin_m: dropped, leaving MIN_POINTS - 1
    with pytest.raises(InputError, match="^no frame with at least 300 depth points on the person: the actor must "
                       "stand fully in view of the Kinect during initialisation$"):
        initialise_from_observations([InitObservation(51, P2, base.joints, base.tracked, "v2")], model, passes=1)


def test_bone_scaling_needs_only_the_segments_own_joints(mean_body):
    """A missing hand joint or an untracked knee leaves every other segment's scaling alone; the scaled body
    keeps the body's resolution, rig and vertex ids."""
    sk = mean_body.skeleton
    K = kinect_joints(sk, sk.heads, sk.tails)
    K2, _ = _stretch_left_thigh(K, 1.2)
    d = 0.1 * (K[IX["KneeRight"]] - K[IX["HipRight"]])
    for n in ("KneeRight", "AnkleRight", "FootRight"):
        K2[IX[n]] += d
    K2[IX["HandTipRight"]] = np.nan
    B = bone_scaled_body(mean_body, K2)
    ratio = B.skeleton.lengths / sk.lengths
    assert ratio[sk.index("thigh_l")] == pytest.approx(1.2) and ratio[sk.index("thigh_r")] == pytest.approx(1.1)
    tracked = np.ones(len(NAMES), bool)
    tracked[IX["KneeLeft"]] = False
    ratio = bone_scaled_body(mean_body, K2, tracked).skeleton.lengths / sk.lengths
    assert ratio[sk.index("thigh_l")] == pytest.approx(1.0) and ratio[sk.index("thigh_r")] == pytest.approx(1.1)
    assert B.resolution == mean_body.resolution and B.rig == mean_body.rig
    assert B.vertex_ids is mean_body.vertex_ids


def test_default_pose_reads_points_as_float64_and_respects_untracked_joints(mean_body):
    sk = mean_body.skeleton
    K = posed_kinect_joints(sk, _pose(sk))
    pose = ik_pose(sk, K, None, "v2")
    Vp = skin_vertices(mean_body.vertices, mean_body.weights, sk, pose)[::7]
    P32 = Vp.astype(np.float32)
    out = transform_to_default_pose(P32, K, mean_body, scale_bones=False)
    assert out.dtype == np.float64
    ref = transform_to_default_pose(P32.astype(np.float64), K, mean_body, scale_bones=False)
    np.testing.assert_array_equal(out, ref)
    # an untracked (inferred) hip 5 cm off: not used to scale the thigh, and weighted down in the root's fit
    K2 = K.copy()
    K2[IX["HipLeft"]] += [0.0, 0.0, 0.05]
    tracked = np.ones(len(NAMES), bool)
    tracked[IX["HipLeft"]] = False
    cloud = transform_to_default_pose(Vp, K2, mean_body, tracked, details=True)
    thigh = sk.index("thigh_l")
    assert cloud.body.skeleton.lengths[thigh] == pytest.approx(sk.lengths[thigh])
    expect = ik_pose(cloud.body.skeleton, K2, tracked, "v2")
    np.testing.assert_allclose(cloud.pose.rotations, expect.rotations, atol=1e-12)
    assert np.abs(ik_pose(cloud.body.skeleton, K2, None, "v2").rotations - expect.rotations).max() > 1e-3


def test_eq2_defaults_and_edges(model):
    """Defaults (4 iterations, 5 cm trim, joints ignored without a weight), exactly 10 points, no iterations, a
    joint weight below 1, the first closest-point match keeping every pair, matching against the translated
    model."""
    rng = np.random.default_rng(15)
    c_true = _planted_coeffs(model, seed=15)
    V = model.vertices(c_true)
    P = V[::3] + rng.normal(0, 0.003, V[::3].shape)
    P[::40] += [0.0, 0.0, 0.2]
    a = fit_shape(P, model)
    np.testing.assert_array_equal(a, fit_shape(P, model, iterations=4, trim_m=0.05))
    assert not np.array_equal(a, fit_shape(P, model, iterations=5))
    assert not np.array_equal(a, fit_shape(P, model, trim_m=1.0))
    Jm, Jb = _model_kinect_joints(model, "v2")
    Jd = (Jm + np.einsum("k,kjd->jd", c_true, Jb))[None] + 0.05
    np.testing.assert_array_equal(fit_shape(P, model, joints_default=Jd), a)
    np.testing.assert_array_equal(fit_shape(P, model, joint_weight=2.0), a)  # weight without joints: nothing
    assert not np.array_equal(fit_shape(P, model, joints_default=Jd, joint_weight=0.5), a)
    assert fit_shape(V[:10], model, correspondence=np.arange(10), iterations=1).shape == (model.n_components,)
    c0, r0 = fit_shape(P, model, init_coeffs=c_true, iterations=0, return_residual=True)
    np.testing.assert_array_equal(c0, c_true)
    assert r0 == np.inf
    # the first closest-point match (from the mean shape) keeps every pair, however far
    m = cKDTree(model.mean).query(P)[1]
    sigma = POINT_SIGMA
    c1 = fit_shape(P, model, iterations=1, point_sigma_m=sigma)
    c_ref, _ = _dense_eq2(model, P, m, sigma**2 / model.stddev**2)
    np.testing.assert_allclose(c1, c_ref, atol=1e-8 * model.stddev.max())
    # matching is against the model moved by the fitted translation
    t = np.array([0.02, -0.01, 0.03])
    c8 = fit_shape(V + t, model, init_coeffs=c_true, iterations=8, point_sigma_m=1e-7)
    np.testing.assert_allclose(c8, c_true, atol=1e-6 * model.stddev.max())


POINT_SIGMA = 0.01


def test_eq3_uses_the_given_neighbourhoods_and_symmetric_matching_is_translated(model):
    sk0 = init_mod._default_skeleton(model)
    c = _planted_coeffs(model, seed=16)
    V = model.vertices(c)
    D = V - model.mean
    heads_nb = np.tile(np.arange(5), (sk0.n_bones, 1))
    tails_nb = np.tile(np.arange(5, 9), (sk0.n_bones, 1))
    sk = refit_skeleton_from_vertices(model.mean, sk0, V, (heads_nb, tails_nb))
    np.testing.assert_allclose(sk.heads, sk0.heads + D[:5].mean(0), atol=1e-12)
    np.testing.assert_allclose(sk.tails, sk0.tails + D[5:9].mean(0), atol=1e-12)
    t = np.array([0.02, -0.01, 0.03])
    c8 = fit_shape(V + t, model, init_coeffs=c, iterations=8, point_sigma_m=1e-7, symmetric=True)
    np.testing.assert_allclose(c8, c, atol=1e-6 * model.stddev.max())
