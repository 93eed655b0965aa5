"""The joint-distance term of the source-body fit (MIR12o): the SDK's bone lengths, averaged over the init frames,
pin the fitted body's proportions without going through the unposing pose.

Closed-form cases on the 2k statistical model (~1 s to load, each test well under a second): the averaged distances
recover the true ones from noisy, moved frames and drop a wild frame; the linearised rows are exact at the
linearisation point and their derivative is the distance's; a fit that sees only the front of the torso recovers
the planted shoulder width and limb lengths with the term, and does not without it.
"""

import functools

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.body.kinect import kinect_joint_names
from bodystudio.errors import InputError
from bodystudio.mirror.init import (
    BONE_LENGTH_WEIGHT,
    BONE_PAIRS,
    InitObservation,
    _model_kinect_joints,
    bone_length_rows,
    fit_shape,
    kinect_bone_lengths,
)

NAMES = kinect_joint_names("v2")
PAIRS = np.array([(NAMES.index(a), NAMES.index(b)) for a, b in BONE_PAIRS])


@functools.lru_cache(maxsize=1)
def _model_2k():
    from bodystudio.body.statistical import load_statistical_model

    return load_statistical_model("2k", progress=False)


@pytest.fixture(scope="module")
def model():
    return _model_2k()


def _planted(model, seed=3, scale=1.5):
    return np.random.default_rng(seed).normal(0.0, 1.0, model.n_components) * model.stddev * scale


def _joints(model, c, version="v2"):
    Jm, Jb = _model_kinect_joints(model, version)
    return Jm + np.tensordot(c, Jb, axes=1)


def _distances(J):
    return np.linalg.norm(J[PAIRS[:, 0]] - J[PAIRS[:, 1]], axis=1)


def _frames(J, n, noise_m, seed=0):
    """``n`` observations of the joints ``J`` moved rigidly (a random turn and step) with per-joint noise."""
    rng = np.random.default_rng(seed)
    out = []
    for f in range(n):
        R = Rotation.from_rotvec(rng.normal(0, 0.5, 3)).as_matrix()
        K = J @ R.T + rng.normal(0, 0.5, 3) + rng.normal(0, noise_m, J.shape)
        out.append(InitObservation(f, np.zeros((0, 3)), K, np.ones(len(J), bool), "v2"))
    return out


def test_mean_distances_recover_the_true_ones_and_drop_a_wild_frame(model):
    J = _joints(model, _planted(model))
    truth = _distances(J)
    obs = _frames(J, 60, 0.01)
    wild = obs[5].joints.copy()
    wild[NAMES.index("ShoulderLeft")] += [1.0, 0.0, 0.0]  # a tracking glitch: one shoulder a metre off
    obs[5] = InitObservation(5, wild[:0], wild, obs[5].tracked, "v2")
    L, n = kinect_bone_lengths(obs, "v2")
    assert np.all((n >= 50) & (n <= 60)) and n[0] < 60  # a few frames beyond 3 MADs (~2 sigma), the glitch among them
    # 1 cm per joint: each distance's noise ~1.4 cm per frame, ~2 mm over 60 frames (and a ~1 mm bias up)
    assert np.abs(L - truth).max() < 0.006
    plain = np.array([np.mean([np.linalg.norm(o.joints[a] - o.joints[b]) for o in obs]) for a, b in PAIRS])
    assert np.abs(plain - truth)[0] > 0.012  # the glitch moves a plain mean of the shoulder width by ~16 mm


def test_untracked_pairs_and_other_versions_give_nan(model):
    J = _joints(model, np.zeros(model.n_components))
    obs = _frames(J, 6, 0.0)
    ankle = NAMES.index("AnkleLeft")
    obs = [InitObservation(o.frame, o.points, o.joints, np.where(np.arange(len(J)) == ankle, o.frame < 2, True),
                           "v2") for o in obs]
    L, n = kinect_bone_lengths(obs, "v2")
    knee_ankle = [n for n, (a, b) in enumerate(BONE_PAIRS) if (a, b) == ("KneeLeft", "AnkleLeft")][0]
    assert np.isnan(L[knee_ankle]) and n[knee_ankle] == 0  # two frames track the ankle: fewer than three
    assert np.isfinite(np.delete(L, knee_ankle)).all()
    np.testing.assert_allclose(np.delete(L, knee_ankle), np.delete(_distances(J), knee_ankle), atol=1e-9)
    assert np.isnan(kinect_bone_lengths(obs, "v1")[0]).all()  # no observation of that version


def test_rows_are_exact_at_the_linearisation_point_and_have_the_distance_derivative(model):
    c0 = _planted(model, seed=4, scale=1.0)
    L = _distances(_joints(model, _planted(model, seed=5, scale=1.0)))
    L[2] = np.nan
    A, b, keep = bone_length_rows(model, c0, L, "v2")
    np.testing.assert_array_equal(keep, np.isfinite(L))
    assert A.shape == (keep.sum(), model.n_components)
    d0 = _distances(_joints(model, c0))[keep]
    np.testing.assert_allclose(A @ c0 - b, d0 - L[keep], atol=1e-12)
    for i in (0, 7, model.n_components - 1):
        h = 1e-4 * model.stddev[i]
        e = np.zeros(model.n_components)
        e[i] = h
        fd = (_distances(_joints(model, c0 + e)) - _distances(_joints(model, c0 - e)))[keep] / (2 * h)
        np.testing.assert_allclose(A[:, i], fd, rtol=1e-5, atol=1e-9)


def _front_torso_fit(model, c_true, weight, lengths):
    """Eq. 2 on the planted body's torso front only (the arms and legs unseen), matched to their vertices."""
    V = model.vertices(c_true)
    bone = np.argmax(model.weights, axis=1)
    names = model.skeleton(c_true).bone_names
    torso = np.isin(bone, [names.index(n) for n in ("spine_01", "spine_02", "spine_03", "pelvis")])
    m = np.flatnonzero(torso & (V[:, 2] > np.median(V[torso, 2])))
    return fit_shape(V[m] + [0.01, 0.0, -0.02], model, correspondence=m, iterations=3, bone_lengths=lengths,
                     bone_length_weight=weight, point_sigma_m=0.01)


def test_the_fit_takes_the_proportions_it_cannot_see_from_the_distances(model):
    c_true = _planted(model, seed=9, scale=1.5)
    truth = _distances(_joints(model, c_true))
    without = _front_torso_fit(model, c_true, 0.0, truth)
    with_term = _front_torso_fit(model, c_true, 30.0, truth)
    err_without = np.abs(_distances(_joints(model, without)) - truth)
    err_with = np.abs(_distances(_joints(model, with_term)) - truth)
    # the torso front alone leaves the limbs near the population mean (measured 4.9 mm mean, 14 mm the shoulders);
    # with the distances at weight 30 they come within 0.6 mm (1.4 mm at most)
    assert err_without.mean() > 0.004 and err_without.max() > 0.01
    assert err_with.mean() < 0.2 * err_without.mean() and err_with.max() < 0.003
    # the term's weight matters and NaN lengths or a zero weight leave the fit as it was
    np.testing.assert_array_equal(_front_torso_fit(model, c_true, 0.0, truth), without)
    np.testing.assert_array_equal(_front_torso_fit(model, c_true, 30.0, np.full_like(truth, np.nan)), without)
    weak = _front_torso_fit(model, c_true, 0.3, truth)
    assert np.abs(_distances(_joints(model, weak)) - truth).mean() > 3.0 * err_with.mean()  # measured 3.7 mm


def test_the_weight_is_per_frame_and_v1_has_no_neck(model):
    """A weight per pair is not their mean; Kinect v1 has no Neck joint, so its two neck pairs give no row."""
    c = _planted(model, seed=2, scale=1.0)
    L = _distances(_joints(model, c))
    per_pair = np.arange(1.0, len(BONE_PAIRS) + 1)
    V = model.vertices(c)
    m = np.arange(0, len(V), 9)
    one = fit_shape(V[m], model, correspondence=m, iterations=2, bone_lengths=L + 0.01, bone_length_weight=per_pair)
    same = fit_shape(V[m], model, correspondence=m, iterations=2, bone_lengths=L + 0.01,
                     bone_length_weight=per_pair.mean())
    assert np.abs(one - same).max() > 1e-4 * model.stddev.max()
    _, _, keep = bone_length_rows(model, c, L, "v1")
    assert keep.sum() == len(BONE_PAIRS) - 2


def test_initialisation_passes_the_mean_distances_with_their_frame_counts(model, monkeypatch):
    """initialise_from_observations hands fit_shape the SDK's mean distances over *every* observation (not only the
    fitted frames) and BONE_LENGTH_WEIGHT-style weights per frame behind each; off by default (MIR12o: the option
    did not hold a held-out session's warp_iou)."""
    from bodystudio.mirror import init as init_mod

    assert BONE_LENGTH_WEIGHT == 0.0
    J, obs, seen = _recorded_bone_length_fits(model, monkeypatch)
    init_mod.initialise_from_observations(obs, model, passes=1, max_frames=4, bone_length_weight=2.0)
    lengths, weight = seen[0]
    np.testing.assert_allclose(lengths, _distances(J), atol=1e-9)
    np.testing.assert_allclose(weight, np.full(len(BONE_PAIRS), 2.0 * 12))  # 12 observations, 4 fitted
    init_mod.initialise_from_observations(obs, model, passes=1, max_frames=4)
    assert seen[1] == (None, 0.0)
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(InputError, match="bone_length_weight must be a finite number >= 0"):
            init_mod.initialise_from_observations(obs, model, passes=1, bone_length_weight=bad)


def _recorded_bone_length_fits(model, monkeypatch):
    """A planted body's joints, 12 observations of its vertices, and the list each ``fit_shape`` call then appends
    its ``(bone_lengths, bone_length_weight)`` to (the fit and the default-pose transform stood in)."""
    from bodystudio.mirror import init as init_mod

    c = _planted(model, seed=6, scale=1.0)
    J = _joints(model, c)
    V = model.vertices(c)
    frames = _frames(J, 12, 0.0, seed=4)
    obs = [InitObservation(o.frame, V[:: 3] + [0.0, 0.0, 2.0], o.joints, o.tracked, "v2") for o in frames]
    seen = []

    def fake_fit(P, model, *args, **kwargs):
        seen.append((kwargs.get("bone_lengths"), kwargs.get("bone_length_weight")))
        return (np.zeros(model.n_components), 0.01)

    monkeypatch.setattr(init_mod, "fit_shape", fake_fit)
    monkeypatch.setattr(init_mod, "transform_to_default_pose", _all_points_matched)
    return J, obs, seen


def _all_points_matched(P, joints, body, tracked=None, version="v2", details=False, **kwargs):
    from bodystudio.mirror.init import DefaultPoseCloud

    n = len(P)
    return DefaultPoseCloud(np.asarray(P, float), np.arange(n) % len(body.vertices), np.arange(len(body.vertices)),
                            None, body)
