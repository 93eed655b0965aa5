"""composite.refine_and_composite's wiring of the hem matte (gar13e; issue 17, branch mutI): on by default, used
at a classifier error of exactly MAX_HEM_CLASSIFIER_ERROR, depth compositing on by default, and the frame record
(field, timings, flow flag) whole. Milliseconds."""
from types import SimpleNamespace

import numpy as np

from bodystudio.garment import composite as cp
from bodystudio.garment import refine
from tests.garment.test_hem_matte import SHIRT, SKIN, rect


def _actor(H=240, W=320):
    """A torso (rows 40-200, cols 100-220) and an arm (rows 60-90, cols 220-316) over grey; the worn shirt covers
    the torso to row 160 and the arm to col 260; plain colours, no noise."""
    person = rect((H, W), 40, 200, 100, 220) | rect((H, W), 60, 90, 220, 316)
    worn = person & (rect((H, W), 40, 160, 100, 220) | rect((H, W), 60, 90, 220, 260))
    frame = np.full((H, W, 3), 90.0)
    frame[person] = SKIN
    frame[worn] = SHIRT
    return frame.astype(np.uint8), person, worn


def _layer(shown, behind=None):
    """The garment layer: red where ``shown``, 1.9 m deep (2.1 m in ``behind``: there the body, 2.0 m, is in
    front of it)."""
    H, W = shown.shape
    rgb = np.zeros((H, W, 3), np.float32)
    rgb[shown] = [0.9, 0.1, 0.1]
    depth = np.where(shown, 1.9, 0.0)
    if behind is not None:
        depth[behind & shown] = 2.1
    return SimpleNamespace(rgb=rgb, mask=shown.copy(), depth=depth.astype(np.float32),
                           body_image=np.full((H, W, 3), 0.5, np.float32), body_mask=np.ones((H, W), bool),
                           body_depth=np.full((H, W), 2.0, np.float32))


def _shown(person):
    # the hem 3 rows too low (worn: 160), the sleeve 3 columns short (worn: 260)
    return person & (rect(person.shape, 40, 163, 100, 220) | rect(person.shape, 60, 90, 220, 257))


def test_the_hem_matte_is_on_by_default():
    frame, person, worn = _actor()
    shown = _shown(person)
    out = cp.refine_and_composite(frame, person, _layer(shown), flow=False, rbf=False)
    assert out.hem_applied is True
    assert int((out.garment_mask ^ worn).sum()) <= 0.05 * int((shown ^ worn).sum())


def test_the_matte_is_used_at_exactly_the_largest_classifier_error(monkeypatch):
    frame, person, worn = _actor()
    shown = _shown(person)
    real = refine.worn_garment_probability

    def at_the_limit(*args, **kwargs):
        prob, _ = real(*args, **kwargs)
        return prob, refine.MAX_HEM_CLASSIFIER_ERROR

    monkeypatch.setattr(refine, "worn_garment_probability", at_the_limit)
    out = cp.refine_and_composite(frame, person, _layer(shown), flow=False, rbf=False)
    assert out.hem_applied is True

    def above(*args, **kwargs):
        return real(*args, **kwargs)[0], refine.MAX_HEM_CLASSIFIER_ERROR + 1e-9

    monkeypatch.setattr(refine, "worn_garment_probability", above)
    out = cp.refine_and_composite(frame, person, _layer(shown), flow=False, rbf=False)
    assert out.hem_applied is False and np.array_equal(out.garment_mask, shown)


def test_depth_compositing_is_on_by_default_and_the_frame_record_is_whole():
    frame, person, worn = _actor()
    shown = _shown(person)
    behind = rect(person.shape, 100, 120, 140, 180)  # the body in front of the garment here (an arm across it)
    layer = _layer(shown, behind)
    out = cp.refine_and_composite(frame, person, layer, flow=False, rbf=False, hem=False)
    assert not out.garment_mask[behind].any() and out.garment_mask[shown & ~behind].all()
    assert np.array_equal(out.image[behind], frame[behind])
    flat = cp.refine_and_composite(frame, person, layer, flow=False, rbf=False, hem=False, depth=False)
    assert flat.garment_mask[behind].all()
    # the record: the field used (zero: no flow, no RBF), the step timings, the flow flag a bool
    assert out.field.shape == (*person.shape, 2) and not out.field.any()
    assert set(out.timings_ms) == {"flow", "rbf", "composite"} and all(v >= 0 for v in out.timings_ms.values())
    assert out.flow_applied is False and out.hem_applied is False


def test_the_render_loop_passes_each_option_on_and_counts_the_frames_the_matte_and_the_flow_were_used_on(
        tmp_path, monkeypatch):
    """render_garment_video's wiring: the options reach refine_and_composite as given, and the per-frame flags
    (and n_hem_applied) are what it reports, for the two frames the fit matches (the stand-in fit of
    test_composite_analytic.py; the refinement itself a spy)."""
    from tests.garment.test_composite_analytic import stand_in_render

    H, W = 40, 48
    frames = [np.full((H, W, 3), 60, np.uint8)] * 3
    fit, _ = stand_in_render(monkeypatch, frames, [0.9, 0.5, 0.9])
    seen = []

    def spy(frame, mask, layer, flow=True, rbf=True, depth=True, sigma_px=None, hem=True):
        seen.append((flow, rbf, depth, hem))
        shown = layer.mask.copy()
        return cp.RefinedFrame(frame.copy(), shown, shown, np.zeros((H, W, 2), np.float32),
                               {"flow": 0.0, "rbf": 0.0, "composite": 0.0}, flow_applied=flow, hem_applied=hem)

    monkeypatch.setattr(cp, "refine_and_composite", spy)
    for flow, hem in ((True, True), (False, True), (True, False)):
        seen.clear()
        doc = cp.render_garment_video(tmp_path / f"fit{flow}{hem}", fit=fit, flow=flow, rbf=False, depth=True,
                                      hem=hem)
        assert seen == [(flow, False, True, hem)] * 2
        assert [f["hem_applied"] for f in doc["frames"]] == [hem, False, hem]
        assert [f["flow_applied"] for f in doc["frames"]] == [flow, False, flow]
        assert doc["n_hem_applied"] == 2 * hem and doc["n_flow_applied"] == 2 * flow
        assert doc["options"]["hem"] is hem and doc["options"]["flow"] is flow
