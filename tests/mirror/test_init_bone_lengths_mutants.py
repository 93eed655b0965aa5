"""Mutation tests of MIR12o's joint distances in the source-body fit (issue 17, branch mutT;
docs/mutation/mirror-init.md "MIR12o"): ``bone_pair_indices`` and ``kinect_bone_lengths`` on hand-placed joints whose
distances are exact binary fractions (no model needed): the pairs a version lacks, frames of another version among
the others, a NaN joint outside every pair, exactly three frames, values exactly at and beyond three median absolute
deviations, float32 joints; and on the 2k model (cached by test_init_bone_lengths.py) the term's switch in
``fit_shape`` (lengths and a positive weight both needed) and a weight below one handed on by the initialisation.
"""

import numpy as np

from bodystudio.body.kinect import kinect_joint_names
from bodystudio.mirror.init import BONE_PAIRS, InitObservation, bone_pair_indices, kinect_bone_lengths

NAMES = kinect_joint_names("v2")
WIDTH = BONE_PAIRS.index(("ShoulderLeft", "ShoulderRight"))
UPPER_ARM = BONE_PAIRS.index(("ShoulderLeft", "ElbowLeft"))


def _joints(width, upper_arm, dtype=np.float64, diagonal=False):
    """v2 joints: every joint 0.0625 m apart along z, the shoulders ``width`` apart along x and the left elbow
    ``upper_arm`` below the left shoulder (exact norms; ``diagonal``: also ``upper_arm`` behind it)."""
    K = np.zeros((len(NAMES), 3))
    K[:, 2] = 0.0625 * np.arange(len(NAMES))
    shoulder = K[NAMES.index("ShoulderLeft")]
    K[NAMES.index("ShoulderRight")] = shoulder + [width, 0.0, 0.0]
    K[NAMES.index("ElbowLeft")] = shoulder - [0.0, upper_arm, upper_arm if diagonal else 0.0]
    return K.astype(dtype)


def _obs(widths, arms, version="v2", dtype=np.float64, diagonal=False):
    return [InitObservation(f, np.zeros((0, 3)), _joints(w, a, dtype, diagonal), np.ones(len(NAMES), bool), version)
            for f, (w, a) in enumerate(zip(widths, arms, strict=True))]


def test_pairs_a_version_lacks_are_minus_one():
    v1 = bone_pair_indices("v1")
    names = kinect_joint_names("v1")
    neck = [n for n, pair in enumerate(BONE_PAIRS) if "Neck" in pair]
    assert len(neck) == 2
    np.testing.assert_array_equal(v1[neck], [[names.index("ShoulderCenter"), -1], [-1, names.index("Head")]])
    assert (np.delete(v1, neck, axis=0) >= 0).all()
    assert (bone_pair_indices("v2") >= 0).all()


def test_at_three_deviations_a_frame_is_kept_beyond_it_dropped():
    """Widths 0.25, 0.5, 0.5, 0.75, 1.25: median 0.5, MAD 0.25, the last exactly 3 MADs off (kept); upper arms with
    the last at 1.375 (3.5 MADs: dropped)."""
    L, n = kinect_bone_lengths(_obs([0.25, 0.5, 0.5, 0.75, 1.25], [0.25, 0.5, 0.5, 0.75, 1.375]), "v2")
    assert (L[WIDTH], n[WIDTH]) == (0.65, 5)
    assert (L[UPPER_ARM], n[UPPER_ARM]) == (0.5, 4)
    assert n.dtype.kind == "i"


def test_three_frames_are_enough_and_other_versions_and_nan_joints_outside_the_pairs_are_skipped():
    obs = _obs([0.5, 0.25, 0.75], [0.5, 0.5, 0.5])
    v1 = InitObservation(9, np.zeros((0, 3)), np.zeros((20, 3)), np.ones(20, bool), "v1")
    obs = [v1] + obs
    hand = NAMES.index("HandTipLeft")  # in no pair
    obs[1].joints[hand] = np.nan
    obs[1].tracked[hand] = False
    L, n = kinect_bone_lengths(obs, "v2")
    assert (L[WIDTH], n[WIDTH]) == (0.5, 3) and (L[UPPER_ARM], n[UPPER_ARM]) == (0.5, 3)
    assert np.isfinite(L).all() and (n == 3).all()


def test_float32_joints_are_measured_in_float64():
    """The SDK's joints as float32 (a diagonal upper arm, whose norm rounds differently in float32)."""
    w = np.float32(0.3)
    L, _ = kinect_bone_lengths(_obs([w] * 3, [w] * 3, dtype=np.float32, diagonal=True), "v2")
    K = _joints(w, w, np.float32, diagonal=True).astype(np.float64)
    want = np.linalg.norm(K[NAMES.index("ShoulderLeft")] - K[NAMES.index("ElbowLeft")])
    assert L[UPPER_ARM] == want and L.dtype == np.float64
    K32 = _joints(w, w, np.float32, diagonal=True)
    assert float(np.linalg.norm(K32[NAMES.index("ShoulderLeft")] - K32[NAMES.index("ElbowLeft")])) != want


def test_the_term_needs_both_the_lengths_and_a_positive_weight():
    """On the 2k model (cached by test_init_bone_lengths.py): lengths without a weight (the default 0), a weight
    without lengths, and a zero weight leave the Eq. 2 fit exactly as it is; a weight below one already moves it."""
    from bodystudio.mirror.init import fit_shape
    from tests.mirror.test_init_bone_lengths import _distances, _joints, _model_2k, _planted

    model = _model_2k()
    c = _planted(model, seed=2, scale=1.0)
    L = _distances(_joints(model, c)) + 0.01
    V = model.vertices(c)
    m = np.arange(0, len(V), 9)

    def fit(**kw):
        return fit_shape(V[m], model, correspondence=m, iterations=2, **kw)

    plain = fit()
    np.testing.assert_array_equal(fit(bone_lengths=L), plain)
    np.testing.assert_array_equal(fit(bone_lengths=None, bone_length_weight=30.0), plain)
    np.testing.assert_array_equal(fit(bone_lengths=L, bone_length_weight=0.0), plain)
    assert np.abs(fit(bone_lengths=L, bone_length_weight=0.5) - plain).max() > 1e-6 * model.stddev.max()


def test_initialisation_hands_the_distances_on_at_a_weight_below_one(monkeypatch):
    from bodystudio.mirror import init as init_mod
    from tests.mirror.test_init_bone_lengths import _all_points_matched, _distances, _frames, _joints, _model_2k

    model = _model_2k()
    J = _joints(model, np.zeros(model.n_components))
    V = model.vertices(np.zeros(model.n_components))
    obs = [InitObservation(o.frame, V[::3] + [0.0, 0.0, 2.0], o.joints, o.tracked, "v2") for o in _frames(J, 5, 0.0)]
    seen = []

    def fake_fit(P, model, *args, **kwargs):
        seen.append((kwargs.get("bone_lengths"), kwargs.get("bone_length_weight")))
        return (np.zeros(model.n_components), 0.01)

    monkeypatch.setattr(init_mod, "fit_shape", fake_fit)
    monkeypatch.setattr(init_mod, "transform_to_default_pose", _all_points_matched)
    init_mod.initialise_from_observations(obs, model, passes=1, max_frames=2, bone_length_weight=0.5)
    np.testing.assert_allclose(seen[0][0], _distances(J), atol=1e-9)
    np.testing.assert_allclose(seen[0][1], np.full(len(BONE_PAIRS), 0.5 * 5))
