"""The image-plane registration of the posed bodies to the person's outline (MIR12p, ``mirror.image_plane``).

A disc against the same disc moved: the outline offsets are the move along each normal and one bone's translation
recovers it; a disc against a grown one: the growth. A body rendered 2.5 px right and 1.5 px up of where it is posed
is moved there (both bodies alike); switched on, the run registers the one player's bodies and makes their pairs
again, not with several players.
"""

import numpy as np
import pytest

from bodystudio.body import build_body
from bodystudio.body.population import sample_population
from bodystudio.geometry.camera import Camera
from bodystudio.mirror.image_plane import (
    bone_translations,
    image_plane_shift,
    outline_offsets,
    register_to_outline,
)
from bodystudio.mirror.warp import warp_pairs


def _disc(shape, centre, radius):
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    return (xx - centre[0]) ** 2 + (yy - centre[1]) ** 2 <= radius**2


def _circle(centre, radius, n=72):
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.c_[centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a)], np.c_[np.cos(a), np.sin(a)]


def test_a_moved_disc_gives_its_move_and_a_grown_one_its_growth():
    origin = (10, 20)
    source = _disc((100, 100), (50, 50), 20)  # crop pixels; image centre (60, 70)
    uv, radial = _circle((60, 70), 20)
    fg = _disc((200, 200), (63, 68), 20)  # moved by (3, -2)
    offset, normal, on = outline_offsets(uv, source, fg, origin)
    assert on.all()
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", normal, radial)), 1.0, atol=0.05)  # outward
    gap = np.abs(offset - radial @ [3.0, -2.0])  # pixel masks: their distances are a pixel's to a pixel
    assert np.median(gap) < 0.5 and gap.max() < 1.3
    t = bone_translations(np.ones((len(uv), 1)), [-1], normal, offset, ridge=1e-3)
    np.testing.assert_allclose(t[0], [3.0, -2.0], atol=0.3)  # one step of point-to-line: 92 % of the move
    grown = _disc((200, 200), (60, 70), 22)
    offset, normal, _ = outline_offsets(uv, source, grown, origin)
    assert abs(np.median(offset) - 2.0) < 0.3 and np.abs(offset - 2.0).max() < 1.0
    tg = bone_translations(np.ones((len(uv), 1)), [-1], normal, offset, ridge=1e-3, dilation=True)
    np.testing.assert_allclose(tg[0], [0.0, 0.0, 2.0], atol=0.3)
    # a point off the outline is flagged
    assert not outline_offsets(np.array([[60.0, 70.0]]), source, fg, origin)[2][0]


def _camera():
    R = np.diag([1.0, -1.0, -1.0])  # looking along -z at the body's front, y down
    return Camera("c", np.array([[525.0, 0, 320], [0, 525.0, 240], [0, 0, 1]]), np.zeros(5), R,
                  -R @ np.array([0.05, 0.9, 2.6]), 640, 480)


def test_image_plane_shift_moves_each_projection_by_its_shift():
    cam = _camera()
    rng = np.random.default_rng(0)
    V = rng.normal([0, 0.9, 0], 0.3, (50, 3))
    shift = rng.normal(0, 3, (50, 2))
    np.testing.assert_allclose(cam.project(image_plane_shift(V, shift, cam)) - cam.project(V), shift, atol=1e-9)
    depth = lambda X: (X @ cam.R.T + cam.t)[:, 2]  # noqa: E731
    np.testing.assert_allclose(depth(image_plane_shift(V, shift, cam)), depth(V), atol=1e-12)


def _iou(pairs, fg):
    """The source body's silhouette (``pairs.dense``) against ``fg``."""
    x0, y0 = pairs.dense.origin
    h, w = pairs.dense.source_mask.shape
    m = np.zeros_like(fg)
    m[y0:y0 + h, x0:x0 + w] = pairs.dense.source_mask
    return (m & fg).sum() / (m | fg).sum()


@pytest.fixture(scope="module")
def body():
    phenotype, local = sample_population(1, seed=5)[0]
    return build_body(phenotype, local, resolution="2k")


def test_a_body_is_moved_onto_its_shifted_silhouette(body):
    cam = _camera()
    V = body.vertices
    Vt = V * [0.97, 0.95, 0.97]  # a shorter, thinner target
    shift = np.array([2.5, -1.5])
    seen = warp_pairs(image_plane_shift(V, np.tile(shift, (len(V), 1)), cam), V, body.faces, cam, 400, dense=True)
    x0, y0 = seen.dense.origin
    fg = np.zeros((480, 640), bool)
    h, w = seen.dense.source_mask.shape
    fg[y0:y0 + h, x0:x0 + w] = seen.dense.source_mask  # the person's mask: the body moved
    pairs = warp_pairs(V, Vt, body.faces, cam, 400, dense=True)
    Vs2, Vt2, info = register_to_outline(V, Vt, body.faces, body.weights, body.skeleton.parents, cam, fg,
                                         pairs.dense.source_mask, pairs.dense.source_depth, pairs.dense.origin)
    assert info["outline_vertices"] > 100 and 1.5 < info["mean_abs_offset_px"] < 3.5
    moved = cam.project(Vs2) - cam.project(V)
    # one step, its translations tied to none (RIDGE_WEIGHT) and outliers weighed down (HUBER_PX): most of the move
    # across the limbs' and the trunk's vertical outline, less along it (few outline normals point up or down)
    med = np.median(moved, axis=0)
    assert 1.5 < med[0] < 2.7 and -1.7 < med[1] < -0.5
    before, after = _iou(pairs, fg), _iou(warp_pairs(Vs2, Vt2, body.faces, cam, 400, dense=True), fg)
    assert before < 0.87 and after > 0.94  # 0.857 -> 0.950
    np.testing.assert_allclose(cam.project(Vt2) - cam.project(Vt), moved, atol=0.05)  # the target alike
    # too few outline vertices (no foreground near the body): the bodies come back as they are
    none = register_to_outline(V, Vt, body.faces, body.weights, body.skeleton.parents, cam, np.zeros_like(fg),
                               pairs.dense.source_mask, pairs.dense.source_depth, pairs.dense.origin)
    assert none[0] is V and none[1] is Vt


@pytest.mark.parametrize("several", [False, True])
def test_the_run_registers_one_players_bodies_and_pairs_them_again(monkeypatch, several):
    from types import SimpleNamespace

    from test_run_mutants import _two_player_session

    from bodystudio.mirror import frames as frames_mod
    from bodystudio.mirror import image_plane as image_plane_mod
    from bodystudio.mirror import refine as refine_mod
    from bodystudio.mirror import run as run_mod

    session, b1, b2, model, rec, blocks, spec = _two_player_session(monkeypatch)
    for b in (b1, b2):
        b.weights = f"w{b.p}"
        b.skeleton = SimpleNamespace(parents=f"parents{b.p}")
    monkeypatch.setattr(refine_mod, "refine_plan", lambda *a, **kw: "plan")
    monkeypatch.setattr(refine_mod, "refine_pose", lambda *args, **kw: args[2])
    monkeypatch.setattr(refine_mod, "updated_posture", lambda posture, *a, **kw: posture)  # stand-in skeletons
    monkeypatch.setattr(frames_mod, "point_cloud", lambda frame, sensor, p: np.array([[0.0, 0.5, 2.0]]))
    dense = SimpleNamespace(source_mask="mask", source_depth="depth", origin=(1, 2))
    original = run_mod.frame_pairs

    def frame_pairs(sources, targets, faces, camera, correspondence):
        p = original(sources, targets, faces, camera, correspondence)
        return SimpleNamespace(src_uv=p.src_uv, dst_uv=p.dst_uv, groups=p.groups, dense=dense)

    calls = []

    def register(Vs, Vt, faces, weights, parents, camera, fg, mask, depth, origin):
        calls.append((float(Vs[0, 0]), weights, parents, int(fg.sum()), mask, depth, origin))
        return Vs + 100.0, Vt + 100.0, {}

    monkeypatch.setattr(run_mod, "frame_pairs", frame_pairs)
    monkeypatch.setattr(image_plane_mod, "register_to_outline", register)
    monkeypatch.setattr(run_mod, "REGISTER_OUTLINE_ONE_PLAYER", True)
    players, bodies = ([1, 2], [b1, b2]) if several else (1, b1)
    rec["pairs"].clear()
    fg = np.ones((12, 16), bool)
    for o in run_mod.session_inputs(session, bodies, model, {"taller": 1.0}, players, 2, [1], refine=True):
        o.late_pairs(fg, {})
    if several:  # two players reshaped: no registration, one pairing
        assert calls == [] and rec["pairs"] == [("one", 1.0)]
    else:  # the player's foreground, then the registered bodies paired
        assert calls == [(1.0, "w1", "parents1", int(fg.sum()), "mask", "depth", (1, 2))]
        assert rec["pairs"] == [("one", 1.0), ("one", 101.0)]
    monkeypatch.setattr(run_mod, "REGISTER_OUTLINE_ONE_PLAYER", False)  # the option off
    calls.clear()
    rec["pairs"].clear()
    for o in run_mod.session_inputs(session, bodies, model, {"taller": 1.0}, players, 2, [1], refine=True):
        o.late_pairs(fg, {})
    assert calls == [] and rec["pairs"] == [("one", 1.0)]


def test_the_registration_is_on_by_default():
    """mir12u: the outline registration gains on every one of the 14 re-made sessions: a run reshaping one player
    registers its bodies unless REGISTER_OUTLINE_ONE_PLAYER is switched off."""
    from bodystudio.mirror import run as run_mod

    assert run_mod.REGISTER_OUTLINE_ONE_PLAYER is True


def test_registered_pairs_pairs_the_moved_bodies_again_or_keeps_the_first_pairing(body):
    """``run.registered_pairs`` (the run's and bench_mirror's one call): the bodies moved onto the outline and paired
    again; the first pairing itself where too few outline vertices register or there is no dense correspondence."""
    from types import SimpleNamespace

    from bodystudio.mirror.run import registered_pairs

    cam = _camera()
    V = body.vertices
    Vt = V * [0.97, 0.95, 0.97]
    seen = warp_pairs(image_plane_shift(V, np.tile([2.5, -1.5], (len(V), 1)), cam), V, body.faces, cam, 400,
                      dense=True)
    x0, y0 = seen.dense.origin
    fg = np.zeros((480, 640), bool)
    h, w = seen.dense.source_mask.shape
    fg[y0:y0 + h, x0:x0 + w] = seen.dense.source_mask
    pairs = warp_pairs(V, Vt, body.faces, cam, 400, dense=True)
    again = registered_pairs(pairs, V, Vt, body.faces, body.weights, body.skeleton.parents, cam, fg, "dense")
    assert again is not pairs and again.dense is not None
    assert _iou(pairs, fg) < 0.87 and _iou(again, fg) > 0.94  # the registered bodies' pairs, not the first ones
    kept = registered_pairs(pairs, V, Vt, body.faces, body.weights, body.skeleton.parents, cam, np.zeros_like(fg),
                            "dense")
    assert kept is pairs
    sparse = SimpleNamespace(dense=None)
    assert registered_pairs(sparse, V, Vt, body.faces, body.weights, body.skeleton.parents, cam, fg) is sparse
