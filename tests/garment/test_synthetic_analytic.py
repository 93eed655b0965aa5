"""The synthetic garment session (``garment/synthetic.py``; issue 17: the module was never mutated).

Tiny sessions (2k template, 64 x 80 pixels, 16-texel garments, two or three frames) written inside the tests
that check them, so each test is credited with its own calls (docs/MUTATION.md's blind spot note). What the
session must hold is rebuilt from the same seeds with the module's and the pipeline's functions: the true
lights, skin, garments and poses; the images are checked by their relations (background pixels are the
plate, the person's layers are the mask, the target differs from the video only on the garment).
"""

import functools
import json

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.garment import synthetic as syn


@functools.cache
def _body(seed=4):
    from bodystudio.body import build_body
    from bodystudio.body.population import sample_subject

    phenotype, local = sample_subject(seed)
    return build_body(phenotype, local, resolution="2k")


# --- small functions --------------------------------------------------------------------------------

def test_garment_camera_frames_2_1_m_from_1_m_high():
    from bodystudio.geometry.camera import Camera

    cam = syn.garment_camera()
    assert (cam.name, cam.width, cam.height) == ("cam_00", 480, 640)
    want = Camera.look_at("cam_00", (0.0, 1.0, 3.2), (0.0, 0.9, 0.0), fx=640 * np.hypot(3.2, 0.1) / 2.1,
                          width=480, height=640)
    assert cam.to_dict() == want.to_dict()
    small = syn.garment_camera(64, 80, 2.0)
    eye = -small.R.T @ small.t
    assert np.allclose(eye, [0.0, 1.0, 2.0], atol=1e-12)
    assert small.K[0, 0] == pytest.approx(80 * np.hypot(2.0, 0.1) / 2.1, rel=1e-12)
    # the target (0, 0.9, 0) is on the optical axis; 2.1 m at the target's distance fill the height
    assert np.allclose(small.project(np.array([[0.0, 0.9, 0.0]])), [[small.K[0, 2], small.K[1, 2]]], atol=1e-9)
    assert np.allclose(small.K[:2, 2], [32 - 0.5, 40 - 0.5], atol=0.51)


def test_sample_lighting_draws_one_light_in_the_cameras_hemisphere():
    from bodystudio.garment.lighting import Lighting

    for seed in range(40):
        light = syn.sample_lighting(np.random.default_rng(seed))
        r = np.random.default_rng(seed)
        az, el = np.radians(r.uniform(-50, 50)), np.radians(r.uniform(15, 55))
        intensity, tint, ambient = r.uniform(0.6, 0.85), r.uniform(-0.06, 0.06), r.uniform(0.15, 0.3)
        assert isinstance(light, Lighting) and light.directions.shape == (1, 3)
        d = light.directions[0]
        assert np.allclose(d, [np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)], atol=1e-12)
        assert 15 - 1e-9 <= np.degrees(np.arcsin(d[1])) <= 55 + 1e-9
        assert abs(np.degrees(np.arctan2(d[0], d[2]))) <= 50 + 1e-9
        assert np.allclose(light.colors[0], intensity * (1 + tint * np.array([1.0, 0.0, -1.0])), atol=1e-12)
        assert np.allclose(light.ambient, ambient, atol=1e-15)


def test_subject_albedo_is_a_blotched_skin_tone_with_dark_hair():
    body = _body()
    V = body.vertices
    seen = set()
    for seed in (0, 4, 6, 11):  # seeds that draw each of the four tones (3, 2, 1, 0)
        albedo = syn.subject_albedo(body, np.random.default_rng(seed))
        r = np.random.default_rng(seed)
        tones = np.array([[0.87, 0.68, 0.57], [0.76, 0.57, 0.45], [0.58, 0.42, 0.32], [0.42, 0.29, 0.21]])
        i = int(r.integers(4))
        seen.add(i)
        tone = tones[i] * r.uniform(0.95, 1.05)
        k = r.normal(size=(3, 3)) * 6.0
        phase = r.uniform(0, 2 * np.pi, 3)
        hair = np.array([0.18, 0.13, 0.1]) * r.uniform(0.7, 1.3)
        skin = tone * (1 + 0.06 * np.sin(V @ k.T + phase).mean(1))[:, None]
        head = body.skeleton.heads[body.skeleton.index("head")]
        top = V[:, 1].max()
        scalp = (V[:, 1] > head[1] + 0.55 * (top - head[1])) & (V[:, 2] < head[2] + 0.06)
        assert 10 < scalp.sum() < 0.05 * len(V)
        assert np.allclose(albedo[~scalp], np.clip(skin[~scalp], 0, 1), atol=1e-12)
        assert np.allclose(albedo[scalp], hair, atol=1e-12)
        assert albedo.min() >= 0 and albedo.max() <= 1
    assert seen == {0, 1, 2, 3}


def test_subject_albedo_is_clipped_to_one():
    from types import SimpleNamespace

    body = _body()

    class Bright:  # a generator whose tone factor is 2: the brightest tone goes above one before the clip
        def __init__(self):
            self.r = np.random.default_rng(0)

        def integers(self, n):
            return 0

        def uniform(self, lo, hi, size=None):
            return 2.0 if size is None and (lo, hi) == (0.95, 1.05) else self.r.uniform(lo, hi, size)

        def normal(self, size):
            return self.r.normal(size=size)

    albedo = syn.subject_albedo(SimpleNamespace(vertices=body.vertices, skeleton=body.skeleton), Bright())
    assert albedo.max() == 1.0 and np.any(albedo[:, 0] == 1.0)


@pytest.mark.parametrize("motion,n", [("walk", 10), ("walk", 40), ("arm_flex", 5), ("arm_flex", 70), ("turn", 7),
                                          ("a_pose", 3)])
def test_motion_poses_sample_the_motion_at_its_natural_speed(motion, n):
    from bodystudio.capture.motion import CYCLIC_MOTIONS, keyframes_to_poses, motion_keyframes

    sk = _body().skeleton
    got = syn.motion_poses(motion, n, sk, 3)
    frames = syn.MOTION_CYCLE_S[motion] * 30
    cycles = max(1, int(np.ceil(n / frames)))
    total = max(n, round(cycles * frames)) if motion in ("walk", "arm_flex") else max(n, round(frames))
    want = keyframes_to_poses(sk, motion_keyframes(motion, sk, 3, cycles), total, cyclic=motion in CYCLIC_MOTIONS)
    assert len(got) == n
    for g, w in zip(got, want[:n], strict=True):
        assert np.array_equal(g.rotations, w.rotations) and np.array_equal(g.translation, w.translation)


def test_motion_speeds():
    assert syn.MOTION_CYCLE_S == {"walk": 1.1, "arm_flex": 2.0, "turn": 4.0, "arms_raise": 2.0, "a_pose": 1.0}
    assert syn.FPS == 30.0 and syn.SENSOR_NOISE_STD == 2.0 and syn.MAX_FRAMES == 2000
    sk = _body().skeleton
    # a walk stride is 33 frames: the first 10 of a 10-frame and of a 33-frame request agree
    a, b = syn.motion_poses("walk", 10, sk, 0), syn.motion_poses("walk", 33, sk, 0)
    assert all(np.array_equal(p.rotations, q.rotations) for p, q in zip(a, b[:10], strict=True))


def test_layer_labels():
    from types import SimpleNamespace

    body = np.array([[1, 1, 0], [0, 1, 0]], bool)
    garment = np.array([[0, 1, 1], [0, 0, 0]], bool)
    labels = syn.layer_labels(SimpleNamespace(body_mask=body, garment_mask=garment))
    assert labels.dtype == np.uint8 and np.array_equal(labels, [[1, 2, 2], [0, 1, 0]])


def test_with_noise():
    img = np.array([[0, 1, 128, 254, 255]] * 40, np.uint8)[..., None].repeat(3, 2)
    same = syn._with_noise(img, 0.0, np.random.default_rng(0))
    assert np.array_equal(same, img) and same is not img
    assert np.array_equal(syn._with_noise(img, -1.0, np.random.default_rng(0)), img)
    one = syn._with_noise(img, 1.0, np.random.default_rng(2)).astype(float) - img
    assert 0.7 < np.std(one[:, 2]) < 1.3  # a std of one is noise too
    out = syn._with_noise(img, 3.0, np.random.default_rng(9))
    want = np.clip(np.round(img.astype(np.float32)
                            + np.random.default_rng(9).normal(0.0, 3.0, img.shape).astype(np.float32)), 0, 255)
    assert out.dtype == np.uint8 and np.array_equal(out, want.astype(np.uint8))
    assert out[:, 0].min() == 0 and out[:, 4].max() == 255 and 2.0 < np.std(out[:, 2].astype(float) - 128) < 4.0


def test_appearance_albedo_is_the_worn_garments_colour_where_it_covers_the_skin():
    from bodystudio.garment.garments import dress, sample_texture

    body = _body()
    worn = dress(body, "tshirt", "stripes", texture_size=16, seed=3)
    skin = np.random.default_rng(0).uniform(0, 1, (body.n_vertices, 3))
    out = syn.appearance_albedo(body, worn, skin)
    changed = np.any(out != skin, axis=1)
    y = body.vertices[:, 1]
    sk = body.skeleton
    hip = 0.5 * (sk.heads[sk.index("thigh_l"), 1] + sk.heads[sk.index("thigh_r"), 1])
    # the legs and the head are bare, the chest is covered, with the garment's (stripe) colours
    assert not changed[y < hip - 0.1].any() and not changed[y > sk.heads[sk.index("head"), 1] + 0.05].any()
    chest = (y > hip + 0.2) & (y < hip + 0.35) & (np.abs(body.vertices[:, 0]) < 0.1)
    assert changed[chest].all()
    colours = sample_texture(worn.texture, worn.uv)
    for c in out[changed][:50]:
        assert np.abs(colours - c).sum(1).min() < 0.2  # a colour of the garment's texture
    assert np.array_equal(out[~changed], skin[~changed])
    # the ray runs along the normal from 1 mm inside: the shell is 8 mm out, so a 5 mm reach finds nothing
    assert np.array_equal(syn.appearance_albedo(body, worn, skin, reach_m=0.005), skin)


def test_appearance_albedo_takes_the_texture_at_the_hit():
    from bodystudio.garment.garments import Garment

    body = _body()
    # a single big quad 5 cm in front of the chest: its texture is red on the left half (u < 0.5), blue right
    sk = body.skeleton
    z = body.vertices[:, 2].max() + 0.02
    y0 = sk.heads[sk.index("spine_03"), 1]
    V = np.array([[-0.3, y0 - 0.2, z], [0.3, y0 - 0.2, z], [0.3, y0 + 0.2, z], [-0.3, y0 + 0.2, z]])
    F = np.array([[1, 2, 3], [1, 3, 0]])  # each face's first corner has u = 1: its barycentric weight matters
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    tex = np.zeros((4, 64, 3), np.uint8)
    tex[:, :32] = (255, 0, 0)
    tex[:, 32:] = (0, 0, 255)
    worn = Garment("q", V, F, uv, tex, np.ones((4, 1)), np.arange(4))
    skin = np.full((body.n_vertices, 3), 0.5)
    out = syn.appearance_albedo(body, worn, skin, reach_m=0.5)
    N = __import__("bodystudio.geometry.mesh", fromlist=["vertex_normals"]).vertex_normals(body.vertices, body.faces)
    front = (N[:, 2] > 0.95) & (np.abs(body.vertices[:, 1] - y0) < 0.1)
    left = front & (body.vertices[:, 0] < -0.05)
    right = front & (body.vertices[:, 0] > 0.05)
    assert left.sum() > 3 and right.sum() > 3
    assert np.allclose(out[left], [1, 0, 0]) and np.allclose(out[right], [0, 0, 1])
    assert np.array_equal(out[N[:, 2] < -0.5], skin[N[:, 2] < -0.5])  # the back faces away from the quad


# --- the session -------------------------------------------------------------------------------------

SMALL = dict(subject_seed=4, n_frames=2, resolution=(64, 80), template="2k", texture_size=16)


@pytest.mark.parametrize("kwargs,message", [
    ({"garment": "cape"}, "--garment 'cape': valid: tights, skirt, tshirt, longsleeve"),
    ({"pattern": "tartan"}, "--pattern 'tartan': valid: stripes, checks, print, plain"),
    ({"motion": "dance"}, "--motion 'dance': valid: walk, arm_flex, turn, arms_raise, a_pose"),
    ({"n_frames": 0}, "--frames 0: must be in [1, 2000]"),
    ({"n_frames": 2001}, "--frames 2001: must be in [1, 2000]"),
    ({"subject_seed": -1}, "--subject-seed -1: must be >= 0"),
    ({"resolution": (63, 80)}, "--resolution 63x80: width and height must be in [64, 4096] pixels"),
    ({"resolution": (64, 4097)}, "--resolution 64x4097: width and height must be in [64, 4096] pixels"),
    ({"resolution": (4097, 64)}, "--resolution 4097x64: width and height must be in [64, 4096] pixels"),
    ({"resolution": (64, 63)}, "--resolution 64x63: width and height must be in [64, 4096] pixels"),
])
def test_session_refusals(tmp_path, kwargs, message):
    with pytest.raises(InputError) as e:
        syn.synth_garment_session(tmp_path / "s", **(SMALL | kwargs))
    assert str(e.value) == message
    assert not (tmp_path / "s").exists()


def test_session_refuses_a_used_folder(tmp_path):
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "x").write_text("")
    with pytest.raises(InputError, match="output folder exists and is not empty; choose a new folder"):
        syn.synth_garment_session(tmp_path / "s", **SMALL)
    (tmp_path / "f").write_text("")
    with pytest.raises(InputError, match="output folder exists and is not empty"):
        syn.synth_garment_session(tmp_path / "f", **SMALL)


def _truth(seed, subject_seed, garment, n_frames, motion, texture_size):
    """What the session must hold, rebuilt from its seeds."""
    from bodystudio.garment.garments import dress

    body = _body(subject_seed)
    rng = np.random.default_rng([seed, subject_seed, 13])
    light = syn.sample_lighting(rng)
    skin = syn.subject_albedo(body, rng)
    worn_seed, target_seed = int(rng.integers(1 << 16)), int(rng.integers(1 << 16))
    worn = dress(body, garment, "plain", texture_size, worn_seed)
    poses = syn.motion_poses(motion, n_frames, body.skeleton, seed)
    return body, light, skin, worn_seed, target_seed, worn, poses


def _renders(session, seed, subject_seed, garment, pattern, frame, motion, shadows):
    """(seen, true) renders of ``frame`` rebuilt from the seeds (noise-free sessions of 2 frames, 16 texels)."""
    from bodystudio.capture.render import background_plate
    from bodystudio.garment.garments import dress, pose_garment
    from bodystudio.garment.render import render_garment

    body, light, skin, worn_seed, target_seed, worn, poses = _truth(seed, subject_seed, garment, 2, motion, 16)
    target = dress(body, garment, pattern, 16, target_seed)
    camera = session.cameras["cam_00"]
    plate = background_plate(camera, seed)
    pose = poses[frame]
    Vb, _ = body.pose(pose)
    return tuple(render_garment(Vb, body.faces, g, pose_garment(g, body, pose), camera, light, plate, skin, shadows)
                 for g in (worn, target))


def test_session_holds_the_ground_truth_of_its_seeds(tmp_path):
    from bodystudio.body import posed_joints
    from bodystudio.capture.render import background_plate

    s = syn.synth_garment_session(tmp_path / "a", **SMALL, seed=1, garment="skirt", pattern="checks", noise=False,
                                  shadows=False, motion="arm_flex")
    body, light, skin, worn_seed, target_seed, worn, poses = _truth(1, 4, "skirt", 2, "arm_flex", 16)
    assert s.metadata == {"generator": "bodystudio synth garment", "subject_seed": 4, "garment": "skirt",
                          "pattern": "checks", "worn": "skirt", "motion": "arm_flex", "fps": 30.0, "seed": 1,
                          "noise_std": 0.0, "template": "2k", "resolution": [64, 80], "shadows": False,
                          "calibration_is_ground_truth": True, "color_space": "linear"}
    assert s.camera_names == ["cam_00"] and s.frame_ids == [0, 1]
    assert s.cameras["cam_00"].to_dict() == syn.garment_camera(64, 80).to_dict()
    subj = s.gt_subject
    assert subj["phenotype"] == body.phenotype.to_dict() and subj["local"] == body.local
    assert subj["template"] == "2k" and subj["rig"] == body.rig and subj["n_vertices"] == body.n_vertices
    assert subj["bone_names"] == list(body.skeleton.bone_names)
    assert subj["stature_m"] == pytest.approx(np.ptp(body.vertices[:, 1]), abs=1e-12)
    gl = s.gt_lighting
    assert np.allclose(gl["directions"], light.directions) and np.allclose(gl["colors"], light.colors)
    assert np.allclose(gl["ambient"], light.ambient) and gl["space"] == "world"
    assert gl["model"] == "albedo * (ambient + sum visible max(0, n.d) color), linear"
    assert s.gt_garment == {"worn": {"name": "skirt", "pattern": "plain", "seed": worn_seed},
                            "target": {"name": "skirt", "pattern": "checks", "seed": target_seed}, "texture_size": 16}
    assert np.array_equal(s.gt_albedo, np.round(skin, 6))  # 6 decimals
    assert np.array_equal(s.gt_appearance_albedo, np.round(syn.appearance_albedo(body, worn, skin), 6))
    doc = json.loads((s.path / "gt" / "albedo.json").read_text())
    assert doc["template"] == "2k" and doc["space"] == "linear RGB in [0, 1], one row per body vertex"
    plate = background_plate(syn.garment_camera(64, 80), 1)
    assert np.array_equal(s.background_frames("cam_00")[0], plate)
    for i, pose in enumerate(poses):
        f = s.frame(i)
        heads, tails = posed_joints(body.skeleton, pose)
        assert np.allclose(f.gt_joints["heads"], heads, atol=1e-6) and np.allclose(f.gt_joints["tails"], tails,
                                                                                  atol=1e-6)
        assert f.gt_joints["bone_names"] == list(body.skeleton.bone_names)
        assert np.allclose(f.gt_pose.rotations, pose.rotations, atol=1e-6)
        Vb, _ = body.pose(pose)
        assert np.allclose(f.gt_mesh.vertices, Vb, atol=1e-5) and np.array_equal(f.gt_mesh.faces, body.faces)
        layers, target_layers = f.gt_layers["cam_00"], f.gt_target_layers["cam_00"]
        person = f.masks["cam_00"]
        assert np.array_equal(person, layers > 0) and np.array_equal(f.gt_masks["cam_00"], person)
        assert set(np.unique(layers)) == {0, 1, 2} and np.array_equal(target_layers, layers)  # the same cut
        img, target = f.images["cam_00"], f.gt_target["cam_00"]
        # noise-free: background pixels are the plate's; the target differs from the video only on the garment
        assert np.array_equal(img[layers == 0], plate[layers == 0])
        assert np.array_equal(target[layers != 2], img[layers != 2])
        assert np.abs(target[layers == 2].astype(int) - img[layers == 2]).max() > 20
    seen, true = _renders(s, 1, 4, "skirt", "checks", 1, "arm_flex", shadows=False)
    assert np.array_equal(s.frame(1).images["cam_00"], seen.image)
    assert np.array_equal(s.frame(1).gt_target["cam_00"], true.image)


def test_session_is_reproducible_and_noisy_by_default(tmp_path):
    a = syn.synth_garment_session(tmp_path / "a", **SMALL)
    b = syn.synth_garment_session(tmp_path / "b", **SMALL)
    c = syn.synth_garment_session(tmp_path / "c", **SMALL, noise=False)
    for rel in ("cam_00/rgb/00001.png", "cam_00/background/00000.png", "gt/garment_target/cam_00/00001.png",
                "gt/albedo.json", "gt/lighting.json", "gt/garment.json", "gt/joints/00001.json"):
        assert (a.path / rel).read_bytes() == (b.path / rel).read_bytes(), rel
    assert a.metadata["noise_std"] == 2.0 and a.metadata["shadows"] is True and a.metadata["motion"] == "walk"
    assert a.metadata["garment"] == "tshirt" and a.metadata["pattern"] == "stripes" and a.metadata["seed"] == 0
    assert a.gt_garment["target"]["pattern"] == "stripes" and a.gt_garment["worn"]["name"] == "tshirt"
    # sensor noise of std 2 on the video and the background, none on the true target render
    d = a.frame(1).images["cam_00"].astype(float) - c.frame(1).images["cam_00"]
    assert 1.6 < d.std() < 2.4 and abs(d.mean()) < 0.3
    bg = a.background_frames("cam_00")[0].astype(float) - c.background_frames("cam_00")[0]
    assert 1.6 < bg.std() < 2.4
    assert np.array_equal(a.frame(1).gt_target["cam_00"], c.frame(1).gt_target["cam_00"])
    # the noise-free video and the true target are the renders of the worn and the target garment, with shadows
    seen, true = _renders(c, 0, 4, "tshirt", "stripes", 1, "walk", shadows=True)
    assert np.array_equal(c.frame(1).images["cam_00"], seen.image)
    assert np.array_equal(c.frame(1).gt_target["cam_00"], true.image)


def test_session_into_an_existing_empty_folder(tmp_path, caplog):
    (tmp_path / "s").mkdir()
    with caplog.at_level("INFO", logger="bodystudio.garment.synthetic"):
        s = syn.synth_garment_session(tmp_path / "s", **(SMALL | {"n_frames": 1, "garment": "skirt"}))
    assert s.frame_ids == [0]
    assert (f"wrote {tmp_path / 's'}: 1 frames of subject 4 wearing skirt (target skirt)"
            in [r.getMessage() for r in caplog.records])


# --- survivors of the first mutation run --------------------------------------------------------------

class _Stop(Exception):
    pass


def test_session_limits_are_inclusive(tmp_path, monkeypatch):
    """2000 frames and 4096 pixels are accepted (the generator stops at its first step after the checks)."""
    import bodystudio.body.population as population

    def stop(seed):
        raise _Stop(seed)

    monkeypatch.setattr(population, "sample_subject", stop)
    for kwargs in ({"n_frames": 2000}, {"resolution": (4096, 4096)}, {"resolution": (64, 64)}, {"subject_seed": 0}):
        with pytest.raises(_Stop):
            syn.synth_garment_session(tmp_path / "s", **(SMALL | kwargs))


def test_session_defaults(tmp_path, monkeypatch):
    """Subject 7, 60 frames of a walk on the 6k template, 512-texel garments, no progress bar."""
    import bodystudio.body as body_pkg
    import bodystudio.body.population as population
    import bodystudio.capture.session as session_mod
    import bodystudio.garment.garments as garments

    seen = {}
    real_subject, real_bar, real_build = population.sample_subject, session_mod.progress_bar, body_pkg.build_body

    def subject(seed):
        seen["subject_seed"] = seed
        return real_subject(seed)

    def build(phenotype, local, resolution):
        seen["template"] = resolution
        return real_build(phenotype, local, resolution="2k")  # the 2k body stands in for the 6k one

    def poses(motion, n, skeleton, seed):
        seen["motion"], seen["n_frames"], seen["seed"] = motion, n, seed
        return []

    def dress(body, name, pattern, texture_size, seed):
        seen["texture_size"] = texture_size
        raise _Stop()

    monkeypatch.setattr(population, "sample_subject", subject)
    monkeypatch.setattr(body_pkg, "build_body", build)
    monkeypatch.setattr(syn, "motion_poses", poses)
    monkeypatch.setattr(garments, "dress", dress)
    with pytest.raises(_Stop):
        syn.synth_garment_session(tmp_path / "s")
    assert seen == {"subject_seed": 7, "template": "6k", "motion": "walk", "n_frames": 60, "seed": 0,
                    "texture_size": 512}
    # the progress bar is off unless asked for
    bars = []

    def bar(show):
        bars.append(show)
        return real_bar(show)

    locks = []
    real_lock = session_mod.acquire_lock

    def lock(layout, command):
        locks.append(command)
        return real_lock(layout, command)

    monkeypatch.undo()
    monkeypatch.setattr(session_mod, "progress_bar", bar)
    monkeypatch.setattr(session_mod, "acquire_lock", lock)
    s = syn.synth_garment_session(tmp_path / "one", **(SMALL | {"n_frames": 1, "subject_seed": 0,
                                                                "resolution": (64, 64)}))
    assert bars == [False] and locks == ["bodystudio synth garment"]
    assert s.source == "synthetic"
