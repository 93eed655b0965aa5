"""The per-player mirror view (10ed052, helper mir12d), pinned case by case for mutation testing (issue 17).

``run_players``, ``_source_paths``, ``_player_path``, ``source_body_mesh``, ``source_body_is_the_runs``,
``open_mirror_view`` and ``scene_for_mirror`` of :mod:`bodystudio.viewer.mirror`; docs/mutation/viewer-mirror.md.
The shared session (a copy of the small mirror session with source bodies for players 1 and 2 and no run) is
built once (``_session``) and never written to by a test: each test writes its run folder under ``tmp_path``.
"""

import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest

from bodystudio.errors import InputError

_CACHE: dict = {}


def _body(n: int, seed: int, scale: float = 1.0):
    from bodystudio.body.skeleton import Skeleton
    from bodystudio.mirror.init import SourceBody

    rng = np.random.default_rng(seed)
    V = (rng.normal(size=(n, 3)) * 0.2 + [0.0, 1.0, 0.0]) * scale
    sk = Skeleton(("root",), np.array([-1]), np.array([[0.0, 0.9 + seed, 0.0]]), np.array([[0.0, 1.2, 0.0]]),
                  np.zeros(1))
    return SourceBody(np.full(3, float(seed)), V, sk, (10,), 1.0)


def _n_2k() -> int:
    from bodystudio.body.model import template_topology

    return len(template_topology("2k")[0])


def _session():
    """(session, body1, body2): the small mirror session copied, player 1's and player 2's source bodies written."""
    if "s" not in _CACHE:
        from bodystudio.capture.session import open_session
        from bodystudio.mirror.init import save_source_body
        from tests.mirror.synth_case import small_mirror_session

        path = Path(tempfile.mkdtemp(prefix="mirror-view-mutants-")) / "session"
        shutil.copytree(small_mirror_session(), path, ignore=shutil.ignore_patterns("run"))
        n = _n_2k()
        b1, b2 = _body(n, 1), _body(n, 2, 1.1)
        save_source_body(path / "mirror" / "source_body.npz", b1)
        save_source_body(path / "mirror" / "source_body_player2.npz", b2, player=2)
        _CACHE["s"] = (open_session(path), b1, b2)
    return _CACHE["s"]


@pytest.fixture(scope="module")
def session():
    return _session()


def _run(session, run_dir, player=1, **extra):
    from tests.mirror.synth_case import write_fake_run

    return write_fake_run(session, run_dir, lambda f: f.gt_target_rgb, lambda f: f.gt_person == 1,
                          lambda f: f.gt_target_person == 1, player=player, frames=[10, 12], extra=extra)


def _manifest(run_dir, **doc):
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "run.json").write_text(json.dumps({"format": "bodystudio-mirror-run", **doc}))
    return run_dir


@pytest.mark.parametrize("run, players", [
    (None, [1]), ("not a dict", [1]), ({}, [1]), ({"player": 3}, [3]), ({"players": [2, 3]}, [2, 3]),
    ({"players": [3, 1], "player": 2}, [3, 1]), ({"players": [], "player": 2}, [2]),
    ({"players": "2", "player": 4}, [4]), ({"players": ["2", 5.0]}, [2, 5]), ({"players": ["x"]}, [1]),
    ({"players": [None]}, [1]), ({"players": [1, 2]}, [1, 2]), ({"players": [0, 2]}, [1]), ({"players": [2, -1]}, [1]),
    ({"player": None}, [1]), ({"player": 1}, [1]),
])
def test_run_players_reads_players_then_player_else_one(run, players):
    from bodystudio.viewer.mirror import run_players

    assert run_players(run) == players


def test_source_paths_are_the_existing_files_in_the_players_order(tmp_path):
    from bodystudio.viewer.mirror import _source_paths

    (tmp_path / "mirror").mkdir()
    for name in ("source_body.npz", "source_body_player3.npz"):
        (tmp_path / "mirror" / name).write_bytes(b"x")
    (tmp_path / "mirror" / "source_body_player2.npz").mkdir()  # a folder is no body file
    got = _source_paths(tmp_path, [3, 2, 1, 4])
    assert got == ((3, tmp_path / "mirror" / "source_body_player3.npz"), (1, tmp_path / "mirror" / "source_body.npz"))
    assert isinstance(got, tuple) and _source_paths(tmp_path, [2, 4]) == ()


def test_player_path_is_the_first_players_or_the_named_players():
    from bodystudio.viewer.mirror import MirrorView, _player_path

    view = MirrorView(None, None, Path("first"), ((2, Path("two")), (3, Path("three"))))
    assert _player_path(view, None) == Path("first")
    assert _player_path(view, 3) == Path("three") and _player_path(view, "2") == Path("two")
    assert _player_path(view, 1) is None and _player_path(view, 0) is None


def test_source_body_mesh_is_the_players_rest_mesh_on_its_template(session, tmp_path):
    from bodystudio.body.model import template_topology
    from bodystudio.mirror.init import save_source_body
    from bodystudio.viewer.mirror import MirrorView, source_body_mesh

    _, b1, b2 = session
    d = Path(session[0].path) / "mirror"
    p1, p2 = d / "source_body.npz", d / "source_body_player2.npz"
    view = MirrorView(session[0], None, p2, ((2, p2), (1, p1)))
    _, F = template_topology("2k")
    mesh = source_body_mesh(view)
    assert np.array_equal(mesh.vertices, b2.vertices) and np.array_equal(mesh.faces, F)
    assert np.array_equal(source_body_mesh(view, 1).vertices, b1.vertices)
    assert source_body_mesh(view, 4) is None and source_body_mesh(MirrorView(None, None, None)) is None
    _, F6 = template_topology("6k")
    body6 = _body(len(template_topology("6k")[0]), 5)
    save_source_body(tmp_path / "six.npz", body6)
    mesh6 = source_body_mesh(MirrorView(None, None, tmp_path / "six.npz"))
    assert np.array_equal(mesh6.vertices, body6.vertices) and np.array_equal(mesh6.faces, F6)
    full = _body(13380, 7)  # the full template: no vertex ids
    save_source_body(tmp_path / "full.npz", full)
    mesh = source_body_mesh(MirrorView(None, None, tmp_path / "full.npz"))
    assert np.array_equal(mesh.vertices, full.vertices) and np.array_equal(mesh.faces, template_topology("full")[1])
    save_source_body(tmp_path / "odd.npz", _body(_n_2k() + 1, 6))
    with pytest.raises(InputError, match=r"odd\.npz: a source body with 2\d+ vertices is in no body template; "
                                         r"rerun `bodystudio mirror init`"):
        source_body_mesh(MirrorView(None, None, tmp_path / "odd.npz"))


def test_source_body_is_the_runs_compares_the_players_fingerprint(session, tmp_path):
    from bodystudio.mirror.init import source_fingerprint
    from bodystudio.viewer.mirror import MirrorView, source_body_is_the_runs

    s, b1, b2 = session
    fp1, fp2 = source_fingerprint(b1), source_fingerprint(b2)
    p1, p2 = Path(s.path) / "mirror" / "source_body.npz", Path(s.path) / "mirror" / "source_body_player2.npz"
    paths = ((1, p1), (2, p2))

    def check(doc, player=None, source=p1):
        return source_body_is_the_runs(MirrorView(s, _manifest(tmp_path / str(len(list(tmp_path.iterdir()))),
                                                               **doc), source, paths), player)

    assert not source_body_is_the_runs(MirrorView(s, _manifest(tmp_path / "a", source_fingerprint=fp2), p1, paths))
    assert source_body_is_the_runs(MirrorView(s, None, p1, paths))  # no run: nothing to compare with
    assert source_body_is_the_runs(MirrorView(s, tmp_path / "a", None, paths))  # no body: nothing to compare
    assert check({}) and check({"source_fingerprint": fp1}) and not check({"source_fingerprint": fp2})
    # per player: source_fingerprints decides, the run's single fingerprint stands in for a player it lacks
    assert check({"source_fingerprint": fp1, "source_fingerprints": {"2": fp2}}, 2)
    assert not check({"source_fingerprint": fp2, "source_fingerprints": {"2": fp1}}, 2)
    assert check({"source_fingerprint": fp2, "source_fingerprints": {"1": fp1}}, 1)
    assert not check({"source_fingerprint": fp2, "source_fingerprints": {"3": fp1}}, 1)
    assert check({"source_fingerprint": fp1, "source_fingerprints": {"3": fp2}}, 1)
    # no per-player record: the run's fingerprint is its first player's, says nothing about another's body
    assert check({"source_fingerprint": fp1, "players": [2, 1]}, 1)
    assert not check({"source_fingerprint": fp1, "players": [2, 1]}, 2)
    assert not check({"source_fingerprint": fp2, "players": [1, 2]}, "1")
    assert check({"source_fingerprint": fp2, "players": [2, 1]}, 2)


def test_open_mirror_view_takes_the_run_players_bodies(session, tmp_path):
    from bodystudio.viewer.mirror import open_mirror_view

    s, _, _ = session
    p1, p2 = Path(s.path) / "mirror" / "source_body.npz", Path(s.path) / "mirror" / "source_body_player2.npz"
    view = open_mirror_view(s.path)  # no run: player 1's body, its only path
    assert view.run_dir is None and view.source_path == p1 and view.source_paths == ((1, p1),)
    view = open_mirror_view(_run(s, tmp_path / "r2", player=2, players=[2, 1]))
    assert view.run_dir == tmp_path / "r2" and view.source_path == p2 and view.source_paths == ((2, p2), (1, p1))
    view = open_mirror_view(_run(s, tmp_path / "r3", player=3))  # no body for player 3
    assert view.source_path is None and view.source_paths == ()
    view = open_mirror_view(_run(s, tmp_path / "r31", player=3, players=[3, 1]))
    assert view.source_path is None and view.source_paths == ((1, p1),)


def _points(plotter, name):
    return np.asarray(plotter.actors[name].GetMapper().GetInput().GetPoints().GetData())


def _scene_of(view):
    from bodystudio.viewer.mirror import scene_for_mirror
    from bodystudio.viewer.scene import make_plotter

    plotter = scene_for_mirror(view, 12, plotter=make_plotter(off_screen=True), key_help=False)
    title = plotter.actors["title"].GetText(2)
    names = set(plotter.actors)
    pts = {n: _points(plotter, n) for n in names if n.startswith("source-body")}
    plotter.close()
    return title, names, pts


def test_scene_shows_each_run_players_body_side_by_side_and_says_whose(session, tmp_path):
    from bodystudio.mirror.init import source_fingerprint
    from bodystudio.viewer.mirror import SOURCE_BODY_SPACING_M, open_mirror_view

    s, b1, b2 = session
    fp1, fp2 = source_fingerprint(b1), source_fingerprint(b2)
    name = Path(s.path).name
    # two players: the first 0.4 m left, the second 0.4 m right, in the run's order
    title, names, pts = _scene_of(open_mirror_view(_run(s, tmp_path / "a", players=[2, 1],
                                                     source_fingerprints={"1": fp1, "2": fp2})))
    assert title == f"{name}  frame 12: input | mirror (taller +0.15) | truth (edited body)" \
        "  + source bodies of players 2, 1"
    assert {"source-body", "source-body-player1"} <= names and "source-body-player2" not in names
    assert np.allclose(pts["source-body"], b2.vertices - [SOURCE_BODY_SPACING_M / 2, 0, 0], atol=1e-5)
    assert np.allclose(pts["source-body-player1"], b1.vertices + [SOURCE_BODY_SPACING_M / 2, 0, 0], atol=1e-5)
    # one player (2): its body in place, the title names it
    title, names, pts = _scene_of(open_mirror_view(_run(s, tmp_path / "b", player=2, source_fingerprints={"2": fp2})))
    assert title.endswith("  + source body of player 2") and "input | mirror" in title
    assert np.allclose(pts["source-body"], b2.vertices, atol=1e-5) and len(pts) == 1
    # player 1 alone: "+ source body"
    title, names, pts = _scene_of(open_mirror_view(_run(s, tmp_path / "c", source_fingerprint=fp1)))
    assert title.endswith("(edited body)  + source body") and np.allclose(pts["source-body"], b1.vertices, atol=1e-5)
    # no body at all
    title, names, pts = _scene_of(open_mirror_view(_run(s, tmp_path / "d", player=3)))
    assert title.endswith("  (no source body yet)") and not pts
    # a body the run did not use: left out, the title says so (whose, with several players)
    title, names, pts = _scene_of(open_mirror_view(_run(s, tmp_path / "e", source_fingerprint=fp2)))
    assert title.endswith("  (source body changed since this run: re-run `bodystudio mirror run`)") and not pts
    title, names, pts = _scene_of(open_mirror_view(_run(s, tmp_path / "f", players=[1, 2],
                                                     source_fingerprints={"1": fp1, "2": fp1})))
    assert title.endswith("  (source body of player 2 changed since this run: re-run `bodystudio mirror run`)")
    assert set(pts) == {"source-body"} and np.allclose(pts["source-body"], b1.vertices - [0.4, 0, 0], atol=1e-5)


def test_open_mirror_view_finds_the_sessions_own_run_and_names_a_gone_session(session, tmp_path):
    from bodystudio.errors import SessionError
    from bodystudio.viewer.mirror import open_mirror_view

    s, _, _ = session
    linked = tmp_path / "linked"  # the shared session by links, with a run of its own in mirror/run
    (linked / "mirror").mkdir(parents=True)
    for p in Path(s.path).iterdir():
        if p.name != "mirror":
            (linked / p.name).symlink_to(p)
    for p in (Path(s.path) / "mirror").iterdir():
        (linked / "mirror" / p.name).symlink_to(p)
    _run(s, linked / "mirror" / "run", player=2, players=[2])
    view = open_mirror_view(linked)
    assert view.run_dir == linked / "mirror" / "run"
    assert view.source_path == linked / "mirror" / "source_body_player2.npz"
    bare = _manifest(tmp_path / "bare", frames=[])  # a run that names no session
    with pytest.raises(SessionError, match=r"bare: the run's session \. is gone; view the session folder instead$"):
        open_mirror_view(bare)


def test_open_mirror_view_keeps_the_session_and_names_a_folder_that_is_neither(session, tmp_path):
    from bodystudio.errors import SessionError
    from bodystudio.viewer.mirror import open_mirror_view

    s, _, _ = session
    assert Path(open_mirror_view(s.path).session.path) == Path(s.path)
    assert Path(open_mirror_view(_run(s, tmp_path / "r", player=2)).session.path) == Path(s.path)
    (tmp_path / "empty").mkdir()
    with pytest.raises(SessionError, match=r"empty: neither a mirror session \(kinect/player\) nor a mirror run "
                                           r"folder \(run\.json\)$"):
        open_mirror_view(tmp_path / "empty")


def test_scene_picks_a_changed_frame_and_shows_the_key_help_by_default(session, tmp_path):
    from bodystudio.viewer.mirror import mirror_frames, open_mirror_view, scene_for_mirror
    from bodystudio.viewer.scene import make_plotter

    s, _, _ = session
    view = open_mirror_view(_run(s, tmp_path / "r"))
    plotter = scene_for_mirror(view, plotter=make_plotter(off_screen=True))
    try:
        assert "key-help" in plotter.actors
        assert f"frame {mirror_frames(view, 1)[0]}: " in plotter.actors["title"].GetText(2)
    finally:
        plotter.close()


def _strip(plotter):
    actor = plotter.actors["mirror-strip"]
    return np.array(actor.GetBounds()), actor.GetTexture().GetInput().GetDimensions()[:2]


@pytest.mark.parametrize("with_run", [True, False])
def test_the_strip_stands_centred_at_1_1_m_one_panel_width_per_panel_at_most_1280_px(session, tmp_path, with_run):
    from bodystudio.viewer.mirror import PANEL_WIDTH_M, PANEL_Z_M, open_mirror_view, scene_for_mirror
    from bodystudio.viewer.scene import make_plotter

    s, _, _ = session
    view = open_mirror_view(_run(s, tmp_path / "r") if with_run else s.path)
    n = 3 if with_run else 2  # input | mirror | truth; before a run input | truth
    given = make_plotter(off_screen=True)
    plotter = scene_for_mirror(view, 12, plotter=given)
    try:
        assert plotter is given
        bounds, texture = _strip(plotter)
        width = PANEL_WIDTH_M * n
        height = width * 480 / (640 * n)
        np.testing.assert_allclose(bounds, [-width / 2, width / 2, 1.1 - height / 2, 1.1 + height / 2, PANEL_Z_M,
                                            PANEL_Z_M], atol=1e-6)
        assert tuple(texture) == ((960, 240) if with_run else (1280, 480))  # 1920 px wide strip: every 2nd pixel
    finally:
        plotter.close()
    if not with_run:
        plotter = scene_for_mirror(view, 12)  # no plotter given: an off-screen one of its own
        try:
            assert "mirror-strip" in plotter.actors and "source-body" in plotter.actors
        finally:
            plotter.close()


def test_scene_goes_on_after_a_changed_body_and_names_every_changed_player(session, tmp_path):
    from bodystudio.mirror.init import source_fingerprint
    from bodystudio.viewer.mirror import open_mirror_view

    s, b1, b2 = session
    fp1, fp2 = source_fingerprint(b1), source_fingerprint(b2)
    title, names, pts = _scene_of(open_mirror_view(_run(s, tmp_path / "a", players=[1, 2],
                                                        source_fingerprints={"1": fp2, "2": fp2})))
    assert title.endswith("  (source body of player 1 changed since this run: re-run `bodystudio mirror run`)")
    assert set(pts) == {"source-body-player2"} and np.allclose(pts["source-body-player2"], b2.vertices + [0.4, 0, 0],
                                                               atol=1e-5)
    title, names, pts = _scene_of(open_mirror_view(_run(s, tmp_path / "b", players=[1, 2],
                                                        source_fingerprints={"1": fp2, "2": fp1})))
    assert title.endswith("  (source body of player 1, 2 changed since this run: re-run `bodystudio mirror run`)")
    assert not pts
