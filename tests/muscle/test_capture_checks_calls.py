"""How ``bodystudio muscle capture`` calls its self-checks (trust4's :mod:`bodystudio.muscle.plausibility`): the
lines of :mod:`bodystudio.muscle.capture` that call ``check_before_capture`` / ``check_after_capture`` and write
their verdict (issue 17's mutation tests of this round).

Everything around the calls is stood in (the session, the template, the model, the capture itself and the two
checks: they have their own tests, tests/muscle/test_muscle_plausibility_mutants.py), so each test runs in
milliseconds and checks only the wiring: which frames and side the check before sees, that it runs before the
capture and a refusal there stops it, what the check after gets (the capture, the session, the template, the
model, the first verdict, the override, whether the shape was given), that its verdict is kept on the capture and
written as plausibility.json.
"""

import json
from types import SimpleNamespace

import numpy as np
import pytest

import bodystudio.muscle.plausibility as plausibility
from bodystudio.errors import ImplausibleResultError
from bodystudio.muscle import capture as cap_mod


def _stand_ins(monkeypatch, n_frames=5, gt_side="right", before_raises=False):
    """The session (``n_frames`` frames 10, 11, ...; the ground truth names the ``gt_side`` arm), template, model,
    capture and checks stood in; every call appended to the returned list as (name, args, kwargs)."""
    import bodystudio.body as body_mod
    import bodystudio.capture.session as session_mod
    import bodystudio.muscle.arm as arm_mod
    import bodystudio.muscle.model as model_mod

    log = []
    session = SimpleNamespace(path="S", frame_ids=list(range(10, 10 + n_frames)),
                              gt_subject={"arm": {"resolution": "2k", "side": gt_side}})
    monkeypatch.setattr(session_mod, "open_session", lambda p: session)
    monkeypatch.setattr(body_mod, "build_body", lambda resolution: f"body-{resolution}")
    monkeypatch.setattr(arm_mod, "arm_template", lambda body, side: f"{body}-{side}")
    monkeypatch.setattr(model_mod, "load_arm_model", lambda path, template: f"model-{path}")

    def sequence(s, model, template, options, frames=None, known_shape=None, skip_bad_frames=True):
        log.append(("capture", (s, model, template), {"frames": frames, "known_shape": known_shape}))
        return SimpleNamespace(name="CAPTURE", plausibility=None)

    def before(*a, **k):
        log.append(("before", a, k))
        if before_raises:
            raise ImplausibleResultError("refused before")
        return {"verdict": "BEFORE"}

    monkeypatch.setattr(cap_mod, "capture_arm_sequence", sequence)
    monkeypatch.setattr(plausibility, "check_before_capture", before)
    monkeypatch.setattr(plausibility, "check_after_capture",
                        lambda *a, **k: log.append(("after", a, k)) or {"verdict": "AFTER", "ok": True})
    return session, log


def test_the_check_before_sees_the_captured_frames_and_side_and_runs_first(monkeypatch):
    session, log = _stand_ins(monkeypatch)
    out = cap_mod.capture_session_arm("S", None, mode="nicp", frames=3)
    assert [c[0] for c in log] == ["before", "capture", "after"]
    assert log[0][1] == (session, [10, 11, 12], "right", False) and log[0][2] == {}
    assert out.plausibility == {"verdict": "AFTER", "ok": True}
    # all frames when --frames is not given; the side asked for, not the session's
    log.clear()
    cap_mod.capture_session_arm("S", None, mode="nicp", side="left")
    assert log[0][1] == (session, [10, 11, 12, 13, 14], "left", False)
    log.clear()
    cap_mod.capture_session_arm("S", None, mode="nicp", frames=1)
    assert log[0][1][1] == [10]
    log.clear()
    cap_mod.capture_session_arm("S", None, mode="nicp", frames=5)
    assert log[0][1][1] == [10, 11, 12, 13, 14]


def test_the_check_after_gets_the_capture_inputs_and_the_first_verdict(monkeypatch):
    session, log = _stand_ins(monkeypatch)
    out = cap_mod.capture_session_arm("S", "m.npz", mode="model", frames=2)
    name, args, kwargs = log[2]
    assert name == "after" and len(args) == 6
    assert args[0] is out and args[1] is session and args[2] == "body-2k-right" and args[3] == "model-m.npz"
    assert args[4] == {"verdict": "BEFORE"} and args[5] is False and kwargs == {"shape_given": False}
    # a known shape: the check after knows the shape was given
    log.clear()
    cap_mod.capture_session_arm("S", None, mode="nicp", known_shape="SHAPE")
    assert log[2][1][3] is None and log[2][2] == {"shape_given": True}
    assert log[1][2] == {"frames": None, "known_shape": "SHAPE"}


def test_the_override_reaches_both_checks(monkeypatch):
    session, log = _stand_ins(monkeypatch)
    cap_mod.capture_session_arm("S", None, mode="nicp", accept_implausible=True)
    assert log[0][1][3] is True and log[2][1][5] is True


def test_a_refusal_before_the_capture_stops_it(monkeypatch):
    _, log = _stand_ins(monkeypatch, before_raises=True)
    with pytest.raises(ImplausibleResultError, match="^refused before$"):
        cap_mod.capture_session_arm("S", None, mode="nicp")
    assert [c[0] for c in log] == ["before"]


def _capture(plaus):
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    return cap_mod.ArmCapture(np.stack([V, V + 0.1]), np.array([[0, 1, 2]]), [None, None], None,
                              (1.0, np.eye(3), np.zeros(3)), "nicp", "2k-left", {"depth": 1.0}, [3, 4],
                              session_path="/s", plausibility=plaus)


def test_the_verdict_is_written_as_plausibility_json_when_there_is_one(tmp_path, monkeypatch):
    import bodystudio.muscle.export as export

    monkeypatch.setattr(export, "write_ply_sequence", lambda path, V, F, positions=None: None)
    monkeypatch.setattr(export, "write_morph_glb", lambda path, V, F, fps=30.0, positions=None: None)
    verdict = {"ok": True, "warnings": ["w"], "problems": [], "figures": {"depth_to_tracker_ratio": 0.97}}
    cap_mod.write_arm_capture_files(lambda rel: tmp_path / "a" / rel, _capture(verdict))
    assert json.loads((tmp_path / "a" / "plausibility.json").read_text()) == verdict
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["manifest.json", "params.json", "plausibility.json"]
    cap_mod.write_arm_capture_files(lambda rel: tmp_path / "b" / rel, _capture(None))
    assert sorted(p.name for p in (tmp_path / "b").iterdir()) == ["manifest.json", "params.json"]
    assert cap_mod.ArmCapture(np.zeros((1, 3, 3)), np.zeros((0, 3)), [None], None,
                              (1.0, np.eye(3), np.zeros(3)), "nicp", "k").plausibility is None
