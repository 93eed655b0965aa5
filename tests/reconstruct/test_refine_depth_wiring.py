"""reconstruct_session's ``refine_depth`` wiring (issue 15's neck front): the pose refinement gets the Kinect's
depth term beside the silhouettes' with the given weight, only where depth constraints are on, and run.json
records it. The depth term itself is tested in test_pose_depth_neck.py."""

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import bodystudio.reconstruct.sequence as sequence
from bodystudio.errors import InputError


@pytest.fixture(scope="module")
def session_3(small_synth_session, tmp_path_factory):
    """A copy of the suite's shared small session (4 cameras, 3 frames, 320x240, Kinect v1)."""
    import shutil

    return shutil.copytree(small_synth_session, tmp_path_factory.mktemp("rdw") / "session")


def _record(monkeypatch):
    calls = {"depth": [], "rows": []}
    real_depth_term = sequence.depth_data_term

    def depth_term(obs, F, weight, vertices=None):
        calls["depth"].append((obs, weight))
        calls["vertices"] = vertices
        inner = real_depth_term(obs, F, weight, vertices=vertices)

        def term(V, N):
            out = inner(V, N)
            calls["rows"].append(("depth", len(out[0])))
            return out

        return term

    def refine(body, T, hull, params, data_term=None, anchors=None):
        from bodystudio.geometry.mesh import vertex_normals
        from bodystudio.reconstruct.pose_init import pose_template

        V = pose_template(body, T).vertices  # the frame's initial pose: its neck and head face the Kinect
        N = vertex_normals(V, body.faces)
        calls["rows"].append(("all", len(data_term(V, N)[0])))
        return T

    monkeypatch.setattr(sequence, "depth_data_term", depth_term)
    monkeypatch.setattr(sequence, "refine_bone_transforms", refine)
    return calls


@pytest.mark.parametrize("weight", [0.0, 2.5])
def test_depth_term_joins_the_refinement_with_its_weight(monkeypatch, session_3, weight):
    calls = _record(monkeypatch)
    sequence.reconstruct_session(session_3, template="2k", constraints=("silhouette", "depth"), score=False,
                                 refine_depth=weight, params=sequence.RapidSkinParams(
                                     constraints=("silhouette", "depth"), outer_iterations=1, inner_iterations=1),
                                 accept_implausible=True)
    run = json.loads((Path(session_3) / "reconstruct" / "run.json").read_text())
    assert run["refine_depth"] == weight and run["refine_depth_bones"] == "neck"
    if weight == 0.0:
        assert calls["depth"] == []
        return
    assert [w for _, w in calls["depth"]] == [weight] * 3  # once per frame (per-frame initialisation)
    assert all(obs.n_points > 0 for obs, _ in calls["depth"])
    # the neck's and head's vertices of the 2.5K refinement template only (pose_depth.DEPTH_BONES)
    mask = calls["vertices"]
    assert mask is not None and 0 < mask.sum() < 0.25 * len(mask)
    # each refinement's data term stacks the silhouette rows and this frame's depth rows
    pairs = list(zip(calls["rows"][0::2], calls["rows"][1::2], strict=True))
    assert all(d[0] == "depth" and a[0] == "all" and a[1] > d[1] > 0 for d, a in pairs)


def test_no_depth_term_without_depth_constraints(monkeypatch, session_3):
    calls = _record(monkeypatch)
    sequence.reconstruct_session(session_3, template="2k", constraints=("silhouette",), score=False, refine_depth=3.0,
                                 params=sequence.RapidSkinParams(outer_iterations=1, inner_iterations=1),
                                 accept_implausible=True)
    assert calls["depth"] == []


@pytest.mark.parametrize("bad", [-1.0, float("nan"), 1e4])
def test_bad_depth_weight_is_a_one_line_error(session_3, bad):
    with pytest.raises(InputError, match="refine_depth"):
        sequence.reconstruct_session(session_3, template="2k", constraints=("silhouette", "depth"), refine_depth=bad)


def test_depth_bones_select_the_rows(monkeypatch, session_3):
    from bodystudio.body import build_body
    from bodystudio.reconstruct.pose_depth import bone_vertices

    fit = build_body(resolution="2k")
    masks = {}
    for bones in ("neck", "all", "spine_03+neck_01+head"):
        calls = _record(monkeypatch)
        sequence.reconstruct_session(session_3, template="2k", constraints=("silhouette", "depth"), score=False,
                                     refine_depth=1.0, refine_depth_bones=bones, frames="0:1", accept_implausible=True,
                                     params=sequence.RapidSkinParams(constraints=("silhouette", "depth"),
                                                                     outer_iterations=1, inner_iterations=1))
        masks[bones] = calls["vertices"]
    assert masks["all"] is None
    np.testing.assert_array_equal(masks["neck"], bone_vertices(fit, ("neck_01", "head")))
    assert masks["spine_03+neck_01+head"].sum() > masks["neck"].sum()
    assert np.all(masks["spine_03+neck_01+head"][masks["neck"]])


def test_unknown_depth_bone_is_a_one_line_error(session_3):
    with pytest.raises(InputError, match="refine_depth_bones: no bone"):
        sequence.reconstruct_session(session_3, template="2k", constraints=("silhouette", "depth"), refine_depth=1.0,
                                     refine_depth_bones="spine_99")


@pytest.mark.parametrize(("e_both", "kept"), [(0.0104, "depth"), (0.0108, "silhouettes"), (0.03, "silhouettes")])
def test_guard_keeps_the_depth_pose_only_where_the_silhouettes_agree(monkeypatch, session_3, e_both, kept):
    """``refine_depth_guard`` 0.05: the pose refined with the depth term is kept unless it leaves more than 5 % more
    of the 2.5K template outside the silhouettes than the silhouettes-only refinement (issue 15: the turn's torso
    twisted by the depth term, 0.16 -> 0.52 % outside at its frame 0)."""
    combine = sequence.combined_data_term

    def tagged(*terms):
        term = combine(*terms)
        term.both = True
        return term

    def refine(body, T, hull, params, data_term=None, anchors=None):
        out = np.array(T, dtype=np.float64)
        if getattr(data_term, "both", False):
            out[:, 0, 3] += 0.5  # the depth's pose: the whole body 0.5 m along x
        return out

    starts = []

    def deform(V_start, F, cameras, masks, params, **kw):
        starts.append(np.asarray(V_start).mean(axis=0))
        return SimpleNamespace(vertices=np.asarray(V_start), solver_s=0.0, matching_s=0.0, n_silhouette=[0],
                               n_depth=[0])

    def outside(V, fields, outside_px=2.0):
        return e_both if np.asarray(V)[:, 0].mean() > 0.3 else 0.01

    monkeypatch.setattr(sequence, "combined_data_term", tagged)
    monkeypatch.setattr(sequence, "refine_bone_transforms", refine)
    monkeypatch.setattr(sequence, "deform_to_observations", deform)
    monkeypatch.setattr(sequence, "outside_fraction", outside)
    sequence.reconstruct_session(session_3, template="2k", constraints=("silhouette", "depth"), score=False,
                                 refine_depth=3.0, refine_depth_guard=0.05, frames="0:1", accept_implausible=True,
                                 params=sequence.RapidSkinParams(constraints=("silhouette", "depth")))
    frames = json.loads((Path(session_3) / "reconstruct" / "frames.json").read_text())["frames"]
    assert frames[0]["refine_depth_outside"] == [0.01, e_both]
    assert (starts[0][0] > 0.3) == (kept == "depth")
