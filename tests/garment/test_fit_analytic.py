"""Analytic checks of garment/fit.py (§4 of Garment Replacement, Eq. 1-6): a ten-bone toy skeleton, a ball and
square mattes instead of the body model, so each test runs in well under a second.

Written for mutation testing (issue 17); tests/garment/test_fit.py's end-to-end fit takes minutes. Each term is
pinned by its formula or an exact case: the camera hypothesis, the fit's forward kinematics and four-weight
skinning against the body package, Eq. 2's distance form (zero for a perfect overlap, growing with a shift),
Eq. 3, Eq. 5, Eq. 6, the prior, the keyframe file, the placement, the tracking order and the appearance step.
"""

import json
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.optimize
from scipy.spatial.transform import Rotation

from bodystudio.body.model import RESOLUTIONS
from bodystudio.body.pose import Pose
from bodystudio.body.skeleton import Skeleton
from bodystudio.errors import FileFormatError, InputError
from bodystudio.garment import fit as gf
from bodystudio.garment.shape_refine import CLOTHING_ALLOWANCE_M
from bodystudio.geometry.camera import Camera


def exact(message):
    """A ``pytest.raises(match=...)`` pattern for exactly this message."""
    return "^" + re.escape(str(message)) + "$"


# ------------------------------------------------------------------------------------------ a toy body

BONES = {  # name: (parent, head, tail)
    "Root": (None, (0.0, 1.0, 0.0), (0.0, 1.1, 0.0)),
    "spine_02": ("Root", (0.0, 1.1, 0.0), (0.0, 1.5, 0.05)),
    "thigh_l": ("Root", (0.1, 1.0, 0.0), (0.1, 0.55, 0.02)),
    "calf_l": ("thigh_l", (0.1, 0.55, 0.02), (0.1, 0.1, 0.0)),
    "thigh_r": ("Root", (-0.1, 1.0, 0.0), (-0.1, 0.55, 0.02)),
    "calf_r": ("thigh_r", (-0.1, 0.55, 0.02), (-0.1, 0.1, 0.0)),
    "upperarm_l": ("spine_02", (0.2, 1.45, 0.0), (0.45, 1.3, 0.0)),
    "lowerarm_l": ("upperarm_l", (0.45, 1.3, 0.0), (0.6, 1.1, 0.05)),
    "upperarm_r": ("spine_02", (-0.2, 1.45, 0.0), (-0.45, 1.3, 0.0)),
    "lowerarm_r": ("upperarm_r", (-0.45, 1.3, 0.0), (-0.6, 1.1, 0.05)),
}


def toy_skeleton():
    names = tuple(BONES)
    parents = np.array([-1 if p is None else names.index(p) for p, _, _ in BONES.values()])
    heads = np.array([h for _, h, _ in BONES.values()])
    tails = np.array([t for _, _, t in BONES.values()])
    return Skeleton(names, parents, heads, tails, np.linspace(-0.3, 0.3, len(names)))


def toy_body(seed=0):
    """Points along each bone, skinned to it and (blending) to up to five others."""
    sk = toy_skeleton()
    rng = np.random.default_rng(seed)
    V, W = [], []
    for j in range(sk.n_bones):
        for s in np.linspace(0.0, 1.0, 6):
            V.append(sk.heads[j] + s * (sk.tails[j] - sk.heads[j]) + rng.normal(scale=0.03, size=3))
            w = np.zeros(sk.n_bones)
            w[j] = 1.0
            others = rng.choice(sk.n_bones, 5, replace=False)
            w[others] += rng.uniform(0.0, 0.3, size=5)  # six non-zero weights: the fit keeps the largest four
            W.append(w / w.sum())
    return SimpleNamespace(skeleton=sk, vertices=np.array(V), weights=np.array(W))


def front_camera(width=80, height=120):
    return gf.camera_hypothesis(width, height)


# ------------------------------------------------------------------------------------------ §4.1 camera


def test_focal_from_vertical_field_of_view():
    assert gf.focal_from_vfov(100, 90.0) == pytest.approx(50.0, rel=1e-12)
    assert gf.focal_from_vfov(480, 60.0) == pytest.approx(240.0 / np.tan(np.radians(30.0)), rel=1e-12)
    assert gf.focal_from_vfov(480) == pytest.approx(240.0 / np.tan(np.radians(20.0)), rel=1e-12)  # 40 deg


def test_camera_hypothesis_is_a_centred_pinhole_one_metre_up_looking_along_minus_z():
    cam = gf.camera_hypothesis(640, 480)
    assert cam.name == "cam_00" and (cam.width, cam.height) == (640, 480)
    f = gf.focal_from_vfov(480)
    assert np.allclose(cam.K, [[f, 0, 319.5], [0, f, 239.5], [0, 0, 1]])  # the centre of the pixel grid
    assert np.allclose(cam.center, [0.0, 1.0, 0.0])
    assert np.allclose(cam.project(np.array([[0.0, 1.0, -3.0]])), [[319.5, 239.5]])
    assert cam.project(np.array([[0.0, 2.0, -3.0]]))[0, 1] < 240  # world up is image up
    assert cam.project(np.array([[1.0, 1.0, -3.0]]))[0, 0] > 320  # world +x is image right
    assert np.allclose(gf.camera_hypothesis(640, 480, 500).K[0, 0], 500.0)
    # the plausible focal range is inclusive: [0.2 H, 20 max(W, H)]
    assert gf.camera_hypothesis(640, 480, 96.0).fx == 96.0
    assert gf.camera_hypothesis(640, 480, 12800.0).fx == 12800.0
    for f_bad in (95.9, 12801.0):
        with pytest.raises(InputError, match=exact(f"--focal-px {f_bad:g}: implausible for a 640x480 video; use a "
                                                   "value in [96, 12800] or leave it out")):
            gf.camera_hypothesis(640, 480, f_bad)
    with pytest.raises(InputError, match=re.escape("in [96, 9600] or")):
        gf.camera_hypothesis(480, 480, 10000.0)


# ------------------------------------------------------------------------------------------ fast posing


def test_pose_space_is_the_body_packages_kinematics_with_four_weights():
    from bodystudio.body.skinning import linear_blend_skinning, posed_joints, skinning_transforms

    body = toy_body()
    base = np.random.default_rng(2).normal(scale=0.2, size=(body.skeleton.n_bones, 3))
    space = gf.pose_space(body, base, max_samples=12)
    assert space.n_params == 6 + 3 * 9 and np.array_equal(space.base, base)
    assert [body.skeleton.bone_names[i] for i in space.bone_ids] == list(gf.FIT_BONES)
    assert np.array_equal(space.sample_ids, np.arange(0, 60, 5))
    x = np.random.default_rng(1).normal(0, 0.4, space.n_params)
    pose = space.pose(x)
    assert np.array_equal(pose.rotations[0], x[:3]) and np.array_equal(pose.translation, x[3:6])
    assert np.array_equal(pose.rotations[space.bone_ids], x[6:].reshape(-1, 3))
    assert np.array_equal(space.x_from_pose(pose), x)
    T = space.transforms(x)
    assert np.abs(T - skinning_transforms(body.skeleton, pose)).max() < 1e-12
    # the four largest weights per vertex, renormalised
    W4 = np.zeros_like(body.weights)
    top = np.argsort(-body.weights, axis=1)[:, :4]
    np.put_along_axis(W4, top, np.take_along_axis(body.weights, top, axis=1), axis=1)
    W4 /= W4.sum(1, keepdims=True)
    assert np.allclose(space.skin_w.sum(1), 1.0) and np.array_equal(np.sort(space.skin_idx, 1), np.sort(top, 1))
    want = linear_blend_skinning(body.vertices, W4, T)
    assert np.abs(space.vertices(x) - want).max() < 1e-12
    ids = np.array([3, 17, 42])
    assert np.abs(space.vertices(x, ids) - want[ids]).max() < 1e-12
    assert np.abs(space.vertices(x, ids, T) - want[ids]).max() < 1e-12
    assert np.abs(space.joints(x) - posed_joints(body.skeleton, pose)[0]).max() < 1e-12


def test_pose_space_samples_about_max_samples_vertices_and_stands_by_default():
    body = toy_body()
    space = gf.pose_space(body)
    assert np.array_equal(space.sample_ids, np.arange(60))  # fewer vertices than 900: all of them
    assert np.array_equal(gf.pose_space(body, max_samples=7).sample_ids, np.arange(0, 60, 8))
    assert np.array_equal(gf.pose_space(body, max_samples=100).sample_ids, np.arange(60))
    # the standing prior: the upper arms lowered (72 deg elevation) and nothing else turned
    prior = gf.standing_prior(body)
    assert np.array_equal(space.base, prior)
    moved = {body.skeleton.bone_names[j] for j in np.flatnonzero(np.abs(prior).sum(1) > 1e-9)}
    assert moved == {"upperarm_l", "upperarm_r"}
    from bodystudio.body.skinning import posed_joints

    heads, tails = posed_joints(body.skeleton, Pose(prior, np.zeros(3)))
    for side in ("l", "r"):
        j = body.skeleton.index(f"upperarm_{side}")
        d = (tails[j] - heads[j]) / np.linalg.norm(tails[j] - heads[j])
        assert d[1] < -0.9  # hanging down


# ------------------------------------------------------------------------------------------ Eq. 2, 3


def square_mask(H=60, W=50, rows=(10, 40), cols=(15, 35)):
    m = np.zeros((H, W), bool)
    m[rows[0]:rows[1], cols[0]:cols[1]] = True
    return m


def test_silhouette_target_holds_the_outside_distance_outline_and_extent():
    m = square_mask()
    t = gf.silhouette_target(m)
    assert t.y_min == 10.0 and t.y_max == 39.0 and np.array_equal(t.mask, m)
    assert t.outside_px.dtype == np.float32 and np.all(t.outside_px[m] == 0)
    assert t.outside_px[5, 25] == pytest.approx(5.0, abs=0.05) and t.outside_px[25, 40] == pytest.approx(6.0, abs=0.05)
    # the whole outline (96 pixels) when it is short, a subset of n_samples of it when long
    assert len(t.samples) == 2 * (30 + 20) - 4
    on_edge = (t.samples[:, 0] == 15) | (t.samples[:, 0] == 34) | (t.samples[:, 1] == 10) | (t.samples[:, 1] == 39)
    assert np.all(on_edge)
    few = gf.silhouette_target(m, n_samples=30, seed=1)
    assert len(few.samples) == 30 and len(np.unique(few.samples, axis=0)) == 30
    assert not np.array_equal(few.samples, gf.silhouette_target(m, n_samples=30, seed=2).samples)
    assert len(gf.silhouette_target(m, n_samples=96).samples) == 96
    assert len(gf.silhouette_target(m, n_samples=95).samples) == 95
    two = m | square_mask(rows=(45, 50), cols=(2, 6))
    assert len(gf.silhouette_target(two, n_samples=200).samples) == 96 + 2 * (5 + 4) - 4  # every outer contour
    assert gf.silhouette_target(two).y_max == 49.0


def test_bilinear_sampling_is_exact_on_a_linear_image_and_adds_the_distance_beyond_it():
    H, W = 20, 30
    rows, cols = np.mgrid[:H, :W]
    image = (2.0 * cols + 3.0 * rows + 1.0).astype(np.float32)
    uv = np.array([[3.25, 4.5], [0.0, 0.0], [29.0, 19.0], [12.75, 7.125]])
    assert np.allclose(gf._bilinear(image, uv), 2 * uv[:, 0] + 3 * uv[:, 1] + 1, atol=1e-4)
    beyond = np.array([[-3.0, 4.0], [33.0, 19.0], [29.0, 23.0], [-3.0, -4.0]])
    want = np.array([1 + 12 + 3, 116 + 4, 116 + 4, 1 + 5])
    assert np.allclose(gf._bilinear(image, beyond), want, atol=1e-4)


def grid_points(mask):
    r, c = np.nonzero(mask)
    return np.column_stack([c, r]).astype(np.float64)


def test_silhouette_energy_is_zero_for_a_perfect_overlap_and_grows_with_a_shift():
    """Eq. 2 in distance form: body points on the matte and the matte's outline covered give zero."""
    m = square_mask()
    t = gf.silhouette_target(m)
    uv = grid_points(m)
    r = gf.silhouette_residuals(uv, t)
    assert r.shape == (len(uv) + len(t.samples),) and np.allclose(r, 0.0)
    energies = [float(np.sum(gf.silhouette_residuals(uv + [s, 0.0], t) ** 2)) for s in (1, 2, 4, 8)]
    assert 0 < energies[0] < energies[1] < energies[2] < energies[3]
    # the two parts, each scaled to a mean: points outside by s px, outline points s px from the body
    s = 3.0
    r = gf.silhouette_residuals(uv + [s, 0.0], t)
    outside, cover = r[: len(uv)], r[len(uv):]
    inside_cols = uv[:, 0] + s <= 34
    assert np.allclose(outside[inside_cols], 0.0)
    right = uv[:, 0] == 34  # shifted 3 px beyond the right edge
    assert np.allclose(outside[right] * np.sqrt(len(uv)), s, atol=0.05)
    assert np.allclose(cover * np.sqrt(len(t.samples)), np.clip(15 + s - t.samples[:, 0], 0, None))
    assert np.count_nonzero(cover) == 30 + 2 * 2  # the left edge and two more points of the top and bottom rows


def test_silhouette_residuals_of_a_matte_without_outline_samples():
    t = gf.silhouette_target(square_mask(), n_samples=0)
    uv = grid_points(square_mask())
    assert len(t.samples) == 0 and len(gf.silhouette_residuals(uv, t)) == len(uv)


def test_height_residuals_are_top_and_bottom_rows():
    t = gf.silhouette_target(square_mask())
    uv = np.array([[20.0, 12.5], [21.0, 30.0], [22.0, 41.0]])
    assert np.allclose(gf.height_residuals(uv, t), [2.5, 2.0])


def test_model_silhouette_and_iou():
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    V, F = np.asarray(s.vertices), np.asarray(s.faces)
    cam = Camera.look_at("c", (0, 0, 3), (0, 0, 0), fx=100, width=40, height=40)
    sil = gf.model_silhouette(V, F, cam)
    assert sil.dtype == bool and 50 < sil.sum() < 400
    assert gf.silhouette_iou(V, F, cam, sil) == 1.0
    half = sil.copy()
    half[:, :20] = False
    assert gf.silhouette_iou(V, F, cam, half) == pytest.approx(half.sum() / sil.sum())
    assert gf.silhouette_iou(V + [9, 0, 0], F, cam, np.zeros_like(sil)) == 0.0


# ------------------------------------------------------------------------------------------ Eq. 4-6


def test_temporal_residuals_are_eq_5_in_smooth_form_without_the_translation():
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=12), rng.normal(size=12)
    r = gf.temporal_residuals(x, y)
    d = np.concatenate([x[:3] - y[:3], x[6:] - y[6:]])
    assert r.shape == (9,)
    assert np.allclose(r**2, 2 * 2.5 * (np.cosh(4.0 * d) - 1.0), rtol=1e-12)
    assert np.allclose(np.sign(r), np.sign(d))
    assert np.allclose(gf.temporal_residuals(x, y, beta=1.0, delta=2.0), 2 * np.sinh(d), rtol=1e-12)
    y2 = y.copy()
    y2[3:6] += 5.0  # the translation does not count
    assert np.array_equal(gf.temporal_residuals(x, y2), r)


def spheres_case():
    spheres = gf.PenetrationSpheres(centers=np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), radii=np.array([0.5, 0.2]),
                                    bones=np.array([0, 1]), group=np.array([0, 1]), probe_ids=np.array([4, 7, 9]),
                                    probe_excluded=np.array([-1, 1, 0]))
    T = np.tile(np.eye(4), (2, 1, 1))
    T[1, :3, :3] = Rotation.from_rotvec([0, 0, np.pi / 2]).as_matrix()  # sphere 1 swings to (0, 1, 0)
    T[1, :3, 3] = [0.0, 0.0, 0.5]
    return spheres, T


def test_interpenetration_is_the_depth_into_the_spheres_a_probe_may_enter():
    """Eq. 6: each probe's largest penetration depth into the posed spheres other than its own group's."""
    spheres, T = spheres_case()
    P = np.array([[0.1, 0.0, 0.0],  # 0.4 deep in sphere 0
                  [0.0, 1.0, 0.45],  # 0.15 deep in sphere 1 (moved to (0, 1, 0.5)), but probe 1 is of group 1
                  [0.0, 1.0, 0.4]])  # 0.1 deep in sphere 1; group 0 excluded (sphere 0 is 1.08 away anyway)
    V = np.zeros((10, 3))
    V[[4, 7, 9]] = P
    d = gf.interpenetration_residuals(V, T, spheres)
    assert np.allclose(d, [0.4, 0.0, 0.1], atol=1e-12)
    assert np.allclose(gf.interpenetration_residuals(P, T, spheres), d)  # probes given directly
    far = gf.interpenetration_residuals(P + [5.0, 0, 0], T, spheres)
    assert np.array_equal(far, np.zeros(3))
    # a probe inside two spheres takes the deeper one
    both = gf.PenetrationSpheres(np.array([[0.0, 0, 0], [0.3, 0, 0]]), np.array([0.5, 0.5]), np.array([0, 0]),
                                 np.array([0, 2]), np.array([0]), np.array([-1]))
    assert np.allclose(gf.interpenetration_residuals(np.array([[0.2, 0.0, 0.0]]), np.tile(np.eye(4), (1, 1, 1)),
                                                     both), [0.4])


def test_pose_prior_limits_hips_and_knees_keeps_upright_and_pulls_to_the_base():
    body = toy_body()
    sk = body.skeleton
    space = gf.pose_space(body, np.zeros((sk.n_bones, 3)))
    x = np.zeros(space.n_params)
    r = gf.pose_prior_residuals(x, space)
    assert r.shape == (8 + 27 + 2,) and np.array_equal(r, np.zeros(37))
    names = list(gf.FIT_BONES)

    def with_world(bone, world_rotvec):
        y = np.zeros(space.n_params)
        k = names.index(bone)
        y[6 + 3 * k: 9 + 3 * k] = sk.rest_rotations[space.bone_ids[k]].T @ np.asarray(world_rotvec)
        return y

    hip = gf.pose_prior_residuals(with_world("thigh_l", [0.3, 0, 0]), space)
    assert hip[0] == pytest.approx(10.0 * (0.3 - 0.1)) and np.all(hip[1:8] == 0)
    assert gf.pose_prior_residuals(with_world("thigh_l", [0.05, 0, 0]), space)[0] == 0.0
    assert gf.pose_prior_residuals(with_world("thigh_r", [0.3, 0, 0]), space)[4] == pytest.approx(2.0)
    knee = gf.pose_prior_residuals(with_world("calf_r", [-0.25, 0.1, -0.2]), space)
    assert np.allclose(knee[4:8], [0.0, 10.0 * 0.2, 10.0 * 0.1, -10.0 * 0.2])
    assert np.abs(gf.pose_prior_residuals(with_world("calf_l", [0.5, 0, 0]), space)[:8]).max() < 1e-12  # bent: free
    # the ridge: 0.4 per rad towards the base, 2.0 for the spine; upright: 4.0 on the global x and z
    y = np.zeros(space.n_params)
    y[6:] = 1.0
    y[[0, 1, 2]] = [0.1, 0.7, -0.2]
    ridge = gf.pose_prior_residuals(y, space)[8:]
    weights = np.repeat(np.where(np.array(names) == "spine_02", 2.0, 0.4), 3)
    assert np.allclose(ridge[:27], weights) and np.allclose(ridge[27:], [0.4, -0.8])
    based = gf.pose_space(body, np.ones((sk.n_bones, 3)))
    assert np.allclose(gf.pose_prior_residuals(y, based)[8:35], 0.0)


def test_keyframe_constraints_load_and_residuals(tmp_path):
    p = tmp_path / "keys.json"
    p.write_text(json.dumps({"frames": {"12": {"lowerarm_l": [10, 20.5]}, "3": {"Root": [1, 2], "calf_r": [3, 4]}}}))
    k = gf.KeyframeConstraints.load(p, tuple(BONES))
    assert set(k.points) == {12, 3} and np.array_equal(k.points[3]["calf_r"], [3.0, 4.0])
    assert k.points[12]["lowerarm_l"].dtype == np.float64
    cam = front_camera()
    joints = np.array([[0.0, 1.0, -3.0], [0.5, 1.5, -3.0], [0.1, 0.2, -2.0]])
    names = ["Root", "hand_l", "calf_r"]
    r = gf.keyframe_residuals(joints, cam, {"calf_r": np.array([3.0, 4.0]), "Root": np.array([1.0, 2.0])}, names)
    want = np.concatenate([cam.project(joints[[2]])[0] - [3, 4], cam.project(joints[[0]])[0] - [1, 2]])
    assert np.allclose(r, want)
    assert gf.keyframe_residuals(joints, cam, {}, names).shape == (0,)
    assert gf.keyframe_residuals(joints, cam, None, names).shape == (0,)


@pytest.mark.parametrize("text, phrase", [
    ('{"frames": {"1": {"wing": [1, 2]}}}', "unknown joint 'wing' at frame 1; use bone names such as hand_l, calf_r"),
    ('{"frames": {"1": {"Root": [1, 2, 3]}}}', "joint Root at frame 1 must be [u, v] pixels"),
    ('{"frames": {"1": {"Root": [1, NaN]}}}', "joint Root at frame 1 must be [u, v] pixels"),
    ('{"frames": {"1": {"Root": [1, Infinity]}}}', "joint Root at frame 1 must be [u, v] pixels"),
    ('{"frames": {"1": {"Root": [[1, 2]]}}}', "joint Root at frame 1 must be [u, v] pixels"),
    ('{"frames": {"x": {"Root": [1, 2]}}}', "ValueError"),
    ('{"frame": {}}', "KeyError"),
    ('{"frames": [1]}', "AttributeError"),
    ('{"frames": {"1": {"Root": "up"}}}', "ValueError"),
    ('{"frames": {"1": {"Root": {"u": 1}}}}', "TypeError"),
    ("not json", "JSONDecodeError"),
    (None, "FileNotFoundError"),
])
def test_keyframe_constraints_refuse_bad_files(tmp_path, text, phrase):
    p = tmp_path / "keys.json"
    if text is not None:
        p.write_text(text)
    if " " not in phrase:  # the exception's type
        phrase = (f"unreadable keyframe constraints ({phrase}); write "
                  '{"frames": {"FRAME": {"BONE": [u, v]}}}')
    with pytest.raises(FileFormatError, match=exact(f"{p}: {phrase}")):
        gf.KeyframeConstraints.load(p, tuple(BONES))


def test_keyframe_errors_name_the_file(tmp_path):
    p = tmp_path / "keys.json"
    p.write_text('{"frame": {}}')
    with pytest.raises(FileFormatError) as e:
        gf.KeyframeConstraints.load(p, tuple(BONES))
    assert str(e.value).startswith(f"{p}: ") and str(e.value).endswith('{"frames": {"FRAME": {"BONE": [u, v]}}}')


# ------------------------------------------------------------------------------------------ placement / Eq. 4


def toy_target_and_space(H=120, W=80):
    body = toy_body()
    space = gf.pose_space(body)
    cam = front_camera(W, H)
    x_true = np.zeros(space.n_params)
    x_true[6:] = space.base[space.bone_ids].ravel()
    x_true[3:6] = [0.1, -0.05, -3.0]
    uv = cam.project(space.vertices(x_true))
    m = np.zeros((H, W), bool)
    c, r = np.clip(np.round(uv).astype(int), 0, [W - 1, H - 1]).T
    m[r, c] = True
    import cv2

    m = cv2.dilate(m.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    return space, cam, gf.silhouette_target(m), x_true


def test_initial_placement_puts_the_standing_body_over_the_matte():
    space, cam, t, x_true = toy_target_and_space()
    x = gf.initial_placement(space, cam, t)
    assert np.array_equal(x[:3], [0, 0, 0]) and np.array_equal(x[6:], space.base[space.bone_ids].ravel())
    assert x[5] == pytest.approx(-3.0, rel=0.12)  # depth from the image height (the matte is dilated by 2 px)
    uv = cam.project(space.vertices(x))
    assert uv[:, 1].min() == pytest.approx(t.y_min, abs=1.5)  # top row on the matte's top (depth varies)
    cols = np.flatnonzero(t.mask.any(0))
    assert 0.5 * (uv[:, 0].min() + uv[:, 0].max()) == pytest.approx(0.5 * (cols.min() + cols.max()), abs=1.0)
    height_px = uv[:, 1].max() - uv[:, 1].min()
    assert height_px == pytest.approx(t.y_max - t.y_min, rel=0.02)


def test_initial_placements_add_either_knee_raised():
    space, cam, t, _ = toy_target_and_space()
    starts = gf.initial_placements(space, cam, t)
    assert len(starts) == 3 and np.array_equal(starts[0], gf.initial_placement(space, cam, t))
    sk = space.body.skeleton
    names = list(gf.FIT_BONES)
    for x, side in zip(starts[1:], ("l", "r"), strict=True):
        changed = {names[k] for k in range(9) if not np.array_equal(x[6 + 3 * k: 9 + 3 * k], starts[0][6 + 3 * k:
                                                                                                      9 + 3 * k])}
        assert changed == {f"thigh_{side}", f"calf_{side}"}
        for bone, angle in ((f"thigh_{side}", -0.6), (f"calf_{side}", 1.0)):
            k = names.index(bone)
            world = sk.rest_rotations[space.bone_ids[k]] @ x[6 + 3 * k: 9 + 3 * k]
            assert np.allclose(world, [angle, 0, 0], atol=1e-12)
        assert np.array_equal(x[:6], starts[0][:6])


def test_pose_residuals_stack_the_terms_of_eq_4():
    _, cam, t, x_true = toy_target_and_space()
    space = gf.pose_space(toy_body(), max_samples=12)  # the silhouette term on every fifth vertex only
    spheres = gf.PenetrationSpheres(np.array([[0.0, 1.2, 0.0]]), np.array([0.5]), np.array([0]), np.array([0]),
                                    np.array([10, 40, 50]), np.array([-1, -1, -1]))
    p = gf.PoseProblem(space, cam, t, spheres)
    x = x_true.copy()
    x[9:12] += 0.3
    T = space.transforms(x)
    V = space.vertices(x, space.sample_ids, T)
    uv = cam.project(V)
    sil = gf.silhouette_residuals(uv, t)
    prior = gf.pose_prior_residuals(x, space)
    px_per_m = cam.fx / float(cam.world_to_camera(V.mean(0, keepdims=True))[0, 2])
    depth = gf.interpenetration_residuals(space.vertices(x, spheres.probe_ids, T), T, spheres)
    pen = np.sqrt(4.0) * px_per_m * depth / np.sqrt(3)
    assert depth.min() > 0.01 and len(V) == 12  # the probes are inside the sphere
    r = gf.pose_residuals(x, p)
    assert np.allclose(r, np.concatenate([sil, prior, pen]))
    p.with_height = True
    p.neighbour = x_true
    p.constraints = {"calf_l": np.array([30.0, 100.0])}
    joints = space.joints(x)
    key = np.sqrt(0.5) * gf.keyframe_residuals(joints, cam, p.constraints, list(space.body.skeleton.bone_names))
    want = np.concatenate([sil, np.sqrt(0.3) * gf.height_residuals(uv, t) / 10.0, gf.temporal_residuals(x, x_true),
                           prior, pen, key])
    assert np.allclose(gf.pose_residuals(x, p), want)


def test_fit_frame_pose_lowers_eq_4_from_a_perturbed_start():
    space, cam, t, x_true = toy_target_and_space()
    spheres = gf.PenetrationSpheres(np.zeros((1, 3)), np.array([0.01]), np.array([0]), np.array([0]),
                                    np.array([0]), np.array([-1]))
    p = gf.PoseProblem(space, cam, t, spheres)
    x0 = x_true.copy()
    x0[3:5] += [0.08, 0.06]
    e0 = float(np.sum(gf.pose_residuals(x0, p) ** 2))
    x = gf.fit_frame_pose(x0, p)
    e = float(np.sum(gf.pose_residuals(x, p) ** 2))
    assert e < 0.3 * e0 and np.linalg.norm(x[3:5] - x_true[3:5]) < 0.03
    x_short = gf.fit_frame_pose(x0, p, max_nfev=1)
    assert float(np.sum(gf.pose_residuals(x_short, p) ** 2)) > e


# ------------------------------------------------------------------------------------------ shape (§4.3)


def test_body_stature_is_head_to_sole():
    body = SimpleNamespace(vertices=np.array([[0.0, 0.05, 0.0], [0.3, 1.8, 0.1], [0.0, 1.0, 2.0]]))
    assert gf.body_stature(body) == pytest.approx(1.75)


def fake_build_body(phenotype=None, local=None, resolution="2k"):
    """A 'body' whose stature is 1.4 + 0.5 * height (+ 0.1 * weight) and that remembers its inputs."""
    ph = phenotype.to_dict() if phenotype is not None else {}
    top = 1.4 + 0.5 * ph.get("height", 0.5) + 0.1 * ph.get("weight", 0.5)
    return SimpleNamespace(vertices=np.array([[0.0, 0.0, 0.0], [0.0, top, 0.0]]), phenotype=ph, local=dict(local or {}),
                           resolution=resolution)


def test_stature_matched_height_bisects_the_height_parameter(monkeypatch):
    import bodystudio.body

    built = []

    def recording_build_body(phenotype=None, local=None, resolution="2k"):
        built.append((local, resolution))
        return fake_build_body(phenotype, local, resolution)

    monkeypatch.setattr(bodystudio.body, "build_body", recording_build_body)
    from bodystudio.body.phenotype import Phenotype

    ph = Phenotype().to_dict()
    ph["weight"] = 0.2
    out = gf._stature_matched_height(ph, {"neck": 0.1}, 1.72, "6k")
    assert out["height"] == pytest.approx((1.72 - 1.42) / 0.5, abs=2**-14)
    # 14 halvings: the midpoint of the last interval, an odd multiple of 2^-15
    assert (out["height"] * 2**15) % 2 == 1
    assert out["weight"] == 0.2 and ph["height"] != out["height"]
    assert built == [({"neck": 0.1}, "6k")] * 14
    assert gf._stature_matched_height(ph, {}, 9.0, "2k")["height"] == pytest.approx(1.0, abs=2**-14)
    assert gf._stature_matched_height(ph, {}, 0.1, "2k")["height"] == pytest.approx(0.0, abs=2**-14)


def test_shape_body_clips_macro_and_local_parameters(monkeypatch):
    import bodystudio.body

    monkeypatch.setattr(bodystudio.body, "build_body", fake_build_body)
    from bodystudio.body.phenotype import Phenotype

    ph = Phenotype().to_dict()
    body, ph2, loc = gf._shape_body(np.array([1.4, -0.2, 0.3, 2.0]), ("height", "weight", "upperarm-fat-decr-incr",
                                                                      "neck-scale-horiz-decr-incr"), ph,
                                    {"buttocks-volume-decr-incr": 0.5}, "6k")
    assert ph2["height"] == 1.0 and ph2["weight"] == 0.0 and ph["height"] != 1.0
    assert loc == {"buttocks-volume-decr-incr": 0.5, "upperarm-fat-decr-incr": 0.3, "neck-scale-horiz-decr-incr": 1.0}
    assert body.resolution == "6k" and body.local == loc and body.phenotype["height"] == 1.0
    _, _, loc = gf._shape_body(np.array([-1.5]), ("upperarm-fat-decr-incr",), ph, {}, "2k")
    assert loc == {"upperarm-fat-decr-incr": -1.0}


def test_shape_energy_is_eq_1_plus_the_stature_term(monkeypatch):
    _, cam, t, x_true = toy_target_and_space()
    space = gf.pose_space(toy_body(), max_samples=12)  # every fifth vertex carries the silhouette term
    body = space.body
    monkeypatch.setattr(gf, "pose_space", lambda b, base: space if b is body and base is space.base else None)
    x2 = x_true.copy()
    x2[3] += 0.05
    e = gf.shape_energy(body, [x_true, x2], cam, [t, t], 1.6, space.base)
    parts = []
    for x in (x_true, x2):
        uv = cam.project(space.vertices(x, space.sample_ids))
        parts.append(np.sum(gf.silhouette_residuals(uv, t) ** 2) + 0.3 * np.sum((gf.height_residuals(uv, t) / 10) ** 2))
    stature = gf.body_stature(body)
    assert e == pytest.approx(np.mean(parts) + 2.0 * ((stature - 1.6) * 100) ** 2, rel=1e-12)
    assert parts[1] > parts[0] > 0


# ------------------------------------------------------------------------------------------ §4.4 tracking


def test_track_poses_runs_forward_from_the_reference_then_backward(monkeypatch):
    calls = []

    def fake_fit(x0, problem, max_nfev=6):
        assert problem.space is space and problem.camera == "cam" and problem.spheres == ("spheres", "body")
        assert max_nfev == 6 and not problem.with_height
        calls.append((problem.target, None if problem.neighbour is None else problem.neighbour.copy(), x0.copy(),
                      problem.constraints))
        return x0 + 1.0 if problem.target > 2 else x0 - 1.0

    monkeypatch.setattr(gf, "fit_frame_pose", fake_fit)
    monkeypatch.setattr(gf, "penetration_spheres", lambda body: ("spheres", body))
    monkeypatch.setattr(gf, "silhouette_target", lambda mask: int(mask))
    space = SimpleNamespace(body="body", n_params=2)
    masks = np.arange(5)
    ticks = []
    X = gf.track_poses(space, "cam", masks, 2, np.array([10.0, 20.0]), {7: "keys"}, progress=lambda: ticks.append(1),
                       frame_ids=np.array([5, 6, 7, 8, 9]))
    assert [c[0] for c in calls] == [2, 3, 4, 1, 0]
    assert calls[0][1] is None and np.array_equal(calls[0][2], [10, 20])
    assert np.array_equal(X[2], [9, 19]) and np.array_equal(X[3], [10, 20]) and np.array_equal(X[4], [11, 21])
    assert np.array_equal(X[1], [8, 18]) and np.array_equal(X[0], [7, 17])
    assert np.array_equal(calls[1][1], X[2]) and np.array_equal(calls[1][2], X[2])  # warm start = neighbour
    assert np.array_equal(calls[3][1], X[2]) and np.array_equal(calls[4][1], X[1])
    assert [c[3] for c in calls] == ["keys", None, None, None, None]  # the constraints of frame id 7 only
    assert len(ticks) == 5
    X = gf.track_poses(space, "cam", masks[:3], 0, np.array([0.0, 0.0]))  # default frame ids, no progress
    assert [c[0] for c in calls[5:]] == [0, 1, 2] and np.array_equal(X[2], [-3, -3])


# ------------------------------------------------------------------------------------------ §5 appearance


def test_mean_lighting_averages_the_frames_lights():
    from bodystudio.garment.lighting import Lighting

    a = Lighting([[0, 0, 1]], [[0.6, 0.6, 0.6]], [0.2, 0.2, 0.2])
    b = Lighting([[0, 1, 0], [1, 0, 0]], [[0.3, 0.0, 0.3], [0.9, 0.9, 0.0]], [0.4, 0.0, 0.2])
    m = gf.mean_lighting([a, b])
    assert np.allclose(m.directions, [[0, 0, 1], [0, 1, 0], [1, 0, 0]])
    assert np.allclose(m.colors, [[0.3, 0.3, 0.3], [0.15, 0, 0.15], [0.45, 0.45, 0]])
    assert np.allclose(m.ambient, [0.3, 0.1, 0.2])
    one = gf.mean_lighting([b])
    assert np.allclose(one.colors, b.colors) and np.allclose(one.ambient, b.ambient)
    empty = gf.mean_lighting([])
    assert empty.directions.shape == (0, 3) and np.array_equal(empty.ambient, np.zeros(3))


def ball_frames(n=3, size=64, light_dir=(0.4, 0.5, 1.0)):
    import trimesh

    from bodystudio.capture.render import render
    from bodystudio.garment.lighting import Lighting
    from bodystudio.garment.render import render_body

    s = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    V0, F = np.asarray(s.vertices, dtype=np.float64), np.asarray(s.faces, dtype=np.int64)
    cam = Camera.look_at("c", (0.0, 0.0, 3.0), (0, 0, 0), fx=2.4 * size, width=size, height=size)
    light = Lighting.single(np.asarray(light_dir) / np.linalg.norm(light_dir), 0.8, 0.2)
    albedo = np.where(V0[:, 1:2] > 0, [0.8, 0.5, 0.4], [0.3, 0.5, 0.7])
    images, masks, posed = [], [], []
    for yaw in np.linspace(-0.5, 0.5, n):
        V = V0 @ Rotation.from_rotvec([0, yaw, 0]).as_matrix().T
        image, _ = render_body(V, F, cam, light, albedo)
        images.append(image)
        masks.append(render(V, F, cam).mask)
        posed.append(V)
    return images, masks, posed, F, cam, light, albedo


def test_clip_lighting_stacks_the_frames_rows_and_finds_the_light():
    from bodystudio.garment import lighting as lt

    images, masks, posed, F, cam, light, albedo = ball_frames()
    est = gf.clip_lighting(images, masks, posed, F, cam, albedo, samples_per_frame=400)
    rows = [lt.surface_samples(img, V, F, cam, albedo, 400, 3, seed=k, pixel_mask=m)
            for k, (img, m, V) in enumerate(zip(images, masks, posed, strict=True))]
    P, N, A, B = (np.concatenate([r[i] for r in rows]) for i in range(4))
    axis = cam.center - np.mean([V.mean(0) for V in posed], axis=0)
    want = lt.estimate_lighting(P, N, A, B, axis / np.linalg.norm(axis))
    assert np.array_equal(est.directions, want.directions) and np.allclose(est.colors, want.colors)
    d = lt.dominant_light_direction(est.directions, est.colors)
    assert np.degrees(np.arccos(d @ light.directions[0])) < 10.0  # measured 6.7 (a 64 px ball, 3 frames)
    # half the matte: only its pixels give rows
    half = [m & (np.arange(m.shape[1]) < 32)[None] for m in masks]
    P_half = lt.surface_samples(images[0], posed[0], F, cam, albedo, 10_000, 3, seed=0, pixel_mask=half[0])[0]
    assert np.all(cam.project(P_half)[:, 0] < 32.5)


def test_estimate_appearance_alternates_albedo_and_clip_lights(monkeypatch):
    from bodystudio.garment import lighting as lt

    images, masks, posed, F, cam, light, albedo = ball_frames(n=4)
    seen_lights = []
    real = gf.clip_lighting

    def spy(imgs, ms, Vs, F_, camera, a, **kw):
        assert kw == {"sparsity": 0.0}
        seen_lights.append(a.copy())
        return real(imgs, ms, Vs, F_, camera, a, samples_per_frame=300, **kw)

    # the per-vertex alternation (grouped=False, no sparsity): the materials and the L1 penalty are
    # tests/garment/test_appearance.py's
    monkeypatch.setattr(gf, "clip_lighting", spy)
    a0, l0 = gf.estimate_appearance(np.stack(images), np.stack(masks), posed, F, cam, max_frames=3, iterations=0,
                                    grouped=False, sparsity=0.0)
    pick = [0, 2, 3]  # three frames spread over four: linspace(0, 3, 3) rounded
    mean_colour, count = lt.estimate_albedo([images[i] for i in pick], [posed[i] for i in pick], F, cam)
    assert np.array_equal(a0, mean_colour) and len(seen_lights) == 1
    a1, l1 = gf.estimate_appearance(np.stack(images), np.stack(masks), posed, F, cam, max_frames=3, iterations=1,
                                    grouped=False, sparsity=0.0)
    assert len(seen_lights) == 3 and np.array_equal(seen_lights[1], mean_colour)
    num, den = np.zeros_like(mean_colour), np.zeros_like(mean_colour)
    obs = lt.visible_vertex_colors([images[i] for i in pick], [posed[i] for i in pick], F, cam)
    for (ids, colors), i in zip(obs, pick, strict=True):
        S = lt.vertex_shading(posed[i], F, l0)[ids]
        num[ids] += colors * S
        den[ids] += S * S
    seen = count > 0
    want = mean_colour.copy()
    want[seen] = num[seen] / den[seen]
    want = np.clip(want * mean_colour[seen].mean(0) / want[seen].mean(0), 0, None)
    assert np.abs(a1 - want).max() < 1e-9 and np.array_equal(seen_lights[2], a1)
    assert not np.allclose(a1, a0, atol=1e-3)
    assert np.array_equal(l1.directions, real(*(
        [images[i] for i in pick], [masks[i] for i in pick], [posed[i] for i in pick]), F, cam, a1,
        samples_per_frame=300, sparsity=0.0).directions)


# ------------------------------------------------------------------------------------------ refusals


@pytest.mark.parametrize("stature, template, phrase", [
    (None, "2k", "--stature None: give the actor's stature in metres, between 0.5 and 2.5"),
    (float("nan"), "2k", "--stature nan: give the actor's stature in metres, between 0.5 and 2.5"),
    (float("inf"), "2k", "--stature inf: give the actor's stature in metres, between 0.5 and 2.5"),
    (0.49, "2k", "--stature 0.49: give the actor's stature in metres, between 0.5 and 2.5"),
    (2.51, "2k", "--stature 2.51: give the actor's stature in metres, between 0.5 and 2.5"),
    (1.7, "3k", "--template '3k': valid: " + ", ".join(RESOLUTIONS)),
])
def test_fit_refuses_bad_stature_and_template_before_reading(tmp_path, stature, template, phrase):
    with pytest.raises(InputError, match=exact(phrase)):
        gf.fit_garment_video(tmp_path / "missing.mp4", stature, template=template)


def test_fit_accepts_the_stature_range_ends(tmp_path, monkeypatch):
    import bodystudio.garment.person as person

    def stop(*args, **kwargs):
        raise RuntimeError("reached the video")

    monkeypatch.setattr(person, "person_frames", stop)
    for stature in (0.5, 2.5):
        with pytest.raises(RuntimeError, match="reached the video"):
            gf.fit_garment_video(tmp_path / "v.mp4", stature)


# ------------------------------------------------------------------------------------------ Eq. 6 proxy geometry

FULL_BONES = {  # a standing figure with the bones penetration_spheres and the probes use
    "pelvis": (None, (0.0, 1.0, 0.0), (0.0, 1.1, 0.0)),
    "spine_01": ("pelvis", (0.0, 1.1, 0.0), (0.0, 1.2, 0.0)),
    "spine_02": ("spine_01", (0.0, 1.2, 0.0), (0.0, 1.35, 0.0)),
    "spine_03": ("spine_02", (0.0, 1.35, 0.0), (0.0, 1.5, 0.0)),
    "neck_01": ("spine_03", (0.0, 1.5, 0.0), (0.0, 1.6, 0.0)),
    "thigh_l": ("pelvis", (0.1, 0.95, 0.0), (0.1, 0.5, 0.0)),
    "calf_l": ("thigh_l", (0.1, 0.5, 0.0), (0.1, 0.1, 0.0)),
    "foot_l": ("calf_l", (0.1, 0.1, 0.0), (0.1, 0.0, 0.1)),
    "thigh_r": ("pelvis", (-0.1, 0.95, 0.0), (-0.1, 0.5, 0.0)),
    "calf_r": ("thigh_r", (-0.1, 0.5, 0.0), (-0.1, 0.1, 0.0)),
    "foot_r": ("calf_r", (-0.1, 0.1, 0.0), (-0.1, 0.0, 0.1)),
    "lowerarm_l": ("spine_03", (0.4, 1.3, 0.0), (0.5, 1.05, 0.0)),
    "hand_l": ("lowerarm_l", (0.5, 1.05, 0.0), (0.52, 0.95, 0.0)),
    "lowerarm_r": ("spine_03", (-0.4, 1.3, 0.0), (-0.5, 1.05, 0.0)),
    "hand_r": ("lowerarm_r", (-0.5, 1.05, 0.0), (-0.52, 0.95, 0.0)),
}


def figure(n_per_bone=(60, 30)):
    """Rings of vertices around each bone (radius 0.06-0.12), skinned to it; the hands get few vertices."""
    names = tuple(FULL_BONES)
    parents = np.array([-1 if p is None else names.index(p) for p, _, _ in FULL_BONES.values()])
    heads = np.array([h for _, h, _ in FULL_BONES.values()])
    tails = np.array([t for _, _, t in FULL_BONES.values()])
    sk = Skeleton(names, parents, heads, tails, np.zeros(len(names)))
    rng = np.random.default_rng(3)
    V, W = [], []
    for j, name in enumerate(names):
        count = n_per_bone[1] if name.startswith("hand") else n_per_bone[0]
        s = rng.uniform(0, 1, count)
        radius = 0.06 + 0.06 * rng.uniform(size=count)
        angle = rng.uniform(0, 2 * np.pi, count)
        V.append(heads[j] + s[:, None] * (tails[j] - heads[j]) + radius[:, None] * np.column_stack(
            [np.cos(angle), np.zeros(count), np.sin(angle)]))
        w = np.full((count, len(names)), 0.01)
        w[:, j] = 1.0
        W.append(w)
    return SimpleNamespace(skeleton=sk, vertices=np.vstack(V), weights=np.vstack(W))


def test_penetration_spheres_are_inscribed_along_the_spine_and_legs():
    from scipy.spatial import cKDTree

    body = figure()
    sk = body.skeleton
    sp = gf.penetration_spheres(body)
    dominant = np.argmax(body.weights, axis=1)
    assert len(sp.centers) == 5 * 4 and sp.group.tolist() == [0] * 4 + [1] * 8 + [2] * 8
    segments = [("pelvis", "neck_01", ("pelvis", "spine_01", "spine_02", "spine_03")),
                ("thigh_l", "calf_l", ("thigh_l",)), ("calf_l", "foot_l", ("calf_l",)),
                ("thigh_r", "calf_r", ("thigh_r",)), ("calf_r", "foot_r", ("calf_r",))]
    k = 0
    for a, b, owners in segments:
        ha, hb = sk.heads[sk.index(a)], sk.heads[sk.index(b)]
        own = body.vertices[np.isin(dominant, [sk.index(o) for o in owners])]
        for s in (0.125, 0.375, 0.625, 0.875):
            c = ha + s * (hb - ha)
            assert np.allclose(sp.centers[k], c, atol=1e-15)
            assert sp.radii[k] == pytest.approx(0.9 * cKDTree(own).query(c)[0], rel=1e-12)
            if len(owners) > 1:
                heads = {o: np.linalg.norm(c - sk.heads[sk.index(o)]) for o in owners}
                assert sk.bone_names[sp.bones[k]] == min(heads, key=heads.get)
            else:
                assert sp.bones[k] == sk.index(a)
            k += 1
    assert [sk.bone_names[b] for b in sp.bones[:4]] == ["spine_01", "spine_02", "spine_03", "spine_03"]
    # probes: 40 of each forearm and calf, all (30) of each hand; calves may not enter their own leg
    names = [sk.bone_names[dominant[i]] for i in sp.probe_ids]
    for bone, count, excluded in (("lowerarm_l", 40, -1), ("lowerarm_r", 40, -1), ("hand_l", 30, -1),
                                  ("hand_r", 30, -1), ("calf_l", 40, 1), ("calf_r", 40, 2)):
        mine = [i for i, n in enumerate(names) if n == bone]
        assert len(mine) == count and np.all(sp.probe_excluded[mine] == excluded), bone
        ids = sp.probe_ids[mine]
        assert np.all(np.diff(ids) > 0)  # sorted, no repeats
    assert len(sp.probe_ids) == 220
    again = gf.penetration_spheres(body)
    assert np.array_equal(again.probe_ids, sp.probe_ids)  # seeded
    two = gf.penetration_spheres(body, per_segment=2)
    assert len(two.centers) == 10 and np.allclose(two.centers[0], sk.heads[0] + 0.25 * (sk.heads[4] - sk.heads[0]))


def test_penetration_spheres_without_hand_vertices():
    body = figure()
    hands = np.isin(np.argmax(body.weights, axis=1), [body.skeleton.index("hand_l"), body.skeleton.index("hand_r")])
    body.vertices, body.weights = body.vertices[~hands], body.weights[~hands]
    sp = gf.penetration_spheres(body)
    assert len(sp.probe_ids) == 160 and len(sp.probe_excluded) == 160


# ------------------------------------------------------------------------------------------ §4.3 stages


def test_nelder_mead_shape_starts_from_the_papers_simplex_and_returns_the_best_shape(monkeypatch, caplog):
    import logging

    caplog.set_level(logging.INFO, logger="bodystudio.garment.fit")
    evaluated = []

    def fake_shape_body(values, names, phenotype, local, template):
        assert names == ("weight", "upperarm-fat-decr-incr") and template == "2k"
        return ("body", tuple(values)), {**phenotype, "v": list(values)}, {**local, "t": template}

    def fake_energy(body, xs, camera, targets, stature_m, base):
        v = np.array(body[1])
        evaluated.append(v)
        assert (xs, camera, targets, stature_m, base) == ("xs", "cam", "targets", 1.7, "base")
        return float(np.sum((v - [0.3, -0.2]) ** 2))

    monkeypatch.setattr(gf, "_shape_body", fake_shape_body)
    monkeypatch.setattr(gf, "shape_energy", fake_energy)
    ph, loc = gf.nelder_mead_shape(("weight", "upperarm-fat-decr-incr"), np.array([0.5, 0.0]), {"a": 1}, {"b": 2},
                                   "xs", "cam", "targets", 1.7, "2k", "base", max_evals=200)
    assert np.allclose(evaluated[0], [0.5, 0.0])
    assert np.allclose(evaluated[1], [0.65, 0.0]) and np.allclose(evaluated[2], [0.5, 0.3])  # 0.15 macro, 0.3 local
    assert np.allclose(ph["v"], [0.3, -0.2], atol=2e-3) and ph["a"] == 1 and loc == {"b": 2, "t": "2k"}
    # stopped by the tolerances (xatol 1e-3, fatol 1e-4): as many evaluations as scipy needs with those
    simplex = np.array([[0.5, 0.0], [0.65, 0.0], [0.5, 0.3]])
    ref = scipy.optimize.minimize(lambda v: float(np.sum((v - [0.3, -0.2]) ** 2)), [0.5, 0.0], method="Nelder-Mead",
                                  options={"maxfev": 200, "initial_simplex": simplex, "xatol": 1e-3, "fatol": 1e-4})
    assert len(evaluated) == ref.nfev < 200
    assert np.allclose(ph["v"], ref.x, atol=1e-15)
    assert caplog.records[-1].getMessage() == f"shape stage weight: energy {ref.fun:.4f} after {ref.nfev} evaluations"
    evaluated.clear()
    gf.nelder_mead_shape(("weight", "upperarm-fat-decr-incr"), np.array([0.5, 0.0]), {}, {}, "xs", "cam", "targets",
                         1.7, "2k", "base", max_evals=7)
    assert len(evaluated) <= 7 + 2


def test_estimate_shape_alternates_macro_local_and_the_reference_poses(monkeypatch):
    """§4.3's schedule with every stage stood in: which frames, which stages, in which order, with which budgets."""
    import bodystudio.body

    log = []
    monkeypatch.setattr(bodystudio.body, "build_body", lambda ph, local, resolution: ("body", ph.to_dict()["height"],
                                                                                     dict(local), resolution))
    matched = []

    def fake_matched(ph, local, stature, template):
        matched.append((local, stature, template))
        return {**ph, "height": 0.25}

    monkeypatch.setattr(gf, "_stature_matched_height", fake_matched)
    monkeypatch.setattr(gf, "silhouette_target", lambda mask: ("target", int(mask)))
    monkeypatch.setattr(gf, "penetration_spheres", lambda body: ("spheres", body))

    def fake_space(body, base=None):
        if base is None:  # only the first body's space may build the standing prior
            base = "prior" if not any(e[0] == "pose" for e in log) else "a second prior"
        return SimpleNamespace(body=body, base=base)

    monkeypatch.setattr(gf, "pose_space", fake_space)

    def fake_starts(space, camera, t):
        assert space.body[0] == "body" and camera == "cam" and t[0] == "target"
        return [np.array([1.0]), np.array([2.0]), np.array([3.0])]

    monkeypatch.setattr(gf, "initial_placements", fake_starts)

    def fake_fit(x, problem, max_nfev):
        assert problem.camera == "cam" and problem.spheres == ("spheres", problem.space.body)
        assert problem.space.base == "prior" and problem.space.body[0] == "body"
        log.append(("pose", problem.target[1], float(x[0]), max_nfev, problem.with_height, problem.neighbour,
                    problem.space.body))
        return x + 0.5

    monkeypatch.setattr(gf, "fit_frame_pose", fake_fit)

    def fake_residuals(x, problem):
        assert problem.camera == "cam" and problem.target[0] == "target"
        return np.array([x[0] - 2.5])  # start 2 is best

    monkeypatch.setattr(gf, "pose_residuals", fake_residuals)

    def fake_nm(names, start, phenotype, local, xs, camera, targets, stature_m, template, base, max_evals):
        assert camera == "cam"
        log.append(("nm", names, start.tolist(), [float(x[0]) for x in xs], [t[1] for t in targets], stature_m,
                    template, base, max_evals))
        if names == gf.MACRO_PARAMETERS:
            return {**phenotype, "weight": 0.9}, local
        return phenotype, {**local, "upperarm-fat-decr-incr": 0.4}

    monkeypatch.setattr(gf, "nelder_mead_shape", fake_nm)
    masks = np.arange(10)
    out = gf.estimate_shape(masks, "cam", 1.7, template="6k", rounds=2, macro_evals=11, local_evals=22)
    assert out.reference.tolist() == [0, 3, 6, 9]
    first = log[:12]
    assert [e[1] for e in first] == [0, 0, 0, 3, 3, 3, 6, 6, 6, 9, 9, 9]
    assert [e[2] for e in first[:3]] == [1.0, 2.0, 3.0] and all(e[3] == 12 and e[4] and e[5] is None for e in first)
    nm = [e for e in log if e[0] == "nm"]
    assert [e[1] for e in nm] == [gf.MACRO_PARAMETERS, gf.LOCAL_PARAMETERS] * 2
    assert [e[8] for e in nm] == [11, 22, 11, 22]
    assert nm[0][3] == [2.5] * 4 and all(e[4] == [0, 3, 6, 9] and e[5] == 1.7 and e[6] == "6k" for e in nm)
    assert all(e[7] == "prior" for e in nm)  # the standing prior of the first body, kept for every later body
    assert matched == [({}, 1.7, "6k")]
    from bodystudio.body.phenotype import Phenotype

    default = Phenotype().to_dict()
    assert nm[0][2] == [default[k] if k != "height" else 0.25 for k in gf.MACRO_PARAMETERS]
    assert nm[1][2] == [0.0] * len(gf.LOCAL_PARAMETERS)
    assert nm[3][2] == [0.4 if k == "upperarm-fat-decr-incr" else 0.0 for k in gf.LOCAL_PARAMETERS]
    refits = [e for e in log if e[0] == "pose"][12:]
    assert [e[1] for e in refits] == [0, 3, 6, 9] * 2 and all(e[3] == 8 and e[4] for e in refits)
    assert refits[0][6] == ("body", 0.25, {"upperarm-fat-decr-incr": 0.4}, "6k")  # the new body's space
    assert [e[2] for e in refits] == [2.5] * 4 + [3.0] * 4 and nm[2][3] == [3.0] * 4
    assert out.xs[0].tolist() == [3.5] and len(out.xs) == 4
    assert out.phenotype["weight"] == 0.9 and out.phenotype["height"] == 0.25
    assert out.local == {"upperarm-fat-decr-incr": 0.4}
    assert out.body == ("body", 0.25, {"upperarm-fat-decr-incr": 0.4}, "6k")
    log.clear()
    few = gf.estimate_shape(np.arange(2), "cam", 1.7, rounds=0)
    assert few.reference.tolist() == [0, 1] and few.body[3] == "2k" and len(few.xs) == 2
    assert not [e for e in log if e[0] == "nm"]
    log.clear()
    gf.estimate_shape(np.arange(30), "cam", 1.7)  # defaults: four reference frames, two rounds of 80 and 100
    assert [e[8] for e in log if e[0] == "nm"] == [80, 100, 80, 100]
    assert sorted({e[1] for e in log if e[0] == "pose"}) == [0, 10, 19, 29]


# ------------------------------------------------------------------------------------------ the whole fit


def stand_in_fit(monkeypatch, stature_fit=1.70, ious=(0.9, 0.7, 0.95)):
    """fit_garment_video with each stage stood in; returns the call log."""
    import bodystudio.garment.fitfile as fitfile
    import bodystudio.garment.person as person
    from bodystudio.garment.lighting import Lighting
    from bodystudio.garment.person import PersonFrames

    log = {}
    n = len(ious)
    images = np.zeros((n, 48, 64, 3), np.uint8)
    masks = np.zeros((n, 48, 64), bool)
    masks[:, 10:40, 20:40] = True
    for k in range(n):
        masks[k, 0, k] = True  # each frame's matte its own
    pf = PersonFrames("clip.mp4", 24.0, np.array([5, 6, 7][:n]), images, masks)

    def fake_frames(source, frames, background):
        log["frames"] = (source, frames, background)
        return pf

    monkeypatch.setattr(person, "person_frames", fake_frames)
    body = SimpleNamespace(skeleton=SimpleNamespace(bone_names=("Root", "spine_02")), faces="F",
                           vertices=np.array([[0.0, 0.0, 0.0], [0.0, stature_fit, 0.0]]),
                           pose=lambda p: (np.full((3, 3), p.translation[0]), None))
    shape = gf.ShapeFit({"height": 0.4}, {"neck": 0.1}, body, np.array([1, 2]), [np.array([7.0]), np.array([8.0])])

    def fake_shape(m, camera, stature_m, template):
        log["shape"] = (m, camera, stature_m, template)
        return shape

    monkeypatch.setattr(gf, "estimate_shape", fake_shape)
    space = SimpleNamespace(pose=lambda x: Pose(np.full((2, 3), 0.1 * x[0]), [x[0], 0.0, 0.0]))
    log["space"] = space
    monkeypatch.setattr(gf, "pose_space", lambda b: space if b is body else None)

    def fake_track(sp, camera, m, start, x_start, constraints, progress=None, frame_ids=None):
        log["track"] = (sp, camera, m, start, x_start, constraints, frame_ids)
        progress()
        return np.arange(n, dtype=float)[:, None] + 1.0

    monkeypatch.setattr(gf, "track_poses", fake_track)
    ious_iter = iter(ious)

    def fake_iou(V, F, camera, m):
        log.setdefault("iou", []).append((float(V[0, 0]), F, camera, m))
        return next(ious_iter)

    monkeypatch.setattr(gf, "silhouette_iou", fake_iou)
    light = Lighting.single([0, 0, 1])

    def fake_appearance(imgs, m, posed, F, camera):
        log["appearance"] = (imgs, m, [float(V[0, 0]) for V in posed], F, camera)
        return np.full((4, 3), 0.5), light

    monkeypatch.setattr(gf, "estimate_appearance", fake_appearance)

    def fake_refine(sh, poses, m, camera, stature_m, template, allowance_m):
        call = (sh, [float(p.translation[0]) for p in poses], m, camera, stature_m, template, allowance_m)
        log.setdefault("refine", call)  # step 4b's first call; every call in "refines"
        log.setdefault("refines", []).append(call)
        return sh

    monkeypatch.setattr(gf, "refine_fit_shape", fake_refine)

    def fake_refine_poses(b, poses, m, camera, allowance_m):  # step 4c: each pose moved by 10
        log["refine_poses"] = (b, [float(p.translation[0]) for p in poses], m, camera, allowance_m)
        return [Pose(p.rotations, np.asarray(p.translation) + 10.0) for p in poses]

    monkeypatch.setattr(gf, "refine_fit_poses", fake_refine_poses)
    monkeypatch.setattr(fitfile, "save_garment_fit", lambda out, fit: log.setdefault("saved", (out, fit)))
    return log, pf, shape, light


def test_fit_garment_video_chains_the_stages_into_a_garment_fit(tmp_path, monkeypatch):
    log, pf, shape, light = stand_in_fit(monkeypatch)
    keys = tmp_path / "keys.json"
    keys.write_text('{"frames": {"6": {"spine_02": [3, 4]}}}')
    fit = gf.fit_garment_video("clip.mp4", 1.72, tmp_path / "out", frames="5-7", template="6k", focal_px=80.0,
                               keyframes=keys, background="plate.png")
    assert log["frames"] == ("clip.mp4", "5-7", "plate.png")
    m, camera, stature, template = log["shape"]
    assert m is pf.masks and stature == 1.72 and template == "6k"
    assert camera.fx == 80.0 and (camera.width, camera.height) == (64, 48)
    sp, cam2, m2, start, x_start, constraints, frame_ids = log["track"]
    assert sp is log["space"] and cam2 is camera and m2 is pf.masks and start == 1 and x_start.tolist() == [7.0]
    assert list(constraints) == [6] and np.array_equal(constraints[6]["spine_02"], [3, 4])
    assert np.array_equal(frame_ids, [5, 6, 7])
    # the poses of steps 4b-4c: tracked (1, 2, 3), then refined on the refined shape (+10)
    assert [e[0] for e in log["iou"]] == [11.0, 12.0, 13.0]
    assert all(e[1] == "F" and e[2] is camera for e in log["iou"])
    assert all(np.array_equal(e[3], pm) for e, pm in zip(log["iou"], pf.masks, strict=True))
    imgs, m3, posed, F, cam3 = log["appearance"]
    assert imgs is pf.images and m3 is pf.masks and posed == [11.0, 12.0, 13.0] and F == "F" and cam3 is camera
    assert log["saved"] == (tmp_path / "out", fit)
    assert fit.source == str(Path("clip.mp4").absolute())
    assert fit.fps == 24.0 and np.array_equal(fit.frame_ids, [5, 6, 7])
    assert fit.camera is camera and fit.template == "6k" and fit.bone_names == ("Root", "spine_02")
    assert fit.phenotype == {"height": 0.4} and fit.local == {"neck": 0.1} and fit.stature_m == 1.70
    assert np.allclose(fit.rotations[:, 0, 0], [0.1, 0.2, 0.3]) and np.array_equal(fit.translations[:, 0], [11, 12, 13])
    assert np.array_equal(fit.silhouette_iou, [0.9, 0.7, 0.95]) and fit.masks is pf.masks
    assert fit.lighting is light and np.array_equal(fit.albedo, np.full((4, 3), 0.5))
    sh, poses, m4, cam4, stature4, template4, allowance = log["refine"]  # step 4b: the tracked poses, held
    assert sh is shape and poses == [1.0, 2.0, 3.0] and m4 is pf.masks and cam4 is camera and stature4 == 1.72
    assert template4 == "6k" and allowance == CLOTHING_ALLOWANCE_M
    b5, poses5, m5, cam5, allowance5 = log["refine_poses"]  # step 4c: the tracked poses on the refined body
    assert b5 is shape.body and poses5 == [1.0, 2.0, 3.0] and m5 is pf.masks and cam5 is camera
    assert allowance5 == CLOTHING_ALLOWANCE_M
    assert len(log["refines"]) == 1  # 4b once: refining the shape again on the new poses was not kept
    assert set(fit.timings_ms) == {"masks", "shape", "pose", "shape_refinement", "pose_refinement", "appearance"}
    assert all(v >= 0 for v in fit.timings_ms.values())
    assert fit.warnings == ("fitted stature 1.700 m differs from the given 1.720 m by over 1 cm",
                            "1 of 3 frames have a silhouette IoU below 0.80")


def test_fit_garment_video_without_appearance_keys_or_warnings(tmp_path, monkeypatch):
    log, pf, shape, light = stand_in_fit(monkeypatch, stature_fit=1.715, ious=(0.8, 0.85, 0.9))
    fit = gf.fit_garment_video("clip.mp4", 1.72, appearance=False, shape_refinement=False)
    assert log["shape"][3] == "2k" and log["track"][5] is None and "appearance" not in log and "saved" not in log
    assert "refine" not in log and "refine_poses" not in log
    assert fit.lighting is None and fit.albedo is None and set(fit.timings_ms) == {"masks", "shape", "pose"}
    assert fit.warnings == ()  # 5 mm off the stature and IoU 0.80 are fine
    assert log["shape"][1].fx == pytest.approx(gf.focal_from_vfov(48))


def test_clip_lighting_keeps_to_the_mattes_and_draws_1500_rows_per_frame():
    from bodystudio.garment import lighting as lt

    images, masks, posed, F, cam, light, albedo = ball_frames()
    half = [m & (np.arange(m.shape[1]) < 30)[None] for m in masks]

    def written_out(ms, samples):
        rows = [lt.surface_samples(img, V, F, cam, albedo, samples, 3, seed=k, pixel_mask=m)
                for k, (img, m, V) in enumerate(zip(images, ms, posed, strict=True))]
        P, N, A, B = (np.concatenate([r[i] for r in rows]) for i in range(4))
        axis = cam.center - np.mean([V.mean(0) for V in posed], axis=0)
        return lt.estimate_lighting(P, N, A, B, axis / np.linalg.norm(axis)), sum(len(r[0]) for r in rows)

    got = gf.clip_lighting(images, half, posed, F, cam, albedo, samples_per_frame=10_000)
    want, n_rows = written_out(half, 10_000)
    full, n_full = written_out(masks, 10_000)
    assert n_rows < n_full and np.array_equal(got.directions, want.directions) and np.allclose(got.colors, want.colors)
    default = gf.clip_lighting(images, masks, posed, F, cam, albedo)
    want, n_rows = written_out(masks, 1500)
    assert n_rows == 3 * 1500 and np.array_equal(default.directions, want.directions)
    assert np.allclose(default.colors, want.colors)


def test_fit_garment_video_times_each_stage_per_frame_and_refuses_a_used_folder(tmp_path, monkeypatch):
    log, pf, shape, light = stand_in_fit(monkeypatch)
    ticks = iter(np.arange(100.0, 200.0, 0.5))
    monkeypatch.setattr(gf, "time", SimpleNamespace(perf_counter=lambda: float(next(ticks))))
    fit = gf.fit_garment_video("clip.mp4", 1.70)
    assert fit.timings_ms == {"masks": 166.7, "shape": 166.7, "pose": 166.7, "shape_refinement": 166.7,
                              "pose_refinement": 166.7, "appearance": 166.7}  # 500 ms / 3
    used = tmp_path / "out"
    used.mkdir()
    (used / "fit.json").write_text("{}")
    with pytest.raises(InputError, match=exact(f"fit folder {used}: exists and is not empty; choose a new folder")):
        gf.fit_garment_video("clip.mp4", 1.70, used)
    assert "saved" not in log


def test_initial_placement_of_a_one_row_matte():
    space, cam, _, _ = toy_target_and_space()
    m = np.zeros((120, 80), bool)
    m[50, 30:40] = True
    t = gf.silhouette_target(m)
    x = gf.initial_placement(space, cam, t)
    V = space.vertices(np.concatenate([np.zeros(6), space.base[space.bone_ids].ravel()]))
    assert -x[5] == pytest.approx(cam.fx * (V[:, 1].max() - V[:, 1].min()) / 1.0)  # at least one pixel tall


def test_fit_frame_pose_is_trust_region_least_squares_with_its_scales():
    space, cam, t, x_true = toy_target_and_space()
    spheres = gf.PenetrationSpheres(np.zeros((1, 3)), np.array([0.01]), np.array([0]), np.array([0]),
                                    np.array([0]), np.array([-1]))
    p = gf.PoseProblem(space, cam, t, spheres)
    x0 = x_true.copy()
    x0[3:5] += [0.05, 0.04]
    x0[9] += 0.2
    scale = np.concatenate([np.full(3, 0.3), np.full(3, 0.1), np.full(len(x0) - 6, 0.3)])
    want = scipy.optimize.least_squares(gf.pose_residuals, x0, args=(p,), method="trf", x_scale=scale,
                                        diff_step=1e-3, max_nfev=6, loss="linear").x
    assert np.array_equal(gf.fit_frame_pose(x0, p), want)
