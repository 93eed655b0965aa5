"""viewer/garment.py's lights, frames and folder kinds against hand-computed cases (mutOO; < 1 s, no fit run).

The light arrows of Eq. 7's lights (powers, the 2 % cut inclusive, the brightest kept first, lengths and starts
by hand), the true lights carried camera to camera (a 90-degree turn written out), the chest origin, the frames
worth showing (render ``ok`` > fitted > all, spread by ``linspace`` written by hand), a frame's index and its
refusal, the missing panels' phrases, what a folder is (fit / render / neither).
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.viewer import garment as vg


def _lights(directions, colors):
    return SimpleNamespace(directions=np.asarray(directions, float), colors=np.asarray(colors, float))


def test_light_power_sums_the_non_negative_channels():
    np.testing.assert_array_equal(vg.light_power(_lights(np.eye(3), [[1, 2, 3], [-1, 0.5, 0], [0, 0, 0]])),
                                  [6.0, 0.5, 0.0])


def test_light_arrows_by_hand():
    d = [[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, -1], [-1, 0, 0]]
    c = [[1, 1, 2], [0.02, 0.04, 0.02], [0.02, 0.02, 0.03], [2, 1, 1], [0, 0, 0]]  # powers 4, 0.08, 0.07, 4, 0
    starts, vectors, power = vg.light_arrows(_lights(d, c), [1.0, 2.0, 3.0], length_m=0.5, offset_m=0.25)
    np.testing.assert_array_equal(power, [4.0, 4.0, 0.08])  # 0.08 = 2 % of 4 kept, 0.07 dropped; ties stable
    np.testing.assert_allclose(starts, [[1.25, 2, 3], [1, 2, 2.75], [1, 2.25, 3]])
    np.testing.assert_allclose(vectors, [[0.5, 0, 0], [0, 0, -0.5], [0, 0.01, 0]])
    s2, v2, p2 = vg.light_arrows(_lights(d, c), [0, 0, 0], max_arrows=2)
    np.testing.assert_array_equal(p2, [4.0, 4.0])
    np.testing.assert_allclose(v2, [[vg.ARROW_M, 0, 0], [0, 0, -vg.ARROW_M]])
    np.testing.assert_allclose(s2, [[vg.ARROW_OFFSET_M, 0, 0], [0, 0, -vg.ARROW_OFFSET_M]])
    _, _, p3 = vg.light_arrows(_lights(d, c), [0, 0, 0], min_fraction=0.0175)
    np.testing.assert_array_equal(p3, [4.0, 4.0, 0.08, 0.07])
    for lights in (_lights(d[:1], [[0, 0, 0]]), _lights(np.zeros((0, 3)), np.zeros((0, 3)))):
        s, v, p = vg.light_arrows(lights, [0, 0, 0])
        assert s.shape == (0, 3) and v.shape == (0, 3) and p.shape == (0,)
    s, v, p = vg.light_arrows(_lights(np.array([0.0, 1, 0]), [[1, 0, 0]]), [0, 0, 0])  # one flat direction
    np.testing.assert_allclose(v, [[0, vg.ARROW_M, 0]])


def test_light_origin_is_the_chest():
    V = np.array([[-1.0, 0.0, 2.0], [3.0, 2.0, 4.0], [0.0, 1.0, 3.0]])
    np.testing.assert_allclose(vg.light_origin(V), [1.0, 1.4, 3.0])


def test_true_lighting_turned_into_the_fit_frame():
    from bodystudio.garment.lighting import Lighting

    Rz = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])  # 90 degrees about z
    gt = {"directions": [[1, 0, 0], [0, 0, 1]], "colors": [[1, 1, 1], [0.5, 0.5, 0.5]], "ambient": [0.1, 0.2, 0.3]}
    session = SimpleNamespace(gt_lighting=gt, camera_names=["front", "side"], path="S",
                              cameras={"front": SimpleNamespace(R=Rz), "side": SimpleNamespace(R=np.eye(3))})
    view = SimpleNamespace(session=session, fit=SimpleNamespace(camera=SimpleNamespace(R=np.eye(3))))
    out = vg.true_lighting_in_fit_frame(view)
    assert isinstance(out, Lighting)
    np.testing.assert_allclose(out.directions, [[0, 1, 0], [0, 0, 1]], atol=1e-15)  # R_fit^T R_true d
    np.testing.assert_array_equal(out.colors, gt["colors"])
    np.testing.assert_array_equal(out.ambient, gt["ambient"])
    view = SimpleNamespace(session=session, fit=SimpleNamespace(camera=SimpleNamespace(R=Rz)))
    np.testing.assert_allclose(vg.true_lighting_in_fit_frame(view).directions, [[1, 0, 0], [0, 0, 1]], atol=1e-15)
    assert vg.true_lighting_in_fit_frame(SimpleNamespace(session=None, fit=None)) is None
    no_gt = SimpleNamespace(session=SimpleNamespace(gt_lighting=None), fit=None)
    assert vg.true_lighting_in_fit_frame(no_gt) is None
    bad = SimpleNamespace(session=SimpleNamespace(**{**vars(session), "gt_lighting": {"directions": [1]}}),
                          fit=view.fit)
    with pytest.raises(Exception, match=r"^S/gt/lighting.json: lights need"):
        vg.true_lighting_in_fit_frame(bad)


def _gview(ids, fitted, render=None, fit_dir="fits/F"):
    fit = SimpleNamespace(frame_ids=np.asarray(ids), fitted=list(fitted))
    return SimpleNamespace(fit=fit, render=render, fit_dir=Path(fit_dir))


def test_garment_frames_prefer_composited_then_fitted_frames():
    ids = list(range(20, 30))
    fitted = [k % 3 != 0 for k in range(10)]  # 21, 22, 24, 25, 27, 28 fitted
    assert vg.garment_frames(_gview(ids, fitted)) == [21, 24, 28]  # linspace(0, 5, 3) = 0, 2.5 -> 2, 5
    assert vg.garment_frames(_gview(ids, fitted), n=4) == [21, 24, 25, 28]  # 0, 1.67 -> 2, 3.33 -> 3, 5
    assert vg.garment_frames(_gview(ids, fitted), n=6) == [21, 22, 24, 25, 27, 28]
    assert vg.garment_frames(_gview(ids, [False] * 10), n=2) == [20, 29]
    render = {"frames": [{"frame": 22, "status": "ok"}, {"frame": "25", "status": "ok"},
                         {"frame": 27, "status": "failed"}, {"frame": 20, "status": "ok"}, "junk"]}
    assert vg.garment_frames(_gview(ids, fitted, render)) == [22, 25]
    assert vg.garment_frames(_gview(ids, fitted, {"frames": []})) == [21, 24, 28]
    assert vg.garment_frames(_gview(ids, fitted, {})) == [21, 24, 28]
    assert vg.garment_frames(_gview(ids, fitted, {"frames": [{"frame": 20, "status": "ok"}]})) == [21, 24, 28]


def test_frame_index_and_its_refusal():
    v = _gview([np.int64(5), 7, 9], [True] * 3)
    assert vg._frame_index(v, 7) == 1 and vg._frame_index(v, np.int64(9)) == 2 and vg._frame_index(v, 5) == 0
    with pytest.raises(InputError) as e:
        vg._frame_index(v, 8)
    assert str(e.value) == "--frame 8: not a frame of the fit fits/F (it has 3 frames, 5..9)"


def test_missing_panels_phrases():
    v = _gview([1], [True])
    assert vg.missing_panels(v, 7, [("input frame", 0), ("composite x", 0), ("truth y", 0)]) == []
    assert vg.missing_panels(v, 7, []) == ["input (the fit's source is gone)", "composite (no render)",
                                           "truth (not a synthetic garment session)"]
    v = _gview([1], [True], render={})
    assert vg.missing_panels(v, 7, [("input", 0), ("truth", 0)]) == ["composite (render/frames/00007.png missing)"]
    assert vg.missing_panels(v, 7, [("inputs", 0), ("composite", 0), ("truth", 0)]) == [
        "input (the fit's source is gone)"]


def test_what_a_folder_is(tmp_path):
    fit, render, other = tmp_path / "fit", tmp_path / "fit" / "render", tmp_path / "other"
    render.mkdir(parents=True)
    other.mkdir()
    (fit / "fit.json").write_text('{"format": "bodystudio-garment-fit"}', encoding="utf-8")
    (render / "render.json").write_text('{"format": "bodystudio-garment-render"}', encoding="utf-8")
    assert vg.is_garment_fit(fit) and vg.is_garment_fit(str(fit)) and not vg.is_garment_fit(render)
    assert vg.is_garment_render(render) and not vg.is_garment_render(fit)
    for text in ('{"format": "bodystudio-garment-render"}', "[1]", "{bad", '{"format": 3}'):
        (other / "fit.json").write_text(text, encoding="utf-8")
        assert not vg.is_garment_fit(other)
    assert vg._json_format(other / "missing.json") is None
    (other / "x.json").write_text('{"format": "é"}', encoding="utf-8")
    assert vg._json_format(other / "x.json") == "é"
    (other / "y.json").write_text("[]", encoding="utf-8")
    assert vg._json_format(other / "y.json") is None


def test_source_path_relative_to_the_fit_when_not_found_as_given(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "here.mp4").write_bytes(b"")
    fit = SimpleNamespace(source="here.mp4")
    assert vg._source_path(fit, Path("fits/F")) == Path("here.mp4")
    assert vg._source_path(SimpleNamespace(source="gone.mp4"), Path("fits/F")) == Path("fits/F/gone.mp4")
    assert vg._source_path(SimpleNamespace(source="/abs/gone.mp4"), Path("fits/F")) == Path("/abs/gone.mp4")


# --- the first run's survivors ---


def test_light_arrows_scale_to_the_brightest_below_one_and_keep_ties_in_order():
    _, v, _ = vg.light_arrows(_lights([[0, 1, 0]], [[0.1, 0.1, 0.05]]), [0, 0, 0])
    np.testing.assert_allclose(v, [[0, vg.ARROW_M, 0]])  # the brightest is ARROW_M long whatever its power
    theta = np.arange(40) * 0.1
    d = np.column_stack([np.cos(theta), np.sin(theta), np.zeros(40)])  # 40 directions, each its own
    c = np.tile([[0.5, 0.5, 0.5], [1.0, 0.5, 0.5]], (20, 1))  # 40 lights, 20 tied at each power
    starts, _, power = vg.light_arrows(_lights(d, c), [0, 0, 0], offset_m=1.0, max_arrows=40)
    np.testing.assert_array_equal(power, [2.0] * 20 + [1.5] * 20)
    np.testing.assert_allclose(starts, d[list(range(1, 40, 2)) + list(range(0, 40, 2))], atol=1e-15)  # file order


def test_light_origin_with_the_body_off_the_floor():
    V = np.array([[0.0, 1.0, 0.0], [2.0, 3.0, 2.0]])
    np.testing.assert_allclose(vg.light_origin(V), [1.0, 2.4, 1.0])


def test_garment_frames_refuse_a_fitted_list_of_another_length():
    with pytest.raises(ValueError):
        vg.garment_frames(_gview([1, 2, 3], [True, True]))
