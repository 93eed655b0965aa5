"""``init.time_init_and_track(untwist_bones=)``: the benchmark times the IK with the run's untwisting, the feet
included since mir12aa (``bench_mirror`` passes ``run.untwist_bones()``); stand-ins, < 1 s."""
from types import SimpleNamespace as NS

import numpy as np

import bodystudio.mirror.track as track_mod
from bodystudio.mirror import init as init_mod
from bodystudio.mirror import run as run_mod


def test_the_bones_given_reach_every_frames_untwisting(monkeypatch):
    source = NS(vertices=np.zeros((3, 3)), weights=np.ones((3, 1)), skeleton="skeleton", frames_used=(0,))
    monkeypatch.setattr(init_mod, "initialise_from_observations", lambda obs, m, **kw: source)
    monkeypatch.setattr(init_mod, "ik_pose", lambda sk, joints, tracked, version, previous=None: "ik" + joints)
    bones_seen = []
    monkeypatch.setattr(init_mod, "untwisted_pose", lambda sk, pose, bones: bones_seen.append(bones) or pose)
    monkeypatch.setattr(init_mod, "skin_vertices", lambda *a: None)
    monkeypatch.setattr(track_mod, "skin_source_and_target", lambda *a: None)
    obs = [NS(joints="J0", tracked="T0", version="v2")]
    init_mod.time_init_and_track(obs, "model", track_frames=2, untwist_bones=run_mod.untwist_bones())
    assert bones_seen == [track_mod.UNTWIST_BONES + track_mod.UNTWIST_FEET_BONES] * 2
    assert "foot_l" in bones_seen[0] and "foot_r" in bones_seen[0]
