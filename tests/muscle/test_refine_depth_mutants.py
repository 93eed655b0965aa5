"""Mutation tests of mus11n's refinement depth clean-up and rim cut and mus11o's grazing pairs in the capture
(issue 17, branch mutT; docs/mutation/muscle-capture.md "mus11n / mus11o").

The capture's Sec. 7 refinement is stubbed: what ``capture_arm_frames`` hands it (every argument, the clouds of the
refinement's own clean-up, their trees) and the time it books under "depth" are checked against values computed
here; the rim cut drops exactly the pairs of the vertices seen edge-on; both rest-shape fits (with and without their
poses) get the frames with the rest fit's own grazing cut; the options' refusals name the value and the range.
"""

from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.geometry.mesh import vertex_normals
from bodystudio.muscle import capture as cm
from bodystudio.muscle.depth import clean_depth, depth_point_cloud
from bodystudio.muscle.nicp import NicpOptions, apply_similarity, vertex_neighbourhoods
from bodystudio.muscle.refine import DepthFrame, edge_on_pairs, grazing_pairs
from tests.muscle.test_capture_analytic import Spies, scene  # noqa: F401  (the tiny capture scene)
from tests.muscle.test_refine_depth_bias import tube

FAST = dict(shape_frames=1, shape_rounds=1, first_frame_nicp_iterations=1, sequence_rounds=0,
            nicp=NicpOptions(iterations=1), pose_refit=False, body_rest_shape=False, pose_sigma_frames=0.0)
OWN = {"refine_depth_median_px": 3, "refine_depth_gaussian_sigma_px": 0.0}
PIPELINE = {"refine_depth_median_px": None, "refine_depth_gaussian_sigma_px": None}
REFINEMENT = cm._refinement


class _Clock:
    """``time.perf_counter`` of the capture module, one second a call: each step's booked time is its number of
    timer intervals."""

    def __init__(self):
        self.t = 0.0

    def perf_counter(self):
        self.t += 1.0
        return self.t


def _capture(s, monkeypatch, **options):
    """``capture_arm_frames`` with its refinement stubbed (the model meshes come back): the capture, the stub's
    arguments and keywords, the options."""
    handed = []

    def stub(*args, **kwargs):
        handed.append(SimpleNamespace(args=args, kwargs=kwargs))
        return args[0]

    monkeypatch.setattr(cm, "_refinement", stub)
    monkeypatch.setattr(cm, "time", _Clock())
    o = cm.CaptureOptions(**FAST, **options)
    cap = cm.capture_arm_frames(s.depths, s.camera, s.template, s.model, o, known_shape=s.shape)
    return cap, handed, o


def test_the_refinement_gets_every_input_with_the_clouds_of_its_own_clean_up(scene, monkeypatch):  # noqa: F811
    s = scene
    cap, handed, o = _capture(s, monkeypatch, **OWN)
    (call,) = handed
    assert len(call.args) == 11 and set(call.kwargs) == {"camera", "similarity"}
    meshes, poses, clouds, trees, F, C, arm, adjacency, J, options, timer = call.args
    S = cap.similarity
    assert call.kwargs["camera"] is s.camera and call.kwargs["similarity"] is S
    np.testing.assert_allclose(np.stack([apply_similarity(S, m) for m in meshes]), cap.stages["model"], atol=1e-12)
    assert poses is cap.poses and len(poses) == 3
    assert len(clouds) == len(trees) == 3
    for d, (P, N), tree in zip(s.depths, clouds, trees, strict=True):
        Pw, Nw = depth_point_cloud(clean_depth(d, cm.refinement_depth_options(o)), s.camera)
        np.testing.assert_allclose(apply_similarity(S, P), Pw, atol=1e-9)
        np.testing.assert_allclose(N @ S[1].T, Nw, atol=1e-12)
        np.testing.assert_array_equal(tree.data, P)
    np.testing.assert_array_equal(F, s.template.faces)
    np.testing.assert_allclose(apply_similarity(S, np.asarray(C)[None])[0], s.camera.center, atol=1e-12)
    np.testing.assert_array_equal(arm, s.template.arm_mask)
    assert (adjacency != vertex_neighbourhoods(F, len(s.template.vertices), rings=2)).nnz == 0
    np.testing.assert_allclose(J, cap.joints, atol=0.0)
    assert options.refine_depth_median_px == 3 and options.refine_depth_gaussian_sigma_px == 0.0
    assert isinstance(timer, cm._Timer)


def test_the_own_clean_up_is_booked_under_depth_and_skipped_when_it_is_the_pipelines(scene, monkeypatch):  # noqa: F811
    """One clock second per timer interval: the pipeline's three frames (3 s), the refinement's own clean-up one
    interval more; none when the refinement pairs with the pipeline's clouds (the same objects)."""
    own, _, _ = _capture(scene, monkeypatch, **OWN)
    pipe, handed, _ = _capture(scene, monkeypatch, **PIPELINE)
    assert own.timings_ms["depth"] == 4000.0 and pipe.timings_ms["depth"] == 3000.0
    assert set(own.timings_ms) == set(pipe.timings_ms)
    for (P, _), tree in zip(handed[0].args[2], handed[0].args[3], strict=True):
        np.testing.assert_array_equal(tree.data, P)


def test_the_rim_cut_drops_exactly_the_edge_on_vertices_pairs(scene, monkeypatch):  # noqa: F811
    """The refinement's pairs with the rim cut are its pairs without it less the vertices seen edge-on
    (``edge_on_pairs`` of each frame's model mesh, its normals and the sensor)."""
    _, handed, _ = _capture(scene, monkeypatch, **OWN)
    args = list(handed[0].args)
    monkeypatch.setattr(cm, "_refinement", REFINEMENT)
    valid = []
    real = cm.time_consistent_correspondences

    def spy(vectors, ok, sigma):
        valid.append([np.asarray(v).copy() for v in ok])
        return real(vectors, ok, sigma)

    monkeypatch.setattr(cm, "time_consistent_correspondences", spy)
    for cos in (0.0, 0.6):
        args[9] = cm.CaptureOptions(**FAST, **OWN, refine_min_facing_cos=cos, detail_sigma_frames=0.0)
        REFINEMENT(*args, **handed[0].kwargs)
    M, F, C = args[0][0], args[4], args[5]
    everything, cut = valid[0][0], valid[3][0]  # frame 0's pairs (first of the three windows) without / with the cut
    rim = edge_on_pairs(M, vertex_normals(M, F), C, 0.6)
    assert 0 < (everything & rim).sum() and (everything & ~rim).sum() > 0
    np.testing.assert_array_equal(cut, everything & ~rim)


@pytest.mark.parametrize("median", [None, 1, 3, 5])
def test_every_allowed_median_aperture_is_accepted(median):
    assert cm.CaptureOptions(refine_depth_median_px=median).refine_depth_median_px == median


@pytest.mark.parametrize("field, value, message", [
    ("refine_depth_median_px", 7, "refine_depth_median_px must be 1 (off), 3 or 5, got 7"),
    ("refine_depth_gaussian_sigma_px", -0.5, "refine_depth_gaussian_sigma_px must be >= 0, got -0.5"),
    ("refine_min_facing_cos", 1.5, "refine_min_facing_cos must be in [0, 1), got 1.5"),
    ("body_rest_min_facing_cos", 1.0, "body_rest_min_facing_cos and sequence_min_facing_cos must be in [0, 1), got "
                                      "1.0 and 0.3"),
    ("sequence_min_facing_cos", -0.1, "body_rest_min_facing_cos and sequence_min_facing_cos must be in [0, 1), got "
                                      "0.0 and -0.1"),
])
def test_the_refusals_name_the_value_and_the_range(field, value, message):
    with pytest.raises(InputError) as exc:
        cm.CaptureOptions(**{field: value})
    assert str(exc.value) == message


@pytest.mark.parametrize("field", ["body_rest_min_facing_cos", "sequence_min_facing_cos"])
def test_zero_and_just_under_one_are_accepted(field):
    for value in (0.0, 0.999):
        assert getattr(cm.CaptureOptions(**{field: value}), field) == value


@pytest.mark.parametrize("fit_poses", [True, False])
def test_the_rest_fits_get_the_rest_cut_and_their_own_inputs(scene, monkeypatch, fit_poses):  # noqa: F811
    """``body_rest_min_facing_cos`` reaches both rest-shape fits (with and without the poses) and the sequence fit
    keeps its own cut; the other positional inputs in their places (the shoulder anchor, the prior)."""
    s = scene
    name = "fit_body_rest_shape_and_poses" if fit_poses else "fit_body_rest_shape"
    spies = Spies(monkeypatch, (name, "fit_arm_sequence_skeleton"))
    o = cm.CaptureOptions(mode="model", shape_frames=2, shape_rounds=1, first_frame_nicp_iterations=2,
                          sequence_rounds=1, sequence_max_nfev=2, nicp=NicpOptions(iterations=1),
                          pose_sigma_frames=0.0, pose_refit=False, body_rest_rounds=1, body_rest_frame_stride=1,
                          body_rest_iterations=1, body_rest_keep_best=False, body_rest_fit_poses=fit_poses,
                          body_rest_min_facing_cos=0.2, sequence_min_facing_cos=0.25)
    cm.capture_arm_frames(s.depths, s.camera, s.template, s.model, o, tracker_joints=s.tracker, known_shape=s.shape)
    (call,) = spies[name]
    space, model, poses, frames, body_x, anchor, prior_mean, prior_sigma = call.args[:8]
    assert model is s.model and len(poses) == len(frames) == 3
    assert {f.min_facing_cos for f in frames} == {0.2}
    assert body_x.shape == prior_mean.shape == prior_sigma.shape == (space.n_parameters,)
    # the prior's spread the capture gives its rest fits (mus11r: the body population's on the local targets)
    np.testing.assert_array_equal(prior_sigma, space.prior(s.shape, local_sigma=cm.body_rest_local_sigma(o, space))[1])
    assert np.asarray(anchor).shape == (3,)
    np.testing.assert_allclose(anchor, spies["fit_arm_sequence_skeleton"][0].args[4][0], atol=1e-12)
    for seq in spies["fit_arm_sequence_skeleton"]:
        assert {f.min_facing_cos for f in seq.args[3]} == {0.25}


def test_the_cuts_at_their_exact_cosine_near_the_sensor():
    """A vertex off the origin half a metre from the sensor (the ray's length enters, not only its direction), its
    normal at cosine 0.8 exactly (0.6, 0, 0.8): neither cut takes a vertex at its own threshold."""
    V = np.array([[1.0, 2.0, 3.0]])
    sensor = V[0] + [0.0, 0.0, 0.5]
    N = np.array([[0.6, 0.0, 0.8]])
    assert not grazing_pairs(V, N, sensor, 0.8)[0] and grazing_pairs(V, N, sensor, 0.81)[0]
    assert not grazing_pairs(V, N, sensor, 0.5)[0]
    assert not edge_on_pairs(V, N, sensor, 0.8)[0] and edge_on_pairs(V, N, sensor, 0.81)[0]
    assert not edge_on_pairs(V, N, sensor, 0.5)[0]
    assert not edge_on_pairs(V, -N, sensor, 0.5)[0]  # facing away at the same angle: not the rim either


def test_plane_pairs_drop_the_grazing_ones_only_with_a_cut():
    """With every Sec. 5.2 filter off (the front-side one too) a frame whose cloud is the mesh itself pairs every
    vertex; its grazing cut keeps exactly the vertices ``grazing_pairs`` does not name, the back side among them
    only without the cut."""
    from scipy.spatial import cKDTree

    from bodystudio.muscle.nicp import CorrespondenceFilters

    V, F = tube(n_around=16, n_along=5)
    N = vertex_normals(V, F)
    sensor = np.array([0.0, 1.0, 1.0])
    off = CorrespondenceFilters(arm_only=False, front_only=False, normals=False, neighbours=False, length=False,
                                duplicates=False)
    frame = DepthFrame(V, N, cKDTree(V), sensor, np.ones(len(V), bool), vertex_neighbourhoods(F, len(V)), off, F)
    k, q, n = frame.plane_pairs(V)
    np.testing.assert_array_equal(k, np.arange(len(V)))
    np.testing.assert_allclose(q, V, atol=0.0)
    for cos in (0.3, 0.6):
        kc, qc, nc = DepthFrame(V, N, cKDTree(V), sensor, np.ones(len(V), bool), vertex_neighbourhoods(F, len(V)),
                                off, F, min_facing_cos=cos).plane_pairs(V)
        np.testing.assert_array_equal(kc, np.flatnonzero(~grazing_pairs(V, N, sensor, cos)))
        np.testing.assert_allclose(qc, V[kc], atol=0.0)
        np.testing.assert_allclose(nc, N[kc], atol=0.0)
