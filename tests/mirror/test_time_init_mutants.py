"""``mirror.init.time_init_and_track``'s one-pass bodies timing (MIR12e) on stand-ins (issue 17).

The source and target bodies are posed once before the timer (numba's compile or cache load, which a running
mirror has behind it) and then once per tracked frame inside it; the stand-in clock ticks per read, so each
figure is exact. < 1 s, no body model.
"""
from __future__ import annotations

from types import SimpleNamespace as NS

import numpy as np

import bodystudio.mirror.track as track_mod
from bodystudio.mirror import init as init_mod


def _stand_ins(monkeypatch):
    calls = []
    clock = {"wall": 0.0, "cpu": 0.0}

    def wall():
        clock["wall"] += 2.0
        return clock["wall"]

    def cpu():
        clock["cpu"] += 0.5
        return clock["cpu"]

    monkeypatch.setattr(init_mod, "time", NS(perf_counter=wall, process_time=cpu))
    source = NS(vertices=np.zeros((3, 3)), weights=np.ones((3, 1)), skeleton="skeleton", frames_used=(0, 1))
    # (**kw: main's later initialisation also takes the depth camera)
    monkeypatch.setattr(init_mod, "initialise_from_observations", lambda obs, m, view_point=None, passes=3, **kw:
                        source)
    monkeypatch.setattr(init_mod, "ik_pose", lambda sk, joints, tracked, version, previous=None: ("pose", joints))
    monkeypatch.setattr(init_mod, "untwisted_pose", lambda sk, pose, bones: pose)  # MIR12p, timed with the IK
    monkeypatch.setattr(init_mod, "skin_vertices", lambda *a, **k: None)

    def bodies(Vs, Vt, W, sk_s, sk_t, pose):
        calls.append((Vs is source.vertices, Vt is source.vertices, W is source.weights, sk_s, sk_t, pose,
                      clock["wall"]))
        return Vs, Vt

    monkeypatch.setattr(track_mod, "skin_source_and_target", bodies)
    return calls


def test_one_tracked_frame_is_posed_once_before_the_timer_and_once_in_it(monkeypatch):
    calls = _stand_ins(monkeypatch)
    obs = [NS(joints="J0", tracked=None, version="v2")]
    out = init_mod.time_init_and_track(obs, "model", track_frames=1)
    # clock reads: init 2, ik 2, skin 2, then the warm-up, then bodies 2
    assert [c[-1] for c in calls] == [12.0, 14.0]
    assert all(c[:5] == (True, True, True, "skeleton", "skeleton") for c in calls)
    assert calls[0][5] == ("pose", "J0") and calls[1][5] == ("pose", "J0")
    assert out["bodies_ms"] == 2000.0 and out["bodies_cpu_ms"] == 500.0


def test_no_tracked_frame_poses_no_body(monkeypatch):
    calls = _stand_ins(monkeypatch)
    out = init_mod.time_init_and_track([NS(joints="J0", tracked=None, version="v2")], "model", track_frames=0)
    assert calls == []
    assert out["bodies_ms"] == 2000.0  # the per-frame figure of no frame is the total (one clock tick)


def test_three_frames_pose_the_first_pose_before_the_timer(monkeypatch):
    calls = _stand_ins(monkeypatch)
    obs = [NS(joints=f"J{i}", tracked=None, version="v2") for i in range(2)]
    out = init_mod.time_init_and_track(obs, "model", track_frames=3)
    assert [c[5][1] for c in calls] == ["J0", "J0", "J1", "J0"]
    assert [c[-1] for c in calls] == [12.0, 14.0, 14.0, 14.0]
    assert out["bodies_ms"] == 2000.0 / 3 and out["bodies_cpu_ms"] == 500.0 / 3
