"""mus11j's hold of the unseen side, case by case (issue 17, mutation round mutR): ``refine.unseen_hold_weights``,
``refine_surface``'s ``hold=``, ``capture.hold_seen_vertices`` and ``capture._refinement``'s wiring of them.

``test_refine_unseen_hold.py`` measures the effect on a planted tube; these cases pin what it leaves open: weights
below 1, no seen vertex, a negative weight, a vertex with neither a pair nor a hold, a vertex exactly edge-on to the
sensor, the sensor off the origin, and the capture handing each frame's paired / front-facing / z-buffer-visible
vertices and the band to the weights (spies on a 3-frame tube; no ARAP solve where the wiring is the question).
"""

import functools
import warnings

import numpy as np
from scipy.spatial import cKDTree

from bodystudio.muscle import capture as cm
from bodystudio.muscle import refine as rf
from bodystudio.muscle.arm import ArmPose
from bodystudio.muscle.nicp import vertex_neighbourhoods
from tests.muscle.test_refine_unseen_hold import SENSOR, THICKER_M, tube

LINE = np.array([[0.0, 0, 0], [0.005, 0, 0], [0.01, 0, 0], [0.03, 0, 0]])
SEEN = np.array([True, False, False, False])


def test_hold_weights_below_one_ramp_too_and_nothing_seen_holds_everything():
    np.testing.assert_allclose(rf.unseen_hold_weights(LINE, SEEN, 0.5, 0.02), [0.0, 0.125, 0.25, 0.5])
    np.testing.assert_allclose(rf.unseen_hold_weights(LINE, SEEN, 0.5, 0.04), [0.0, 0.0625, 0.125, 0.375])
    # no vertex seen: every vertex held at the full weight (no distance to a seen vertex exists)
    np.testing.assert_array_equal(rf.unseen_hold_weights(LINE, np.zeros(4, bool), 0.5, 0.02), [0.5] * 4)
    np.testing.assert_array_equal(rf.unseen_hold_weights(LINE, [0, 0, 0, 0], 3.0, 0.02), [3.0] * 4)
    # a negative weight holds nothing, seen or not
    np.testing.assert_array_equal(rf.unseen_hold_weights(LINE, SEEN, -1.0, 0.02), [0.0] * 4)
    np.testing.assert_array_equal(rf.unseen_hold_weights(LINE, np.zeros(4, bool), -1.0, 0.02), [0.0] * 4)
    # the distance is to the nearest seen vertex, two of them; a 0/1 list is a mask, not indices
    np.testing.assert_allclose(rf.unseen_hold_weights(LINE, [True, False, False, True], 1.0, 0.02),
                               [0.0, 0.25, 0.5, 0.0])
    np.testing.assert_allclose(rf.unseen_hold_weights(LINE, [1, 0, 0, 0], 1.0, 0.02), [0.0, 0.25, 0.5, 1.0])
    for seen, weight in ((np.zeros(4, bool), 0.5), (SEEN, 0.0), (SEEN, -1.0)):
        assert rf.unseen_hold_weights(LINE, seen, weight, 0.02).shape == (4,)


def test_a_band_of_zero_holds_every_unseen_vertex_fully_without_dividing_by_it():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no 0 / 0 for the seen vertices, no d / 0 for the others
        np.testing.assert_array_equal(rf.unseen_hold_weights(LINE, SEEN, 2.0, 0.0), [0.0, 2.0, 2.0, 2.0])
        np.testing.assert_array_equal(rf.unseen_hold_weights(LINE, SEEN, 2.0, -0.01), [0.0, 2.0, 2.0, 2.0])


def test_a_vertex_with_neither_a_pair_nor_a_hold_keeps_its_model_position():
    """Weight 0 and hold 0 (a seen vertex without a pair): its correspondence vector, whatever it is, is not used
    (the division by the total weight is skipped there, not 0 / 0); the other vertices get the weighted mean."""
    V, F = tube(n_around=12, n_along=5)
    vectors = np.tile([0.0, 0.0, 0.004], (len(V), 1))
    w = np.ones(len(V))
    hold = np.ones(len(V))
    w[0], hold[0] = 0.0, 0.0
    X = rf.refine_surface(V, F, vectors, w, 1.0, 3, hold=hold)
    assert np.all(np.isfinite(X))
    np.testing.assert_allclose((X - V)[:, 2], 0.002, atol=1e-9)  # vertex 0 carried rigidly with the rest
    # the hold of a vertex with a pair and no weight of its own: pulled nowhere
    w2, hold2 = np.ones(len(V)), np.zeros(len(V))
    w2[:12] = 0.0
    hold2[:12] = 5.0
    X2 = rf.refine_surface(V, F, vectors, w2, 1.0, 3, hold=hold2)
    plain = rf.refine_surface(V, F, vectors, w2, 1.0, 3)
    assert np.abs(X2[:12] - V[:12]).max() < 2e-4 < np.abs(plain[:12] - V[:12]).max()


def test_the_seen_side_is_paired_or_facing_the_sensor_wherever_the_sensor_is():
    C = np.array([2.0, 0.0, 0.0])
    V = np.array([[3.0, 0, 0], [1.0, 0, 0], [2.0, 1.0, 0.0], [1.0, 0, 0]])
    N = np.array([[-1.0, 0, 0], [-1.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0]])
    # faces the sensor / faces away / exactly edge-on (dot 0: not facing) / faces it from the other side
    paired = np.zeros(4, bool)
    np.testing.assert_array_equal(cm.hold_seen_vertices(V, N, C, paired), [True, False, False, True])
    mask = cm.hold_seen_vertices(V, N, C, [0, 2, 0, 0])  # a 0/1 (or any integer) list is read as a mask
    assert mask.dtype == bool and mask.tolist() == [True, True, False, True]
    np.testing.assert_array_equal(cm.hold_seen_vertices(V, N, C, paired, np.array([False, False, True, False])),
                                  [True, False, True, True])


@functools.cache
def _frames():
    """A 3-frame tube whose depth points are the front of a 3 mm thicker tube (as test_refine_unseen_hold.py's), on
    one half of its length only: the other half's front faces the sensor without a pair."""
    V, F = tube(n_around=16, n_along=9)
    thick, _ = tube(radius=0.04 + THICKER_M, n_around=48, n_along=33)
    Nt = np.c_[np.zeros(len(thick)), thick[:, 1:] / np.linalg.norm(thick[:, 1:], axis=1, keepdims=True)]
    front = (thick[:, 2] < -0.01) & (thick[:, 0] < -0.02)
    return V, F, thick[front], Nt[front]


def _wiring(monkeypatch, options, camera=None, visible=None):
    """``_refinement`` with its ARAP stubbed (returns the model mesh): the calls of the hold's two functions."""
    V, F, P, N = _frames()
    calls = {"seen": [], "weights": [], "refine": []}
    real_seen, real_weights = cm.hold_seen_vertices, cm.unseen_hold_weights

    def seen_spy(*a, **k):
        out = real_seen(*a, **k)
        calls["seen"].append((a, k, out))
        return out

    def weights_spy(*a, **k):
        out = real_weights(*a, **k)
        calls["weights"].append((a, k, out))
        return out

    monkeypatch.setattr(cm, "hold_seen_vertices", seen_spy)
    monkeypatch.setattr(cm, "unseen_hold_weights", weights_spy)
    monkeypatch.setattr(cm, "refine_surface", lambda *a, **k: calls["refine"].append((a, k)) or a[0])
    if visible is not None:
        monkeypatch.setattr(cm, "model_visible_vertices", lambda M, F, camera: visible)
        monkeypatch.setattr(cm, "apply_similarity", lambda s, M: M)
    n = 3
    joints = np.array([[-1.0, 0, 0], [-0.9, 0, 0], [-0.8, 0, 0]])
    cm._refinement([V] * n, [ArmPose.rest()] * n, [(P, N)] * n, [cKDTree(P)] * n, F, SENSOR,
                   np.ones(len(V), bool), vertex_neighbourhoods(F, len(V)), joints, options, cm._Timer(),
                   camera=camera, similarity=None)
    return V, calls


def test_the_capture_hands_each_frames_seen_side_and_band_to_the_hold(monkeypatch):
    o = cm.CaptureOptions(refine_unseen_hold=0.7, refine_unseen_band_m=0.015, detail_sigma_frames=0.0)
    V, calls = _wiring(monkeypatch, o)
    assert len(calls["seen"]) == len(calls["weights"]) == len(calls["refine"]) == 3
    for (a, k, seen), (wa, wk, hold), (ra, rk) in zip(calls["seen"], calls["weights"], calls["refine"], strict=True):
        paired = a[3]
        assert paired.any() and (seen & ~paired).any() and not seen.all()
        np.testing.assert_array_equal(a[2], SENSOR)
        assert (a[4] if len(a) > 4 else k.get("visible")) is None  # no camera: no z-buffer
        np.testing.assert_array_equal(a[0], V)
        np.testing.assert_array_equal(seen, paired | (np.einsum("kd,kd->k", a[1], SENSOR - V) > 0))
        assert np.array_equal(wa[1], seen)  # every paired vertex is seen already: ok | seen = seen
        assert wa[2] == 0.7 and wa[3] == 0.015 and not wk
        np.testing.assert_array_equal(wa[0], V)
        assert ra[0] is wa[0] and ra[4:] == (o.refine_data_weight, o.refine_iterations)
        assert rk["hold"] is hold and hold.max() == 0.7 and not hold[seen].any()


def test_the_z_buffers_visible_vertices_are_seen_and_no_hold_means_none(monkeypatch):
    V, F, _, _ = _frames()
    visible = V[:, 2] > 0.035  # pretend the z-buffer shows some of the back
    o = cm.CaptureOptions(refine_unseen_hold=1.0, refine_visible_only=True, detail_sigma_frames=0.0)
    _, calls = _wiring(monkeypatch, o, camera=object(), visible=visible)
    for a, k, seen in calls["seen"]:
        np.testing.assert_array_equal(a[4] if len(a) > 4 else k["visible"], visible)
        assert seen[visible].all()
    for _, _, hold in calls["weights"]:
        assert not hold[visible].any() and hold.max() == 1.0


def test_no_hold_weight_means_no_hold_at_all(monkeypatch):
    for weight in (0.0, -0.0):
        o = cm.CaptureOptions(refine_unseen_hold=weight, detail_sigma_frames=0.0)
        _, calls = _wiring(monkeypatch, o)
        assert calls["weights"] == [] and [k["hold"] for _, k in calls["refine"]] == [None] * 3
        monkeypatch.undo()
