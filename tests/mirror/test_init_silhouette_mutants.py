"""What bodystudio/mirror/init.py gained since its mutation row (36e9153; issue 17): MIR12c's optional shape
refinement against the init frames' silhouettes (``silhouette_frames``, ``collect_observations(silhouettes=True)``),
the statistical model's own skeleton in the returned body, the source-body fingerprint and the refusal of
non-finite bones. Stand-ins replace the Eq. 2 fit, the default-pose transform, the shape refinement and the
frame readers: each test checks what is handed on, in well under a second (2k model loaded once).
"""

import functools
import hashlib
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import FileFormatError
from bodystudio.mirror import init as init_mod
from bodystudio.mirror.init import (
    MIN_POINTS,
    InitObservation,
    SourceBody,
    collect_observations,
    initialise_from_observations,
    load_source_body,
    save_source_body,
    source_fingerprint,
)


@functools.lru_cache(maxsize=1)
def _model_2k():
    from bodystudio.body.statistical import load_statistical_model

    return load_statistical_model("2k", progress=False)


@pytest.fixture(scope="module")
def model():
    return _model_2k()


def _observations(n=5, with_fg=(0, 1, 3, 4)):
    rng = np.random.default_rng(0)
    out = []
    for f in range(n):
        points = rng.uniform([-0.3, 0.5, -0.2], [0.3, 1.8, 0.2], (MIN_POINTS + 10 * f, 3))
        joints = rng.normal(0, 1, (25, 3))
        tracked = rng.uniform(size=25) > 0.2
        fg = np.full((4, 5), f % 2 == 0) if f in with_fg else None
        others = np.full((4, 5), f == 3) if f in with_fg else None
        out.append(InitObservation(10 + f, points, joints, tracked, "v2", fg, others))
    return out


def _stand_ins(monkeypatch, model):
    from bodystudio.mirror import shape_refine

    calls = {"refine": []}
    c_fit = 0.3 * model.stddev
    c_ref = -0.2 * model.stddev

    def tdp(P, joints, body, tracked, version, **kw):
        return SimpleNamespace(points=P, correspondence=np.arange(len(P)) % 100, candidates=np.arange(100),
                               body=body, pose=None)

    def fit(P0, m, coeffs, **kw):
        return c_fit.copy(), 0.004

    def refine(m, coeffs, views, camera, **kw):
        calls["refine"].append(SimpleNamespace(model=m, coeffs=np.array(coeffs), views=views, camera=camera, kw=kw))
        return c_ref.copy()

    monkeypatch.setattr(init_mod, "transform_to_default_pose", tdp)
    monkeypatch.setattr(init_mod, "fit_shape", fit)
    monkeypatch.setattr(shape_refine, "refine_shape_to_silhouettes", refine)
    return calls, c_fit, c_ref


@pytest.mark.parametrize("frames, picked", [(3, [0, 3, 4]), (10, [0, 1, 3, 4]), (4, [0, 1, 3, 4]), (1, [0]),
                                            (2, [0, 4])])
def test_the_silhouette_refinement_gets_evenly_spread_frames_with_their_data(monkeypatch, model, frames, picked):
    calls, c_fit, c_ref = _stand_ins(monkeypatch, model)
    obs = _observations()
    src = initialise_from_observations(obs, model, passes=1, camera="colour camera", silhouette_frames=frames)
    assert len(calls["refine"]) == 1
    call = calls["refine"][0]
    assert call.model is model and call.camera == "colour camera" and call.kw == {}
    np.testing.assert_allclose(call.coeffs, c_fit, atol=1e-15)
    assert len(call.views) == len(picked)
    for view, i in zip(call.views, picked, strict=True):
        o = obs[i]
        assert view.foreground is o.foreground and view.others is o.others
        assert view.joints is o.joints and view.tracked is o.tracked and view.version == "v2"
        np.testing.assert_array_equal(view.points, o.points)  # the frame's points as fitted (all kept here)
    # the refined shape is the body's: coefficients, rest vertices and the model's own skeleton for them
    np.testing.assert_allclose(src.coeffs, c_ref, atol=1e-15)
    np.testing.assert_allclose(src.vertices, model.vertices(c_ref), atol=1e-12)
    np.testing.assert_allclose(src.skeleton.heads, model.skeleton(c_ref).heads, atol=1e-12)
    np.testing.assert_allclose(src.skeleton.tails, model.skeleton(c_ref).tails, atol=1e-12)
    assert src.frames_used == (10, 11, 12, 13, 14) and src.residual_mm == pytest.approx(4.0)
    assert src.weights is model.weights and src.faces is model.faces


@pytest.mark.parametrize("kw", [dict(camera=None, silhouette_frames=6), dict(camera="colour camera"),
                                dict(camera="colour camera", silhouette_frames=0),
                                dict(camera="colour camera", silhouette_frames=6, no_foreground=True)])
def test_without_frames_camera_or_foregrounds_the_depth_fit_stands(monkeypatch, model, kw):
    calls, c_fit, _ = _stand_ins(monkeypatch, model)
    kw = dict(kw)
    obs = _observations(with_fg=() if kw.pop("no_foreground", False) else (0, 1, 3, 4))
    src = initialise_from_observations(obs, model, passes=1, **kw)
    assert calls["refine"] == []
    np.testing.assert_allclose(src.coeffs, c_fit, atol=1e-15)
    np.testing.assert_allclose(src.vertices, model.vertices(c_fit), atol=1e-12)
    # the statistical model's joints for the shape (not Eq. 3's refit)
    np.testing.assert_allclose(src.skeleton.heads, model.skeleton(c_fit).heads, atol=1e-12)


def test_a_frame_dropped_for_its_points_gives_no_silhouette(monkeypatch, model):
    calls, _, _ = _stand_ins(monkeypatch, model)
    obs = _observations()
    obs[1] = InitObservation(11, obs[1].points[:MIN_POINTS - 1], obs[1].joints, obs[1].tracked, "v2",
                             obs[1].foreground, obs[1].others)
    initialise_from_observations(obs, model, passes=1, camera="c", silhouette_frames=10)
    assert [v.foreground is o.foreground for v, o in zip(calls["refine"][0].views, [obs[0], obs[3], obs[4]],
                                                          strict=True)] == [True] * 3


# --- collect_observations(silhouettes=True) with stand-in frames ------------------------------------------

class _Session:
    path = "SESSION"

    def __init__(self, n):
        self.frame_ids = list(range(n))
        self.kinect = SimpleNamespace(depth=SimpleNamespace(center=np.zeros(3)), color="colour camera")


def _body(player):
    from bodystudio.body.kinect import kinect_joint_names

    names = kinect_joint_names("v2")
    return SimpleNamespace(player=player, names=tuple(names), positions=np.ones((len(names), 3)),
                           tracked=np.ones(len(names), bool))


def _fake(monkeypatch, frames):
    from bodystudio.mirror import compose, foreground
    from bodystudio.mirror import frames as frames_mod

    log = {"register": [], "background": [], "foreground": []}

    def read(session, i):
        bodies, depth = frames[i]
        return SimpleNamespace(index=i, bodies=bodies, depth_m=depth, rgb=f"rgb{i}", player=f"player{i}")

    def register(depth, player, sensor):
        log["register"].append((depth, player, sensor))
        i = int(player[len("player"):])
        players_c = np.array([[0, 1, 2, i % 3]])
        return f"depth_c{i}", players_c

    def background(model, rgb, mask):
        log["background"].append((model, rgb, mask.copy()))
        return f"bg after {rgb}"

    def refine(rgb, mask, depth_c, background=None):
        log["foreground"].append((rgb, mask.copy(), depth_c, background))
        return f"fg of {rgb}"

    monkeypatch.setattr(frames_mod, "read_mirror_frame", read)
    monkeypatch.setattr(frames_mod, "point_cloud", lambda frame, sensor, player: np.ones((MIN_POINTS, 3)))
    monkeypatch.setattr(frames_mod, "register_depth_to_color", register)
    monkeypatch.setattr(compose, "update_background", background)
    monkeypatch.setattr(foreground, "refine_foreground", refine)
    return log


def test_collect_observations_learns_the_background_before_the_player_and_cuts_each_frames_foreground(
        monkeypatch):
    depth = np.ones((2, 2))
    frames = {0: ([], depth),  # empty: the background learns
              1: ([], None),  # no depth: nothing to register
              2: ([_body(2)], depth),  # another player only: learns too, his pixels masked
              3: ([_body(1)], depth),  # the player: foreground and the other players' pixels
              4: ([], depth),  # after the player was seen: no more learning
              5: ([_body(1), _body(2)], depth)}
    log = _fake(monkeypatch, frames)
    obs, sensor = collect_observations(_Session(6), frames=range(6), silhouettes=True)
    assert [o.frame for o in obs] == [3, 5]
    assert [b[:2] for b in log["background"]] == [(None, "rgb0"), ("bg after rgb0", "rgb2")]
    for b in log["background"]:
        np.testing.assert_array_equal(b[2], [[False, True, True, b[1] != "rgb0"]])  # every player's pixels
    assert [r[1] for r in log["register"]] == ["player0", "player2", "player3", "player5"]
    assert all(r[0] is depth and r[2] is sensor for r in log["register"])
    assert [f[0] for f in log["foreground"]] == ["rgb3", "rgb5"]
    assert [f[2] for f in log["foreground"]] == ["depth_c3", "depth_c5"]
    assert [f[3] for f in log["foreground"]] == ["bg after rgb2"] * 2
    np.testing.assert_array_equal(log["foreground"][0][1], [[False, True, False, False]])  # player 1's mask
    np.testing.assert_array_equal(log["foreground"][1][1], [[False, True, False, False]])
    assert [o.foreground for o in obs] == ["fg of rgb3", "fg of rgb5"]
    np.testing.assert_array_equal(obs[0].others, [[False, False, True, False]])  # 3 % 3 = 0: nobody
    np.testing.assert_array_equal(obs[1].others, [[False, False, True, True]])  # 5 % 3 = 2: the other player
    # without silhouettes nothing of it runs
    log = _fake(monkeypatch, frames)
    obs, _ = collect_observations(_Session(6), frames=range(6))
    assert log == {"register": [], "background": [], "foreground": []}
    assert all(o.foreground is None and o.others is None for o in obs)


def test_collect_observations_of_another_player_with_silhouettes(monkeypatch):
    depth = np.ones((2, 2))
    log = _fake(monkeypatch, {0: ([], depth), 1: ([_body(1)], depth), 2: ([_body(2)], depth)})
    obs, _ = collect_observations(_Session(3), frames=range(3), player=2, silhouettes=True)
    assert [o.frame for o in obs] == [2]
    # player 1's frame comes before player 2 is seen: the background learns it with player 1 masked
    assert [b[1] for b in log["background"]] == ["rgb0", "rgb1"]
    np.testing.assert_array_equal(log["foreground"][0][1], [[False, False, True, True]])  # 2 % 3 = 2: player 2
    np.testing.assert_array_equal(obs[0].others, [[False, True, False, False]])


# --- the source body's file: fingerprint and refusals --------------------------------------------------

def _source(model, seed=0):
    c = np.random.default_rng(seed).normal(0, 0.5, model.n_components) * model.stddev
    return SourceBody(c, model.vertices(c), model.skeleton(c), (1, 2), 3.0)


def test_the_fingerprint_hashes_coefficients_vertices_and_bone_heads(model):
    src = _source(model)
    h = hashlib.sha256()
    for a in (src.coeffs, src.vertices, src.skeleton.heads):
        h.update(np.ascontiguousarray(a, np.float64).tobytes())
    assert source_fingerprint(src) == h.hexdigest()[:16]
    assert len(source_fingerprint(src)) == 16
    # float32 arrays are hashed as float64 (the same numbers, the same hash); any of the three changed is not
    as32 = SimpleNamespace(coeffs=src.coeffs.astype(np.float32), vertices=src.vertices.astype(np.float32),
                           skeleton=SimpleNamespace(heads=src.skeleton.heads.astype(np.float32)))
    h = hashlib.sha256()
    for a in (as32.coeffs, as32.vertices, as32.skeleton.heads):
        h.update(a.astype(np.float64).tobytes())
    assert source_fingerprint(as32) == h.hexdigest()[:16]
    for change in ("coeffs", "vertices", "heads"):
        parts = dict(coeffs=src.coeffs, vertices=src.vertices, skeleton=src.skeleton)
        if change == "heads":
            parts["skeleton"] = SimpleNamespace(heads=src.skeleton.heads + 1e-9)
        else:
            parts[change] = parts[change] + 1e-9
        assert source_fingerprint(SimpleNamespace(**parts)) != source_fingerprint(src), change


@pytest.mark.parametrize("key", ["heads", "tails", "rolls", "parents high", "parents low"])
def test_a_source_body_with_non_finite_bones_or_parents_out_of_range_is_refused(model, tmp_path, key):
    src = _source(model)
    path = tmp_path / "src.npz"
    save_source_body(path, src)
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    assert load_source_body(path).skeleton.n_bones == len(arrays["parents"])
    if key == "parents high":
        arrays["parents"][-1] = len(arrays["parents"])
    elif key == "parents low":
        arrays["parents"][-1] = -2
    else:
        arrays[key] = arrays[key].astype(float)
        arrays[key].flat[-1] = np.nan
    np.savez(path, **arrays)
    with pytest.raises(FileFormatError, match=r"src\.npz: source body arrays are inconsistent or not finite; "
                       r"rerun 'bodystudio mirror init'$"):
        load_source_body(path)
    # the last bone's parent may be any earlier bone, the root's -1
    save_source_body(path, src)
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["parents"][-1] = len(arrays["parents"]) - 2
    np.savez(path, **arrays)
    assert load_source_body(path).skeleton.parents[-1] == len(arrays["parents"]) - 2
