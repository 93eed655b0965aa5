"""views.py: what a path opens as, each scene's layers, framing and frame export, on stand-in sessions (mutMM).

The layers are read back from the plotter's actors and compared with the inputs (vertices, the distances of a
plane in closed form, the frames picked by hand); the framing against :func:`scene.frame_front` called on its own.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import BodyStudioError, FileFormatError, InputError, SessionError
from bodystudio.geometry.mesh import Mesh, save_mesh
from bodystudio.viewer import scene as sc
from bodystudio.viewer import views as vw

SIZE = (320, 240)
V4 = np.array([[-0.5, 0.0, 0.0], [0.5, 0.0, 0.0], [0.5, 1.0, 0.0], [-0.5, 1.0, 0.0]])
F2 = np.array([[0, 1, 2], [0, 2, 3]])


def _points(plotter, name) -> np.ndarray:
    import pyvista as pv

    mapper = plotter.renderer.actors[name].GetMapper()
    mapper.Update()
    return np.asarray(pv.wrap(mapper.GetInput()).points)


def _data(plotter, name):
    import pyvista as pv

    mapper = plotter.renderer.actors[name].GetMapper()
    mapper.Update()
    return pv.wrap(mapper.GetInput())


def _framed_like(bounds, **kw):
    p = sc.make_plotter(window_size=SIZE)
    sc.frame_front(p, bounds, **kw)
    pos = np.asarray(p.camera.position)
    p.close()
    return pos


def _texts(plotter) -> dict:
    out = {}
    for name in ("title", "key-help"):
        actor = plotter.renderer.actors.get(name)
        if actor is not None:
            out[name] = next(actor.GetText(k) for k in range(4) if actor.GetText(k))
    return out


# --- what a path is ---------------------------------------------------------------------------------------------------


def test_open_viewable_kinds_and_one_line_refusals(monkeypatch, tmp_path):
    import bodystudio.capture.session as cs
    import bodystudio.viewer.arm as va
    import bodystudio.viewer.garment as vg
    import bodystudio.viewer.mirror as vm

    monkeypatch.setattr(va, "open_arm_view", lambda p: ("arm", p))
    monkeypatch.setattr(vg, "open_garment_view", lambda p: ("garment", p))
    monkeypatch.setattr(vm, "open_mirror_view", lambda p: ("mirror", p))
    monkeypatch.setattr(cs, "open_session", lambda p: ("session", p))
    arm = tmp_path / "arm"
    arm.mkdir()
    (arm / "manifest.json").write_text('{"format": "bodystudio-arm-capture"}')
    fit = tmp_path / "fit"
    fit.mkdir()
    (fit / "fit.json").write_text("{}")
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text('{"format": "bodystudio-mirror-run"}')
    sess = tmp_path / "holder" / "sess"
    sess.mkdir(parents=True)
    (sess / "session.json").write_text("{}")
    render = tmp_path / "render"
    render.mkdir()
    (render / "render.json").write_text('{"format": "bodystudio-garment-render"}')
    for path, kind in ((arm, "arm"), (fit, "garment"), (run, "mirror"), (sess, "session"), (render, "garment")):
        item = vw.open_viewable(str(path))
        assert (item.path, item.kind, item.data) == (path, kind, (kind, path))
    with pytest.raises(SessionError) as exc:
        vw.open_viewable(tmp_path / "holder")
    suffixes = ", ".join(vw.MESH_SUFFIXES)
    assert str(exc.value) == (f"{tmp_path / 'holder'}: not a session folder (no session.json) (it holds the session "
                              f"{sess}); give a session folder or a mesh file ({suffixes})")
    with pytest.raises(SessionError) as exc:
        vw.open_viewable(arm / ".." / "fit" / ".." / "run" / ".." / "holder" / "sess" / "..")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(SessionError) as exc:
        vw.open_viewable(empty)
    assert str(exc.value) == (f"{empty}: not a session folder (no session.json); give a session folder or a mesh "
                              f"file ({suffixes})")
    with pytest.raises(InputError) as exc:
        vw.open_viewable(tmp_path / "nope.ply")
    assert str(exc.value) == f"{tmp_path / 'nope.ply'}: no such file or folder; give a session folder or a mesh file"
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(FileFormatError) as exc:
        vw.open_viewable(tmp_path / "notes.txt")
    assert str(exc.value) == (f"{tmp_path / 'notes.txt'}: not a session folder or mesh; give a session folder or a "
                              f"mesh file ({suffixes})")
    save_mesh(tmp_path / "m.PLY", Mesh(V4, F2))
    item = vw.open_viewable(tmp_path / "m.PLY")
    assert item.kind == "mesh" and np.allclose(item.data.vertices, V4) and item.path == tmp_path / "m.PLY"
    save_mesh(tmp_path / "plain.glb", Mesh(V4, F2))
    assert vw.open_viewable(tmp_path / "plain.glb").kind == "mesh"
    monkeypatch.setattr(vw, "glb_has_skin", lambda p: True)
    monkeypatch.setattr(vw, "load_avatar", lambda p: ("avatar", p))
    item = vw.open_viewable(tmp_path / "plain.glb")
    assert (item.path, item.kind, item.data) == (tmp_path / "plain.glb", "avatar", ("avatar", tmp_path / "plain.glb"))
    (tmp_path / "a.gltf").write_text("{}")
    assert vw.open_viewable(tmp_path / "a.gltf").kind == "avatar"
    assert vw.open_viewable(tmp_path / "m.PLY").kind == "mesh"  # only a glTF can be an avatar


# --- mesh and avatar scenes -----------------------------------------------------------------------------------------


def test_scene_for_mesh_with_a_reference_colours_by_distance_and_frames_the_mesh():
    ref = Mesh(V4 * 3, F2)
    mesh = Mesh(V4 + [0.0, 0.0, 0.004], F2)
    plotter = vw.scene_for_mesh(mesh, sc.make_plotter(window_size=SIZE), reference=ref, title="T")
    assert np.allclose(_points(plotter, "reference"), ref.vertices)
    assert np.isclose(plotter.renderer.actors["reference"].GetProperty().GetOpacity(), 0.25)
    assert np.allclose(plotter.renderer.actors["reference"].GetProperty().GetColor(), sc.GT_COLOR, atol=1 / 255)
    assert np.allclose(_data(plotter, "error").point_data["error (mm)"], 4.0)
    floor = _points(plotter, "floor")
    assert np.isclose(np.ptp(floor[:, 0]), 2.0) and np.allclose(floor.mean(0), [0.0, 0.0, 0.004])
    assert _texts(plotter) == {"title": "T", "key-help": sc.KEY_HELP}
    assert np.allclose(plotter.camera.position, _framed_like(mesh.bounds))
    plotter.close()
    wide = Mesh(V4 * [4.0, 1.0, 1.0] + [1.0, 0.0, 0.0], F2)
    plotter = vw.scene_for_mesh(wide, sc.make_plotter(window_size=SIZE), key_help=False)
    assert np.isclose(np.ptp(_points(plotter, "floor")[:, 0]), 1.5 * 4.0)
    assert "error" not in plotter.renderer.actors and _texts(plotter) == {}
    assert np.allclose(_points(plotter, "mesh"), wide.vertices)
    plotter.close()
    given = sc.make_plotter(window_size=SIZE)
    plotter = vw.scene_for_mesh(wide, given, floor=False)
    assert plotter is given and "floor" not in plotter.renderer.actors
    plotter.close()
    own = vw.scene_for_mesh(wide)
    assert "mesh" in own.renderer.actors and list(own.window_size) == list(sc.WINDOW_SIZE)
    own.close()


def _avatar():
    return SimpleNamespace(mesh=Mesh(V4, F2), weights=np.array([[1.0, 0.0], [0.0, 1.0], [0.5, 0.5], [0.2, 0.8]]),
                           bone_names=("hip", "knee"), heads=np.array([[0.0, 0.0, 0.0], [0.0, 0.5, 0.0]]),
                           tails=np.array([[0.0, 0.5, 0.0], [0.0, 1.0, 0.0]]))


def test_scene_for_avatar_layers():
    av = _avatar()
    plotter = vw.scene_for_avatar(av, sc.make_plotter(window_size=SIZE), title="A")
    assert np.isclose(plotter.renderer.actors["mesh"].GetProperty().GetOpacity(), 0.3)
    assert {"skeleton-bones", "skeleton-joints", "floor"} <= set(plotter.renderer.actors)
    assert np.allclose(_points(plotter, "floor").mean(0), [0.0, 0.0, 0.0]) and np.isclose(
        np.ptp(_points(plotter, "floor")[:, 0]), 3.0)
    assert _texts(plotter) == {"title": "A", "key-help": sc.KEY_HELP}
    assert np.allclose(plotter.camera.position, _framed_like(av.mesh.bounds))
    plotter.close()
    plotter = vw.scene_for_avatar(av, sc.make_plotter(window_size=SIZE), bone="knee", skeleton=False, key_help=False)
    assert np.array_equal(_data(plotter, "weights").point_data["weight knee"], av.weights[:, 1])
    assert "skeleton-bones" not in plotter.renderer.actors and "mesh" not in plotter.renderer.actors
    assert _texts(plotter) == {}
    plotter.close()
    given = sc.make_plotter(window_size=SIZE)
    plotter = vw.scene_for_avatar(av, given, skeleton=False)
    assert plotter is given and np.isclose(plotter.renderer.actors["mesh"].GetProperty().GetOpacity(), 1.0)
    plotter.close()
    own = vw.scene_for_avatar(av)
    assert "mesh" in own.renderer.actors and list(own.window_size) == list(sc.WINDOW_SIZE)
    own.close()


# --- sessions -------------------------------------------------------------------------------------------------------


def _cam(name, center):
    center = np.asarray(center, float)

    def frustum(near, far):
        c = np.array([[-0.4, 0.3, -1.0], [0.4, 0.3, -1.0], [0.4, -0.3, -1.0], [-0.4, -0.3, -1.0]])
        return np.r_[c * near, c * far] + center

    return SimpleNamespace(name=name, center=center, frustum=frustum)


class _Sensor:
    def __init__(self):
        self.asked = []
        self.depth = self
        self.name, self.center = "kinect", np.array([0.0, 1.0, 3.0])

    def frustum(self, near, far):
        return _cam("k", self.center).frustum(near, far)

    def unproject(self, uv, d):
        self.asked.append((uv.copy(), d.copy()))
        return np.c_[uv * 0.01, d]


def _stand_in_session(tmp_path, frame_ids=(1, 2, 3), gt_frames=(1, 2, 3), kinect=True, cameras=2):
    cams = [_cam(f"c{k}", [2.0 * k - 1.0, 1.0, 4.0]) for k in range(cameras)]
    image = np.full((12, 700, 3), 90, np.uint8)
    mask = np.ones((12, 700), bool)
    depth = np.full((10, 15), 2.0)
    depth[7, 7] = 0.0  # one of the stride-7 grid's 2 x 3 pixels has no depth

    def frame(fid):
        gt = Mesh(V4 + [0.0, 0.0, 0.01 * fid], F2) if fid in gt_frames else None
        joints = {"heads": np.array([[0.0, 0.2, 0.0]]), "tails": np.array([[0.0, 0.8, 0.0]])} if gt else None
        return SimpleNamespace(images={"c0": image}, masks={"c1": mask}, gt_mesh=gt, kinect_depth_m=depth,
                               gt_joints=joints)

    return SimpleNamespace(path=tmp_path / "sess", frame_ids=list(frame_ids), cameras=cams,
                           kinect=_Sensor() if kinect else None, frame=frame)


def test_downsample_and_kinect_points():
    img = np.arange(4 * 700).reshape(4, 700)
    assert np.array_equal(vw._downsample(img), img[::3, ::3])  # ceil(700 / 320) = 3
    assert np.array_equal(vw._downsample(img[:, :320]), img[:, :320])
    assert np.array_equal(vw._downsample(img[:, :321]), img[:, :321][::2, ::2])
    s = _stand_in_session(Path("."))
    depth = np.zeros((15, 16))
    depth[0, 7] = 1.5
    depth[7, 14] = 2.5
    depth[14, 0] = -1.0
    depth[3, 3] = 9.0  # on neither grid
    depth[2, 4] = 3.0  # on the stride-2 grid only
    depth[14, 7] = 0.5  # any depth above zero counts
    pts = vw.kinect_points(s, SimpleNamespace(kinect_depth_m=depth))
    (uv, d), = s.kinect.asked
    assert uv.tolist() == [[7.0, 0.0], [14.0, 7.0], [7.0, 14.0]] and d.tolist() == [1.5, 2.5, 0.5]
    assert uv.dtype == np.float64
    assert np.allclose(pts, [[0.07, 0.0, 1.5], [0.14, 0.07, 2.5], [0.07, 0.14, 0.5]])
    vw.kinect_points(s, SimpleNamespace(kinect_depth_m=depth), stride=2)
    assert s.kinect.asked[-1][0].tolist() == [[4.0, 2.0]] and s.kinect.asked[-1][1].tolist() == [3.0]
    assert vw.kinect_points(s, SimpleNamespace(kinect_depth_m=None)).shape == (0, 3)
    s2 = _stand_in_session(Path("."), kinect=False)
    assert vw.kinect_points(s2, SimpleNamespace(kinect_depth_m=depth)).shape == (0, 3)


def test_reconstructed_mesh_path_in_a_folder_without_a_run(tmp_path, monkeypatch):
    sess = tmp_path / "s"
    sess.mkdir()
    assert vw.reconstructed_mesh_path(sess, 3) is None
    rec = sess / "reconstruct"
    for rel in ("a/frame_00003.ply", "frame_00013.ply", "frame_00003.txt", ".staging/frame_00003.ply",
                "z/frame_00004.obj", "b/mesh3x.ply"):
        (rec / rel).parent.mkdir(parents=True, exist_ok=True)
        (rec / rel).write_text("x")
    assert vw.reconstructed_mesh_path(sess, 3) == rec / "a" / "frame_00003.ply"
    assert vw.reconstructed_mesh_path(sess, 13) == rec / "frame_00013.ply"
    assert vw.reconstructed_mesh_path(sess, 4) == rec / "z" / "frame_00004.obj"
    assert vw.reconstructed_mesh_path(sess, 5) is None
    import bodystudio.reconstruct.sequence as rs

    (rec / "run.json").write_text("{}")  # a run: its manifest decides, checked by read_reconstruction
    asked = []

    def read(session_path, frame):
        asked.append((session_path, frame))
        return {}, {frame: rec / f"run_{frame}.ply"}

    monkeypatch.setattr(rs, "read_reconstruction", read)
    assert vw.reconstructed_mesh_path(sess, 3) == rec / "run_3.ply" and asked == [(sess, 3)]


def test_session_bounds():
    assert np.array_equal(vw._session_bounds(None, None), [[-0.5, 0.0, -0.5], [0.5, 1.9, 0.5]])
    assert np.array_equal(vw._session_bounds(None, Mesh(V4, F2)), [[-0.5, 0.0, 0.0], [0.5, 1.0, 0.0]])


def test_scene_for_frame_layers_replace_the_previous_frame(monkeypatch, tmp_path):
    s = _stand_in_session(tmp_path, gt_frames=(1, 2))
    recon = {1: tmp_path / "r1.ply", 3: tmp_path / "r3.ply"}
    save_mesh(recon[1], Mesh(V4 + [0.0, 0.0, 0.015], F2))
    save_mesh(recon[3], Mesh(V4 + [0.0, 0.0, 0.5], F2))
    def mesh_path(path, fid):
        assert path == s.path
        return recon.get(fid)

    monkeypatch.setattr(vw, "reconstructed_mesh_path", mesh_path)
    plotter = sc.make_plotter(window_size=SIZE)
    sc.add_error_map(plotter, Mesh(V4, F2), np.arange(4.0), name="static", title="static (mm)")
    vw.scene_for_frame(s, 1, plotter)
    names = set(plotter.renderer.actors)
    assert {"gt", "recon", "kinect", "gt-skeleton-bones", "gt-skeleton-joints", "camera-c0", "camera-c0-image"} <= names
    assert "camera-c1-image" not in names and "error (mm)" in plotter.scalar_bars
    bones = _points(plotter, "gt-skeleton-bones")
    assert np.isclose(np.abs(bones[:, 0]).max(), 0.005, atol=1e-6)  # 5 mm bones around x = 0
    assert np.allclose(_data(plotter, "recon").point_data["error (mm)"], 5.0, atol=1e-4)  # 15 mm vs the gt at 10 mm
    assert np.isclose(plotter.renderer.actors["gt"].GetProperty().GetOpacity(), 0.25)
    assert np.allclose(plotter.renderer.actors["gt"].GetProperty().GetColor(), sc.GT_COLOR, atol=1 / 255)
    assert np.allclose(_points(plotter, "camera-c0-image"), _cam("c0", [-1.0, 1.0, 4.0]).frustum(0, vw.FRUSTUM_M)[4:])
    assert _data(plotter, "camera-c0-image") is not None
    cloud = plotter.renderer.actors["kinect"]
    assert np.allclose(cloud.GetProperty().GetColor(), vw.KINECT_COLOR, atol=1 / 255)
    assert cloud.GetProperty().GetPointSize() == 2.0
    grid = [[0, 0, 2], [0.07, 0, 2], [0.14, 0, 2], [0, 0.07, 2], [0.14, 0.07, 2]]  # (7, 7) has no depth
    assert np.allclose(_points(plotter, "kinect"), grid)
    vw.scene_for_frame(s, 2, plotter, images="mask", skeleton=False)
    names = set(plotter.renderer.actors)
    assert "recon" not in names and "camera-c0-image" not in names and "camera-c1-image" in names
    assert "gt-skeleton-bones" not in names and "error (mm)" not in plotter.scalar_bars
    assert np.allclose(_points(plotter, "gt"), V4 + [0.0, 0.0, 0.02])
    assert np.isclose(plotter.renderer.actors["gt"].GetProperty().GetOpacity(), 1.0)
    assert np.allclose(plotter.renderer.actors["gt"].GetProperty().GetColor(), sc.GT_COLOR, atol=1 / 255)
    assert "static (mm)" in plotter.scalar_bars  # only the frame's own bar goes
    vw.scene_for_frame(s, 3, plotter, images="none", cloud=False)
    names = set(plotter.renderer.actors)
    assert "gt" not in names and "kinect" not in names and not any(n.endswith("-image") for n in names)
    assert np.allclose(_points(plotter, "recon"), V4 + [0.0, 0.0, 0.5])
    assert not plotter.renderer.actors["recon"].GetMapper().GetScalarVisibility()
    with pytest.raises(InputError) as exc:
        vw.scene_for_frame(s, 1, plotter, images="rgb")
    assert str(exc.value) == "unknown image layer 'rgb'; valid: image, mask, none"
    assert vw.frame_layer_names(plotter, s.cameras) == {*vw.FRAME_LAYERS, "camera-c0-image", "camera-c1-image"}
    plotter.close()


def test_scene_for_session_frusta_title_and_framing(monkeypatch, tmp_path):
    monkeypatch.setattr(vw, "reconstructed_mesh_path", lambda path, fid: None)
    s = _stand_in_session(tmp_path)
    given = sc.make_plotter(window_size=SIZE)
    plotter = vw.scene_for_session(s, plotter=given)
    assert plotter is given
    names = set(plotter.renderer.actors)
    assert {"camera-c0", "camera-c1", "floor", "kinect", "gt-skeleton-bones"} <= names
    # the Kinect's frustum (magenta lines from the sensor) is still there after the frame's "kinect" cloud was
    # added: pyvista drops every actor named "kinect-..." when one named "kinect" is added (it was "kinect-frustum")
    lines = [n for n in names if n not in ("title", "key-help") and len(_points(plotter, n)) == 5]
    frusta = [n for n in lines if np.allclose(_points(plotter, n)[0], [0.0, 1.0, 3.0])]
    assert frusta == ["frustum-kinect"]
    assert np.allclose(_points(plotter, "frustum-kinect")[1:], _cam("k", [0.0, 1.0, 3.0]).frustum(0, vw.FRUSTUM_M)[4:])
    assert np.allclose(plotter.renderer.actors[frusta[0]].GetProperty().GetColor(), vw.KINECT_COLOR, atol=1 / 255)
    assert np.allclose(_points(plotter, "camera-c1")[1:], _cam("c", [1.0, 1.0, 4.0]).frustum(0, vw.FRUSTUM_M)[4:])
    assert np.allclose(_points(plotter, "gt"), V4 + [0.0, 0.0, 0.01])  # the first frame
    floor = _points(plotter, "floor")
    assert np.isclose(np.ptp(floor[:, 0]), 4.0) and np.allclose(floor.mean(0), [0.0, 0.0, 0.01])
    assert _texts(plotter) == {"title": "sess  frame 1",
                               "key-help": sc.KEY_HELP + "\nslider or n / p: next / previous frame"}
    gt = V4 + [0.0, 0.0, 0.01]
    box = np.array([np.minimum(gt.min(0), [-1.0, 1.0, 4.0]), np.maximum(gt.max(0), [1.0, 1.0, 4.0])])
    assert np.allclose(plotter.camera.position, _framed_like(box, direction=(0.3, 0.6, 1.0), margin=0.75,
                                                             fit="sphere"))
    plotter.close()
    plotter = vw.scene_for_session(s, 2)
    assert np.allclose(_points(plotter, "gt"), V4 + [0.0, 0.0, 0.02]) and list(plotter.window_size) == list(
        sc.WINDOW_SIZE)
    assert _texts(plotter)["title"] == "sess  frame 2"
    plotter.close()
    plotter = vw.scene_for_session(s, plotter=sc.make_plotter(window_size=SIZE), cloud=False, skeleton=False)
    assert "kinect" not in plotter.renderer.actors and "gt-skeleton-bones" not in plotter.renderer.actors
    plotter.close()
    two = _stand_in_session(tmp_path, frame_ids=(1, 2))
    plotter = vw.scene_for_session(two, plotter=sc.make_plotter(window_size=SIZE))
    assert _texts(plotter)["key-help"].endswith("\nslider or n / p: next / previous frame")
    plotter.close()
    no_cams = _stand_in_session(tmp_path, frame_ids=(4,), gt_frames=(4,), kinect=False, cameras=0)
    plotter = vw.scene_for_session(no_cams, plotter=sc.make_plotter(window_size=SIZE))
    gt = V4 + [0.0, 0.0, 0.04]
    box = np.array([gt.min(0), gt.max(0)])  # the ground truth alone: no camera widens it
    assert np.allclose(plotter.camera.position, _framed_like(box, direction=(0.3, 0.6, 1.0), margin=0.75, fit="sphere"))
    plotter.close()
    one = _stand_in_session(tmp_path, frame_ids=(4,), gt_frames=(), kinect=False, cameras=0)
    plotter = vw.scene_for_session(one, 4, plotter=sc.make_plotter(window_size=SIZE), title="mine")
    assert "frustum-kinect" not in plotter.renderer.actors
    assert _texts(plotter) == {"title": "mine", "key-help": sc.KEY_HELP}
    assert np.allclose(plotter.camera.position, _framed_like(vw._session_bounds(None, None), direction=(0.3, 0.6, 1.0),
                                                             margin=0.75, fit="sphere"))
    plotter.close()
    with pytest.raises(SessionError) as exc:
        vw.scene_for_session(_stand_in_session(tmp_path, frame_ids=()), plotter=sc.make_plotter(window_size=SIZE))
    assert str(exc.value) == f"{tmp_path / 'sess'}: the session has no frames; regenerate or re-import it"


def test_time_slider_shows_the_picked_frame(monkeypatch, tmp_path):
    monkeypatch.setattr(vw, "reconstructed_mesh_path", lambda path, fid: None)
    s = _stand_in_session(tmp_path, frame_ids=(5, 7, 9), gt_frames=(5, 7, 9))
    got = {}

    def slider(plotter, ids, start, show):
        got.update(ids=list(ids), start=start, show=show)
        return plotter

    monkeypatch.setattr(sc, "add_frame_slider", slider)
    plotter = vw.scene_for_session(s, plotter=sc.make_plotter(window_size=SIZE))
    assert vw.add_time_slider(plotter, s, frame_id=9) is plotter
    assert got["ids"] == [5, 7, 9] and got["start"] == 2
    got["show"](1)
    assert {"kinect", "gt-skeleton-bones", "camera-c0-image"} <= set(plotter.renderer.actors)  # the defaults
    assert np.allclose(_points(plotter, "gt"), V4 + [0.0, 0.0, 0.07])
    assert _texts(plotter)["title"] == "sess  frame 7"
    vw.add_time_slider(plotter, s, frame_id=8, images="mask", cloud=False, skeleton=False)
    assert got["start"] == 0
    got["show"](2)
    names = set(plotter.renderer.actors)
    assert "kinect" not in names and "gt-skeleton-bones" not in names and "camera-c1-image" in names
    vw.add_time_slider(plotter, _stand_in_session(tmp_path, frame_ids=(5, 6)))
    assert got["ids"] == [5, 6]
    got.clear()
    vw.add_time_slider(plotter, _stand_in_session(tmp_path, frame_ids=(5,)))
    assert got == {}
    plotter.close()


def test_session_payload_exports_evenly_spaced_frames_and_opens_at_the_nearest(monkeypatch, tmp_path):
    ids = list(range(100, 130))
    recon = {}
    for fid in (100, 113):
        recon[fid] = tmp_path / f"r{fid}.ply"
        save_mesh(recon[fid], Mesh(V4 + [0.0, 0.0, 0.02], F2))
    monkeypatch.setattr(vw, "reconstructed_mesh_path", lambda path, fid: recon.get(fid))
    s = _stand_in_session(tmp_path, frame_ids=ids, gt_frames=set(ids))
    plotter = vw.scene_for_session(s, plotter=sc.make_plotter(window_size=SIZE))
    payload = vw.session_payload(s, plotter, max_frames=5, start=121)
    picked = [ids[int(round(k))] for k in np.linspace(0, 29, 5)]
    assert [f["id"] for f in payload["frames"]] == picked == [100, 107, 114, 122, 129]
    assert payload["start"] == 3  # 122 is the exported frame nearest 121
    static = {o["name"] for o in payload["objects"]}
    assert "gt" not in static and {"camera-c0", "floor"} <= static
    assert {o["name"] for o in payload["frames"][0]["objects"]} >= {"gt", "recon", "kinect", "gt-skeleton-bones"}
    assert not {o["name"] for o in payload["frames"][0]["objects"]} & {"floor", "camera-c0"}  # statics once
    assert np.allclose(_points(plotter, "gt"), V4 + [0.0, 0.0, 0.01 * 122])  # left at the opening frame
    assert {"kinect", "gt-skeleton-bones"} <= set(plotter.renderer.actors)  # with all its layers
    # the opening frame has no error map: the first exported frame that has one gives the bar
    assert payload["colorBars"] == payload["frames"][0]["colorBars"]
    assert payload["colorBars"][0]["title"] == "error (mm)"
    assert payload["frames"][3]["colorBars"] == []
    few = vw.session_payload(s, plotter, frame_ids=[113, 101])
    assert [f["id"] for f in few["frames"]] == [113, 101] and few["start"] == 0
    assert few["colorBars"] == few["frames"][0]["colorBars"] != []
    none = vw.session_payload(s, plotter, frame_ids=[101, 102])
    assert none["colorBars"] == []
    assert len(vw.session_payload(s, plotter)["frames"]) == vw.MAX_HTML_FRAMES == 12
    bare_layers = vw.session_payload(s, plotter, frame_ids=[101, 102], cloud=False, skeleton=False)
    for f in bare_layers["frames"]:
        assert not {o["name"] for o in f["objects"]} & {"kinect", "gt-skeleton-bones", "gt-skeleton-joints"}
    assert "kinect" not in plotter.renderer.actors and "gt-skeleton-bones" not in plotter.renderer.actors
    plotter.close()
    cams_only = _stand_in_session(tmp_path, frame_ids=(1, 2), gt_frames=(), kinect=False)
    p2 = vw.scene_for_session(cams_only, plotter=sc.make_plotter(window_size=SIZE), images="none")
    only_static = vw.session_payload(cams_only, p2, images="none")  # frames without layers still export
    assert only_static["objects"] and not any(f["objects"] for f in only_static["frames"])
    p2.close()
    bare = _stand_in_session(tmp_path, frame_ids=(1,), gt_frames=(), kinect=False, cameras=0)
    with pytest.raises(sc.EmptySceneError) as exc:
        vw.session_payload(bare, sc.make_plotter(window_size=SIZE))
    assert str(exc.value) == f"{tmp_path / 'sess'}: nothing to export; the session has no cameras or meshes"


def test_build_view_refuses_options_of_another_kind_and_dispatches(monkeypatch, tmp_path):
    calls = []
    monkeypatch.setattr(vw, "scene_for_mesh", lambda data, plotter, reference, title: calls.append(
        ("mesh", data, reference, title)))
    monkeypatch.setattr(vw, "scene_for_avatar", lambda data, plotter, bone, title: calls.append(
        ("avatar", data, bone, title)))
    monkeypatch.setattr(vw, "scene_for_session", lambda data, frame, plotter, images, cloud: calls.append(
        ("session", data, frame, images, cloud)))
    monkeypatch.setattr(vw, "add_time_slider", lambda plotter, data, images, cloud, frame_id: calls.append(
        ("slider", frame_id)))
    sizes = []
    monkeypatch.setattr(sc, "make_plotter", lambda off_screen, window_size: sizes.append((off_screen, window_size))
                        or SimpleNamespace())
    item = lambda kind: vw.Viewable(tmp_path / f"x.{kind}", kind, f"data {kind}")  # noqa: E731
    for kind, kw, word in (("mesh", {"bone": "hip"}, "--bone needs an avatar (a skinned .glb), this is a mesh"),
                           ("session", {"reference": "r.ply"}, "--reference colours a mesh or scan by its error; this "
                                                               "is a session"),
                           ("avatar", {"frame": 3}, "--frame picks a session frame; this is a avatar"),
                           ("mesh", {"frame": 0}, "--frame picks a session frame; this is a mesh")):
        with pytest.raises(InputError) as exc:
            vw.build_view(item(kind), **kw)
        assert str(exc.value) == f"{tmp_path / f'x.{kind}'}: {word}"
    assert sizes == []
    vw.build_view(item("session"), frame=4, images="mask", cloud=False, window_size=(10, 20))
    assert calls == [("session", "data session", 4, "mask", False)] and sizes == [(True, (10, 20))]
    vw.build_view(item("session"), off_screen=False)
    assert calls[-2:] == [("session", "data session", None, "image", True), ("slider", None)]
    vw.build_view(item("avatar"), bone="hip")
    assert calls[-1] == ("avatar", "data avatar", "hip", "x.avatar")
    save_mesh(tmp_path / "ref.ply", Mesh(V4, F2))
    vw.build_view(item("mesh"), reference=tmp_path / "ref.ply")
    kind, data, ref, title = calls[-1]
    assert (kind, data, title) == ("mesh", "data mesh", "x.mesh") and np.allclose(ref.vertices, V4)
    vw.build_view(item("mesh"))
    assert calls[-1] == ("mesh", "data mesh", None, "x.mesh")
    with pytest.raises(BodyStudioError):
        vw.build_view(tmp_path / "missing.ply")


def test_build_view_hands_each_kind_its_scene_with_the_plotter_frame_and_options(monkeypatch, tmp_path):
    import bodystudio.viewer.arm as va
    import bodystudio.viewer.garment as vg
    import bodystudio.viewer.mirror as vm

    calls = []
    made = []
    monkeypatch.setattr(sc, "make_plotter", lambda off_screen, window_size: made.append(SimpleNamespace()) or made[-1])
    rec = lambda name: lambda *a, **k: calls.append((name, a, k))  # noqa: E731
    monkeypatch.setattr(vw, "scene_for_session", rec("session"))
    monkeypatch.setattr(vw, "add_time_slider", rec("slider"))
    monkeypatch.setattr(vw, "scene_for_avatar", rec("avatar"))
    monkeypatch.setattr(vw, "scene_for_mesh", rec("mesh"))
    monkeypatch.setattr(va, "scene_for_arm_sequence", rec("arm"))
    monkeypatch.setattr(va, "add_arm_time_slider", rec("arm-slider"))
    monkeypatch.setattr(vm, "scene_for_mirror", rec("mirror"))
    monkeypatch.setattr(vg, "dress_fitted_body", lambda data: ("dressed", data))
    monkeypatch.setattr(vg, "scene_for_garment", rec("garment"))
    monkeypatch.setattr(vg, "add_garment_time_slider", rec("garment-slider"))
    item = lambda kind: vw.Viewable(tmp_path / f"x.{kind}", kind, f"data {kind}")  # noqa: E731
    for kind in ("arm", "mirror", "garment", "session"):
        calls.clear()
        assert vw.build_view(item(kind), frame=7, images="mask", cloud=False) is made[-1]
        p = made[-1]
        expected = {
            "arm": [("arm", ("data arm", 7, p), {"cloud": False})],
            "mirror": [("mirror", ("data mirror", 7, p), {})],
            "garment": [("garment", ("data garment", 7, p), {"dressed": ("dressed", "data garment")})],
            "session": [("session", ("data session", 7, p), {"images": "mask", "cloud": False})]}[kind]
        assert calls == expected
        calls.clear()
        vw.build_view(item(kind), frame=7, images="mask", cloud=False, off_screen=False)
        p = made[-1]
        sliders = {
            "arm": [("arm-slider", (p, "data arm"), {"cloud": False, "frame_id": 7})],
            "mirror": [],
            "garment": [("garment-slider", (p, "data garment", 7, ("dressed", "data garment")), {})],
            "session": [("slider", (p, "data session"), {"images": "mask", "cloud": False, "frame_id": 7})]}[kind]
        assert calls[1:] == sliders
    calls.clear()
    vw.build_view(item("avatar"))
    vw.build_view(item("mesh"))
    assert calls == [("avatar", ("data avatar", made[-2]), {"bone": None, "title": "x.avatar"}),
                     ("mesh", ("data mesh", made[-1]), {"reference": None, "title": "x.mesh"})]
