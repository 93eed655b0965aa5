"""Issue 17's standard on rec15e's frame-time trade-offs (mutN): :class:`MatchSchedule`'s bounds, iteration plan and
keyword arguments exactly; :func:`hull_consistent_constraints`' memo of the gate's decisions on an analytic hull
(which pairs are gated, what is written); the schedule's wiring in :func:`deform_to_observations` (what each outer
iteration hands the matching and the gate); ``silhouette_constraints``' outline bookkeeping. Small stand-ins, fast."""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.geometry.camera import Camera
from bodystudio.reconstruct import rapid_skin
from bodystudio.reconstruct.rapid_skin import RapidSkinParams, deform_to_observations, hull_consistent_constraints
from bodystudio.reconstruct.silhouette import (
    _OUTLINE_STEP_PX,
    MatchSchedule,
    SilhouetteViews,
    area_weighted_normals,
    silhouette_constraints,
    silhouette_mask,
)
from bodystudio.reconstruct.solver import SilhouetteConstraints
from bodystudio.reconstruct.tracking import TrackParams

FIELDS = ("vertex", "origin", "direction", "k", "camera", "pixel_distance")


def _equal(a, b):
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


@pytest.mark.parametrize("name, lo, hi", [("cheap_iterations", 0, 100), ("rim_stride", 1, 16),
                                          ("view_stride", 1, 16)])
def test_schedule_integer_bounds_are_inclusive_and_named(name, lo, hi):
    assert getattr(MatchSchedule(**{name: lo}), name) == lo
    assert getattr(MatchSchedule(**{name: hi}), name) == hi
    for bad in (lo - 1, hi + 1):
        with pytest.raises(InputError, match=rf"^matching {name} {bad} is out of range; use a value in "
                                             rf"\[{lo}, {hi}\]$"):
            MatchSchedule(**{name: bad})


def test_schedule_step_and_gate_are_checked():
    for ok in (0.5, 2.0, 20.0):
        assert MatchSchedule(kept_outline_step_px=ok).kept_outline_step_px == ok
    for bad, shown in ((0.49, "0.49"), (20.01, "20.01"), (np.nan, "nan"), (np.inf, "inf")):
        with pytest.raises(InputError, match=rf"^matching kept_outline_step_px {shown} is out of range; use a value "
                                             r"in \[0.5, 20\] \(pixels\)$"):
            MatchSchedule(kept_outline_step_px=bad)
    for gate in ("each", "reuse", "off"):
        assert MatchSchedule(gate=gate).gate == gate
    with pytest.raises(InputError, match=r"^matching gate 'Each' is unknown; use each, reuse or off$"):
        MatchSchedule(gate="Each")
    d = MatchSchedule()  # the paper's matching
    assert (d.cheap_iterations, d.keep_outline, d.kept_outline_step_px, d.rim_stride, d.view_stride, d.gate) == \
        (0, False, _OUTLINE_STEP_PX, 1, 1, "each")


def test_first_cheap_iteration_is_never_the_first():
    assert [MatchSchedule().first_cheap(n) for n in (1, 3, 8)] == [1, 3, 8]  # none cheap
    assert [MatchSchedule(cheap_iterations=1).first_cheap(n) for n in (1, 2, 3, 8)] == [1, 1, 2, 7]
    assert [MatchSchedule(cheap_iterations=3).first_cheap(n) for n in (2, 3, 4, 8)] == [1, 1, 1, 5]


def test_matching_args_per_outer_iteration_exactly():
    plain = MatchSchedule(cheap_iterations=2, rim_stride=3, kept_outline_step_px=5.0)  # no kept outline
    got = [plain.matching_args(o, 5, 4) for o in range(5)]
    assert got[:3] == [{}, {}, {}]  # nothing drawn whole for a schedule that keeps no outline
    for a in got[3:]:
        assert a == {"outline": "draw", "rim_stride": 3, "use_view": None, "outline_step_px": _OUTLINE_STEP_PX}
    kept = MatchSchedule(cheap_iterations=2, keep_outline=True, view_stride=3, kept_outline_step_px=5.0)
    got = [kept.matching_args(o, 5, 7) for o in range(5)]
    assert got[0] == {} and got[1] == {} and got[2] == {"outline": "full"}
    for o in (3, 4):
        a = got[o]
        assert a["outline"] == "keep" and a["rim_stride"] == 1 and a["outline_step_px"] == 5.0
        assert a["use_view"].dtype == np.bool_
        np.testing.assert_array_equal(a["use_view"], np.arange(7) % 3 == o % 3)
    two = MatchSchedule(cheap_iterations=2, view_stride=2)  # the smallest stride that skips views
    for o in (3, 4):
        np.testing.assert_array_equal(two.matching_args(o, 5, 5)["use_view"], np.arange(5) % 2 == o % 2)
    # all iterations cheap but the first: the first one draws whole
    every = MatchSchedule(cheap_iterations=9, keep_outline=True)
    assert every.matching_args(0, 3, 2) == {"outline": "full"}
    assert every.matching_args(1, 3, 2)["use_view"] is None


def test_gate_at_switches_at_the_first_cheap_iteration():
    for gate in ("each", "reuse", "off"):
        s = MatchSchedule(cheap_iterations=2, gate=gate)
        assert [s.gate_at(o, 5) for o in range(5)] == ["each", "each", "each", gate, gate]
    assert [MatchSchedule(gate="off").gate_at(o, 3) for o in range(3)] == ["each"] * 3


def test_params_take_a_schedule_dict_and_refuse_other_types():
    p = RapidSkinParams(matching={"cheap_iterations": 1, "gate": "reuse"})
    assert p.matching == MatchSchedule(cheap_iterations=1, gate="reuse") and isinstance(p.matching, MatchSchedule)
    with pytest.raises(InputError, match=r"^matching must be a MatchSchedule, got list$"):
        RapidSkinParams(matching=[1])


class _Ball:
    """An analytic hull: a ball of radius 0.1 m at the origin (signed distance, m); counts the points it is asked."""

    def __init__(self):
        self.asked = 0

    def implicit_hull(self, P):
        P = np.asarray(P, float)
        self.asked += len(P)
        return np.linalg.norm(P, axis=1) - 0.1, None


def _ball_constraints():
    """Vertices on the ball; rays from 1 m out along x: half of the targets inside the ball, half 5 cm outside."""
    ang = np.linspace(0.0, 2 * np.pi, 8, endpoint=False)
    V = 0.1 * np.c_[np.cos(ang), np.sin(ang), np.zeros(8)]
    vertex = np.array([0, 1, 2, 3, 0, 1, 2, 3, 4, 5], np.int64)
    camera = np.array([0, 0, 0, 0, 1, 1, 1, 1, 1, 1], np.int64)
    origin = np.zeros((10, 3))
    direction = np.zeros((10, 3))
    for i, v in enumerate(vertex):
        target = V[v] * (1.0 if i % 2 == 0 else 1.5)  # on the ball, or 5 cm out
        origin[i] = target + [0.0, 0.0, 1.0]
        direction[i] = [0.0, 0.0, -1.0]
    return V, SilhouetteConstraints(vertex, origin, direction, np.linspace(0.1, 1.0, 10), camera,
                                    np.arange(10.0))


def test_gate_memo_records_reuses_and_fills_in_decisions():
    V, sil = _ball_constraints()
    plain = hull_consistent_constraints(V, sil, _Ball(), 0.001)
    np.testing.assert_array_equal(plain.vertex, sil.vertex[::2])  # the targets 5 cm out are dropped
    _equal(plain, SilhouetteConstraints(sil.vertex[::2], sil.origin[::2], sil.direction[::2], sil.k[::2],
                                        sil.camera[::2], sil.pixel_distance[::2]))
    memo = np.zeros(2 * len(V), np.int8)
    ball = _Ball()
    _equal(hull_consistent_constraints(V, sil, ball, 0.001, memo=memo, reuse=False), plain)
    slot = sil.camera * len(V) + sil.vertex
    np.testing.assert_array_equal(memo[slot], np.where(np.arange(10) % 2 == 0, 1, 2))
    assert (np.delete(memo, slot) == 0).all()  # nothing else written
    # reuse: the memo decides, the hull is not asked, even where it would decide otherwise now
    flipped = memo.copy()
    flipped[slot] = 3 - memo[slot]
    ball = _Ball()
    again = hull_consistent_constraints(V, sil, ball, 0.001, memo=flipped, reuse=True)
    assert ball.asked == 0
    np.testing.assert_array_equal(again.vertex, sil.vertex[1::2])
    np.testing.assert_array_equal(again.camera, sil.camera[1::2])
    # not reusing: every pair gated anew and its decision written over the old one
    ball = _Ball()
    _equal(hull_consistent_constraints(V, sil, ball, 0.001, memo=flipped, reuse=False), plain)
    np.testing.assert_array_equal(flipped[slot], memo[slot])
    assert ball.asked > 0
    # two undecided pairs (camera 1's vertices 4 and 5): only they are gated, one kept and one dropped
    part = memo.copy()
    part[slot[8:]] = 0
    ball = _Ball()
    got = hull_consistent_constraints(V, sil, ball, 0.001, memo=part, reuse=True)
    _equal(got, plain)
    np.testing.assert_array_equal(part, memo)
    assert ball.asked == 4  # two unique vertices and two targets


def test_gate_memo_is_reused_by_default():
    V, sil = _ball_constraints()
    memo = np.zeros(2 * len(V), np.int8)
    slot = sil.camera * len(V) + sil.vertex
    memo[slot] = 1  # every pair decided "keep" earlier
    ball = _Ball()
    assert len(hull_consistent_constraints(V, sil, ball, 0.001, memo=memo)) == len(sil) and ball.asked == 0


def test_gate_memo_needs_cameras_and_everything_kept_is_the_input():
    V, sil = _ball_constraints()
    memo = np.zeros(2 * len(V), np.int8)
    no_cam = SilhouetteConstraints(sil.vertex, sil.origin, sil.direction, sil.k)
    got = hull_consistent_constraints(V, no_cam, _Ball(), 0.001, memo=memo)
    np.testing.assert_array_equal(got.vertex, sil.vertex[::2])
    assert got.camera is None and got.pixel_distance is None
    assert (memo == 0).all()  # without cameras the memo is not used
    inside = SilhouetteConstraints(sil.vertex[::2], sil.origin[::2], sil.direction[::2], sil.k[::2],
                                   sil.camera[::2], sil.pixel_distance[::2])
    assert hull_consistent_constraints(V, inside, _Ball(), 0.001) is inside
    assert hull_consistent_constraints(V, inside, _Ball(), 0.001, memo=memo, reuse=True) is inside
    empty = SilhouetteConstraints.empty()
    assert hull_consistent_constraints(V, empty, _Ball(), 0.001, memo=memo) is empty


@pytest.fixture(scope="module")
def scene():
    """A template sphere inside a 'body' of two merged spheres seen by four ring cameras (as
    test_frame_tradeoffs.py, smaller)."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=2, radius=0.12)
    V, F = np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)
    arm = 0.6 * V + np.array([0.2, 0.0, 0.0])
    scene_V, scene_F = np.vstack([1.05 * V, arm]), np.vstack([F, F + len(V)])
    cams = [Camera.look_at(f"c{i}", (3 * np.sin(a), 0.4, 3 * np.cos(a)), (0, 0, 0), fx=500.0, width=200, height=160)
            for i, a in enumerate(np.linspace(0.0, 2 * np.pi, 4, endpoint=False) + 0.3)]
    masks = {c.name: silhouette_mask(scene_V, scene_F, c) for c in cams}
    Vs = V + np.random.default_rng(5).normal(0.0, 0.003, V.shape)
    return Vs, F, cams, masks


@pytest.mark.parametrize("packed", [True, False])
def test_outline_bookkeeping_of_the_matching(scene, packed):
    """``outline_whole`` records whether the buffers hold whole rasters: a drawn (probe tiles only) outline is not
    kept, a whole one is, and ``keep`` after a drawn one draws whole first. ``rim_stride`` 0 is the full matching;
    the occlusion test's step is the one given (a half-pixel step reads inside the template's own outline: fewer
    rim vertices pass the occlusion test, 108 against 123 here)."""
    V, F, cams, masks = scene
    N = area_weighted_normals(V, F)
    ref = silhouette_constraints(V, F, N, cams, masks, 20.0, 5.0, 0.2)
    assert (ref.vertex % 2 == 1).any() and (ref.vertex % 2 == 0).any()  # every rim vertex a candidate by default
    views = SilhouetteViews(cams, masks, F)
    if not packed:
        views.packed = None
    assert views.outline_whole is False
    _equal(silhouette_constraints(V, F, N, cams, None, 20.0, 5.0, 0.2, views=views, rim_stride=0), ref)
    assert views.outline_whole is False
    moved = 1.1 * V
    silhouette_constraints(moved, F, area_weighted_normals(moved, F), cams, None, 20.0, 5.0, 0.2, views=views,
                           outline="keep")  # nothing whole yet: drawn whole of the moved mesh
    assert views.outline_whole is True
    kept = silhouette_constraints(V, F, N, cams, None, 20.0, 5.0, 0.2, views=views, outline="keep")
    assert views.outline_whole is True
    assert len(kept) != len(ref)  # read in the moved mesh's outline, not redrawn
    # "full" redraws whole even where a whole outline (of the moved mesh) is kept
    _equal(silhouette_constraints(V, F, N, cams, None, 20.0, 5.0, 0.2, views=views, outline="full"), ref)
    _equal(silhouette_constraints(V, F, N, cams, None, 20.0, 5.0, 0.2, views=views, outline="keep"), ref)
    silhouette_constraints(V, F, N, cams, None, 20.0, 5.0, 0.2, views=views)
    assert views.outline_whole is False
    near = silhouette_constraints(V, F, N, cams, None, 20.0, 5.0, 0.2, views=views, outline_step_px=0.5)
    assert len(near) < 0.95 * len(ref)
    _equal(silhouette_constraints(V, F, N, cams, None, 20.0, 5.0, 0.2, views=views, outline_step_px=_OUTLINE_STEP_PX),
           ref)
    # "full" matches every view whatever use_view says (a whole outline to keep for each)
    _equal(silhouette_constraints(V, F, N, cams, None, 20.0, 5.0, 0.2, views=views, outline="full",
                                  use_view=np.array([True, False, False, False])), ref)
    one = silhouette_constraints(V, F, N, cams, None, 20.0, 5.0, 0.2, views=views, outline="keep",
                                 use_view=np.array([False, False, True, False]))
    assert len(one) and set(one.camera) == {2}
    strided = silhouette_constraints(V, F, N, cams, None, 20.0, 5.0, 0.2, views=views, rim_stride=3)
    sel = ref.vertex % 3 == 0
    assert 0 < len(strided) == sel.sum()
    _equal(strided, SilhouetteConstraints(*(getattr(ref, name)[sel] for name in FIELDS)))


def test_projection_is_offered_only_after_a_matching_of_every_view(scene):
    V, F, cams, masks = scene
    N = area_weighted_normals(V, F)
    views = SilhouetteViews(cams, masks, F)
    assert views.projection(V) is None
    silhouette_constraints(V, F, N, cams, None, 20.0, 5.0, 0.2, views=views)
    uv, z = views.projection(V)
    np.testing.assert_allclose(uv[1], cams[1].project(V), atol=1e-9)
    silhouette_constraints(V, F, N, cams, None, 20.0, 5.0, 0.2, views=views, use_view=np.array([1, 1, 0, 1]))
    assert views.projection(V) is None


def test_deformation_hands_each_outer_iteration_its_matching_and_gate(scene, monkeypatch):
    """The tracked frame's schedule (No = 3): the matching's keywords per outer iteration, the gate's mode (each,
    each, reuse) with one memo shared by the frame's calls (cameras x vertices, int8); a schedule gating nothing
    at its cheap iteration does not call the gate there; the paper's schedule gives no memo."""
    V, F, cams, masks = scene
    calls = {"sil": [], "gate": [], "views": []}
    real_sil, real_gate = rapid_skin.silhouette_constraints, rapid_skin.hull_consistent_constraints

    def sil(*a, **kw):
        calls["sil"].append({k: v for k, v in kw.items() if k != "views"})
        calls["views"].append({"views": kw.get("views")})
        return real_sil(*a, **kw)

    def gate(*a, **kw):
        calls["gate"].append(kw)
        return real_gate(*a, **kw)

    monkeypatch.setattr(rapid_skin, "silhouette_constraints", sil)
    monkeypatch.setattr(rapid_skin, "hull_consistent_constraints", gate)
    start = 1.1 * V
    p = RapidSkinParams(outer_iterations=3, inner_iterations=2, matching=TrackParams().matching)
    r = deform_to_observations(start, F, cams, masks, p)
    assert [c.get("outline", "draw") for c in calls["sil"]] == ["draw", "full", "keep"]
    assert [c.get("rim_stride", 1) for c in calls["sil"]] == [1, 1, 1]
    assert [c["reuse"] for c in calls["gate"]] == [False, False, True]
    memos = [c["memo"] for c in calls["gate"]]
    assert all(m is memos[0] for m in memos) and memos[0].dtype == np.int8 and memos[0].shape == (4 * len(V),)
    assert set(np.unique(memos[0])) <= {0, 1, 2} and (memos[0] > 0).any()
    assert min(r.n_silhouette) > 0
    first = calls["views"][0]["views"]
    assert isinstance(first, SilhouetteViews)  # one views object for the frame: its outline is kept
    assert all(c["views"] is first for c in calls["views"])
    calls["sil"].clear()
    calls["gate"].clear()
    calls["views"].clear()
    rot = MatchSchedule(cheap_iterations=2, view_stride=2)  # the cameras rotate at the cheap iterations
    deform_to_observations(start, F, cams, masks, RapidSkinParams(outer_iterations=3, inner_iterations=2,
                                                                  matching=rot))
    assert calls["sil"][0].get("use_view") is None
    np.testing.assert_array_equal(calls["sil"][1]["use_view"], [False, True, False, True])
    np.testing.assert_array_equal(calls["sil"][2]["use_view"], [True, False, True, False])
    calls["sil"].clear()
    calls["gate"].clear()
    off = MatchSchedule(cheap_iterations=1, rim_stride=2, gate="off")
    deform_to_observations(start, F, cams, masks, RapidSkinParams(outer_iterations=3, inner_iterations=2,
                                                                  matching=off))
    assert len(calls["gate"]) == 2 and all(c["memo"] is None and c["reuse"] is False for c in calls["gate"])
    assert [c.get("rim_stride", 1) for c in calls["sil"]] == [1, 1, 2]
    calls["gate"].clear()
    deform_to_observations(start, F, cams, masks, RapidSkinParams(outer_iterations=2, inner_iterations=2,
                                                                  hull_gate_m=0.0, matching=off))
    assert calls["gate"] == []  # no gate asked for: none at any iteration
