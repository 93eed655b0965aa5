"""reconstruct_session's shape-prior wiring (issue 15's ``shape_prior``, ``shape_prior_outer``,
``shape_prior_first_outer``), with Algorithm 1 and the shape space replaced by recording stand-ins.

Which passes each mode runs, from which start, towards which smoothness reference and with how many outer
iterations; what the shape space's functions get (the first pass's result, the frame's bone transforms and
scale, the run's mean coefficients); the per-frame record (the two passes' counts and times added up, the
prior's time in ``init_ms``, on a clock that only the stand-ins advance), run.json and the one-line errors.
The maths behind the stand-ins is tested in test_shape_prior_analytic.py; the accuracy on a real session in
test_shape_prior_session.py (slow).
"""

import json
from types import SimpleNamespace

import numpy as np
import pytest

import bodystudio.body.statistical as statistical
import bodystudio.reconstruct.sequence as sequence
from bodystudio.errors import InputError
from bodystudio.geometry.mesh import load_mesh
from bodystudio.reconstruct.rapid_skin import RapidSkinParams

NO = 3  # the run's outer iterations
MODEL = object()  # the shape space the stand-ins expect to be handed


@pytest.fixture(scope="module")
def session_3():
    import tempfile
    from pathlib import Path

    from bodystudio.capture.synth import synth_session

    # a folder of its own (not tmp_path_factory): docs/mutation/recheck_direct.py builds the fixture too
    return synth_session(Path(tempfile.mkdtemp(prefix="spw-")) / "walk", n_cameras=2, n_frames=3, motion="walk",
                         subject_seed=23, resolution=(160, 120), template="2k", noise=False, kinect="v2")


def _fakes(monkeypatch):
    """Recording stand-ins for Algorithm 1, the shape space and its loader, and a clock only they advance."""
    log = SimpleNamespace(deform=[], prior=[], coeffs=[], posed=[], load=[], inits=[], clock=[0.0])
    monkeypatch.setattr(sequence, "time", SimpleNamespace(perf_counter=lambda: log.clock[0]))

    def deform(V_start, F, cameras, masks, params, depth=None, delta=None, smooth_reference=None, fields=None):
        k = len(log.deform)
        log.deform.append(dict(start=np.array(V_start), outer=params.outer_iterations, F=F, cameras=cameras,
                               masks=masks, depth=depth, delta=delta, reference=np.array(smooth_reference),
                               fields=fields, constraints=params.constraints))
        out = np.asarray(V_start) + 0.001 * (k + 1)
        log.deform[-1]["out"] = out
        return SimpleNamespace(vertices=out, solver_s=0.25 / (k + 1), matching_s=0.0625 / (k + 1),
                               n_silhouette=[100 * k + i for i in range(params.outer_iterations)],
                               n_depth=[1000 * k + i for i in range(params.outer_iterations)])

    def prior(model, body, deformed, T, scale=1.0, *rest):
        assert not rest
        log.prior.append(dict(model=model, body=body, deformed=np.array(deformed), T=np.array(T), scale=scale))
        log.clock[0] += 1.0
        return np.asarray(deformed) - 0.0005

    def coeffs(model, body, deformed, T, *rest):
        assert not rest
        log.coeffs.append(dict(model=model, body=body, deformed=np.array(deformed), T=np.array(T)))
        log.clock[0] += 0.125
        k = len(log.coeffs)
        return np.array([k, 10.0 * k, 100.0 * k])

    def posed(model, body, c, T, scale=1.0, *rest):
        assert not rest
        log.posed.append(dict(model=model, body=body, c=np.array(c), T=np.array(T), scale=scale))
        log.clock[0] += 0.03125
        return log.inits[-1].vertices + 0.002

    def load(resolution, progress=True):
        log.load.append((resolution, progress))
        return MODEL

    real_init = sequence.initialise_pose

    def init(*a, **kw):
        log.inits.append(real_init(*a, **kw))
        log.clock[0] += 4.0  # the initialisation's own time, which the prior's adds to
        return log.inits[-1]

    monkeypatch.setattr(sequence, "deform_to_observations", deform)
    monkeypatch.setattr(sequence, "shape_prior_mesh", prior)
    monkeypatch.setattr(sequence, "deformed_shape_coefficients", coeffs)
    monkeypatch.setattr(sequence, "posed_shape", posed)
    monkeypatch.setattr(sequence, "initialise_pose", init)
    monkeypatch.setattr(statistical, "load_statistical_model", load)
    return log


def _run(session, monkeypatch, frames="0:2", refine_pose=False, **kw):
    log = _fakes(monkeypatch)
    sequence.reconstruct_session(session.path, template="2k", frames=frames, refine_pose=refine_pose, score=False,
                                 accept_implausible=True, constraints=("silhouette", "depth"),
                                 params=RapidSkinParams(outer_iterations=NO, constraints=("silhouette", "depth")),
                                 **kw)
    root = session.path / "reconstruct"
    return log, json.loads((root / "frames.json").read_text())["frames"], json.loads((root / "run.json").read_text())


def _same_inputs(first, second):
    for key in ("F", "cameras", "masks", "depth", "delta", "fields", "constraints"):
        assert second[key] is first[key], key
    assert first["depth"] is not None and first["masks"] is not None


def test_off_runs_one_pass_and_loads_no_shape_space(session_3, monkeypatch):
    log, frames, run = _run(session_3, monkeypatch)
    assert log.load == [] and log.prior == log.coeffs == log.posed == []
    assert [d["outer"] for d in log.deform] == [NO, NO]
    assert run["shape_prior"] == "off" and run["shape_prior_outer"] == 0 and run["shape_prior_first_outer"] == 0
    assert [f["init_ms"] for f in frames] == [4000.0, 4000.0]


@pytest.mark.parametrize("first_outer, outer, expected", [(0, 0, [NO, NO]), (1, 2, [1, 2]), (2, 5, [2, NO])])
def test_frame_prior_starts_and_regularises_a_second_pass(session_3, monkeypatch, first_outer, outer, expected):
    log, frames, run = _run(session_3, monkeypatch, shape_prior="frame", shape_prior_outer=outer,
                            shape_prior_first_outer=first_outer)
    assert log.load == [("2k", False)]
    assert [d["outer"] for d in log.deform] == expected * 2
    assert log.coeffs == [] and log.posed == []
    assert len(log.prior) == 2
    for i, (init, p, f) in enumerate(zip(log.inits, log.prior, frames, strict=True)):
        first, second = log.deform[2 * i], log.deform[2 * i + 1]
        np.testing.assert_array_equal(first["start"], init.vertices)
        assert p["model"] is MODEL and p["body"].vertices.shape == init.vertices.shape
        np.testing.assert_array_equal(p["deformed"], first["out"])
        np.testing.assert_array_equal(p["T"], init.bone_transforms)
        assert p["scale"] == init.global_scale and init.global_scale != 1.0
        np.testing.assert_array_equal(second["start"], first["out"] - 0.0005)
        np.testing.assert_array_equal(second["reference"], first["out"] - 0.0005)
        _same_inputs(first, second)
        # the record adds both passes up; the prior's time counts as initialisation
        k = 2 * i
        assert f["n_silhouette"] == [100 * k + j for j in range(expected[0])] + [100 * (k + 1) + j
                                                                                for j in range(expected[1])]
        assert f["n_depth"] == [1000 * k + j for j in range(expected[0])] + [1000 * (k + 1) + j
                                                                            for j in range(expected[1])]
        assert f["solver_ms"] == pytest.approx(1000 * (0.25 / (k + 1) + 0.25 / (k + 2)))
        assert f["matching_ms"] == pytest.approx(1000 * (0.0625 / (k + 1) + 0.0625 / (k + 2)))
        assert f["init_ms"] == pytest.approx(5000.0)
        fid = run["frames"][i]
        mesh = load_mesh(session_3.path / "reconstruct" / "meshes" / f"{fid:05d}.ply")
        np.testing.assert_allclose(mesh.vertices, second["out"], atol=1e-5)
    assert run["shape_prior"] == "frame" and run["shape_prior_outer"] == outer
    assert run["shape_prior_first_outer"] == first_outer


def test_run_prior_carries_the_mean_coefficients(session_3, monkeypatch):
    log, frames, run = _run(session_3, monkeypatch, frames="0:3", shape_prior="run", shape_prior_outer=2,
                            shape_prior_first_outer=1)
    assert log.load == [("2k", False)] and run["shape_prior"] == "run"
    # two passes at the first frame, then one from the run's shape (the run's No: first_outer is the first's)
    assert [d["outer"] for d in log.deform] == [1, 2, NO, NO]
    assert len(log.prior) == 1 and len(log.coeffs) == 3 and len(log.posed) == 2
    for c, init, d in zip(log.coeffs, log.inits, [log.deform[1], log.deform[2], log.deform[3]], strict=True):
        assert c["model"] is MODEL and c["body"].vertices.shape == init.vertices.shape
        np.testing.assert_array_equal(c["deformed"], d["out"])
        np.testing.assert_array_equal(c["T"], init.bone_transforms)
    for p, init, d, mean in zip(log.posed, log.inits[1:], log.deform[2:], ([1.0, 10, 100], [1.5, 15, 150]),
                                strict=True):
        assert p["model"] is MODEL and p["body"].vertices.shape == init.vertices.shape
        np.testing.assert_array_equal(p["c"], mean)
        np.testing.assert_array_equal(p["T"], init.bone_transforms)
        assert p["scale"] == init.global_scale
        np.testing.assert_array_equal(d["start"], init.vertices + 0.002)
        np.testing.assert_array_equal(d["reference"], init.vertices + 0.002)
    assert [f["init_ms"] for f in frames] == pytest.approx([5125.0, 4156.25, 4156.25])
    assert frames[1]["n_silhouette"] == [200, 201, 202]


@pytest.mark.parametrize("kw, message", [
    (dict(shape_prior="pca"), r"^unknown shape prior 'pca'; valid: auto, off, frame, run, carried$"),
    (dict(shape_prior="frame", shape_prior_outer=-1),
     r"^shape_prior_outer -1: give 0 \(the run's No\) to 100 outer iterations$"),
    (dict(shape_prior="frame", shape_prior_outer=101),
     r"^shape_prior_outer 101: give 0 \(the run's No\) to 100 outer iterations$"),
    (dict(shape_prior="frame", shape_prior_first_outer=-1),
     r"^shape_prior_first_outer -1: give 0 \(the run's No\) to 100 outer iterations$"),
    (dict(shape_prior="frame", shape_prior_first_outer=101),
     r"^shape_prior_first_outer 101: give 0 \(the run's No\) to 100 outer iterations$"),
])
def test_shape_prior_settings_refused(session_3, monkeypatch, kw, message):
    with pytest.raises(InputError, match=message):
        _run(session_3, monkeypatch, **kw)


def test_hundred_outer_iterations_accepted(session_3, monkeypatch):
    log, _, run = _run(session_3, monkeypatch, frames="0", shape_prior="frame", shape_prior_outer=100,
                       shape_prior_first_outer=100)
    assert [d["outer"] for d in log.deform] == [NO, NO]
    assert run["shape_prior_outer"] == 100 and run["shape_prior_first_outer"] == 100


def test_a_batch_chunk_runs_without_the_prior(session_3, monkeypatch):
    """bodystudio.batch calls reconstruct_frames with none of the shape-prior keywords: one pass, off in run.json."""
    from bodystudio.capture.session import open_session
    from bodystudio.runfolder import RunWriter

    log = _fakes(monkeypatch)
    session = open_session(session_3.path)
    params = RapidSkinParams(outer_iterations=NO)
    with RunWriter(sequence.reconstruction_layout(session.path), "test", {}) as writer:
        sequence.reconstruct_frames(session, writer, [session.frame_ids[0]], list(session.cameras), session.kinect,
                                    params, "gs", "2k", "tracker", None, False, False, False, False)
    run = json.loads((session.path / "reconstruct" / "run.json").read_text())
    assert [d["outer"] for d in log.deform] == [NO] and log.load == [] and log.prior == []
    assert run["shape_prior"] == "off" and run["shape_prior_outer"] == 0 and run["shape_prior_first_outer"] == 0


def test_both_passes_get_the_frames_silhouette_fields(session_3, monkeypatch):
    """With the pose refined on the silhouettes' distance fields, both passes are handed those fields."""
    log, _, _ = _run(session_3, monkeypatch, frames="0", refine_pose=True, shape_prior="frame")
    first, second = log.deform
    assert first["fields"] is not None
    _same_inputs(first, second)


def test_delta_coordinates_of_the_rest_template_or_of_the_runs_shape(session_3, monkeypatch):
    """Eq. 8's weights: of the template's rest shape by default; with ``rest_cotangents=False`` of each pass's
    smoothness reference, so in ``run`` mode of the run's shape (posed_shape's mesh)."""
    from bodystudio.body import build_body
    from bodystudio.geometry.laplacian import cotangent_weights

    F = build_body(resolution="2k").faces
    log, _, _ = _run(session_3, monkeypatch, shape_prior="run")
    rest = cotangent_weights(log.prior[0]["body"].vertices, F).weights
    for d in log.deform:
        np.testing.assert_allclose(d["delta"].weights, rest, rtol=1e-12)
    log, _, _ = _run(session_3, monkeypatch, shape_prior="run", rest_cotangents=False)
    for d in log.deform[0], log.deform[2]:  # the first pass of frame 0 (the posed template), frame 1's only pass
        np.testing.assert_allclose(d["delta"].weights, cotangent_weights(d["reference"], F).weights, rtol=1e-12)
    assert np.abs(log.deform[2]["delta"].weights - rest).max() > 1e-6
