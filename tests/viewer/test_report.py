"""The HTML report: tables and plots appear exactly when their data exists; bad input is one line."""

import base64
import re

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.fileio import write_json
from bodystudio.geometry.mesh import save_mesh
from bodystudio.viewer.report import plots_from_json, tables_from_json, write_report


def _run_folder(tmp_path, body_mesh):
    run = tmp_path / "run"
    rng = np.random.default_rng(1)
    write_json(run / "calibration" / "report.json", {
        "reproj_rms_px": 0.31, "n_observations": 500,
        "residuals_px": rng.normal(0, 0.3, 200).tolist(),
        "cameras": {"cam_00": {"reproj_rms_px": 0.3, "n_corners": 250},
                    "cam_01": {"reproj_rms_px": 0.32, "n_corners": 250}},
    })
    write_json(run / "reconstruct" / "frames.json", {"frames": [
        {"frame": f, "solver_ms": 40.0 + f, "metrics": {"visible_median_mm": 4.0 + f, "p90_mm": 9.0 + f}}
        for f in range(4)]})
    write_json(run / "rig" / "eval.json", {"energy_history": [100.0, 20.0, 5.0, 1.5, 1.2], "joint_error_mm": 12.5})
    save_mesh(run / "scan.ply", body_mesh)
    return run


def test_tables_and_plots_follow_the_data():
    tables = tables_from_json("m.json", {"rms_px": 0.5, "cameras": {"a": {"rms": 1.0}, "b": {"rms": 2.0}}})
    assert [t.columns for t in tables] == [["quantity", "value"], ["name", "rms"]]
    assert tables[1].rows == [["a", 1.0], ["b", 2.0]]
    assert plots_from_json("m.json", {"rms_px": 0.5}) == []  # no series, no plot
    per_frame = {"frames": [{"frame": i, "metrics": {"median_mm": float(i)}} for i in range(3)]}
    (plot,) = plots_from_json("f.json", per_frame)
    assert plot.title.startswith("Error per frame") and plot.png[:4] == b"\x89PNG"
    (conv,) = plots_from_json("s.json", {"cost_history": [3.0, 2.0, 1.0]})
    assert conv.title.startswith("Solver convergence")


def test_report_is_self_contained_with_tables_plots_and_3d(tmp_path, body_mesh):
    run = _run_folder(tmp_path, body_mesh)
    out = tmp_path / "report.html"
    result = write_report(run, out)
    text = out.read_text()
    titles = " | ".join(p.title for p in result.plots)
    assert "Error per frame" in titles and "Solver convergence" in titles and "Calibration residuals" in titles
    assert result.has_3d and 'id="view3d_0"' in text
    assert not re.search(r'(src|href)\s*=\s*["\']https?:', text)
    # Every image is an embedded PNG that decodes.
    images = re.findall(r'src="data:image/png;base64,([^"]+)"', text)
    assert len(images) == len(result.plots) + len(result.screenshots)
    assert all(base64.b64decode(b)[:4] == b"\x89PNG" for b in images)
    assert "cam_01" in text and "visible_median_mm" in text and "12.5" in text


def test_report_bad_input_is_one_line(tmp_path):
    with pytest.raises(InputError, match="not a folder") as exc:
        write_report(tmp_path / "missing", tmp_path / "r.html")
    assert "\n" not in str(exc.value)
    with pytest.raises(InputError, match=r"\.html"):
        write_report(tmp_path, tmp_path / "r.pdf")
    (tmp_path / "bad.json").write_text("{not json")
    result = write_report(tmp_path, tmp_path / "r.html", with_3d=False)  # broken JSON is skipped, not fatal
    assert result.tables == [] and (tmp_path / "r.html").is_file()


def test_report_opens_in_headless_chromium_and_draws(tmp_path, body_mesh, chromium):
    run = _run_folder(tmp_path, body_mesh)
    out = write_report(run, tmp_path / "report.html").path
    page = chromium(out, size=(1200, 1100))
    assert page["console"] == [], page["console"]
    assert 'data-viewer-status="ok"' in page["dom"]
    assert 'data-views-drawn="1"' in page["dom"]
    m = re.search(r'<canvas id="view3d_0"[^>]*data-drawn="(\d+)"', page["dom"])
    assert m and int(m.group(1)) >= 1
    img = page["screenshot"].astype(int)
    # The 3D view is the first dark block on the light page; the body inside it is light.
    dark = img.mean(-1) < 60
    rows = np.flatnonzero(dark.mean(1) > 0.5)
    assert len(rows) > 200
    block = img[rows[0]:rows[-1]]
    assert ((block.mean(-1) > 120) & (np.abs(block - block[5, 5]).max(-1) > 30)).sum() > 1500


def _json_values():
    from hypothesis import strategies as st

    scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6),
                        st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8))
    keys = st.sampled_from(["frame", "err_mm", "median_mm", "residuals_px", "cost_history", "cameras", "a", "iou"])
    return st.recursive(scalars, lambda children: st.one_of(st.lists(children, max_size=6),
                                                            st.dictionaries(keys, children, max_size=5)),
                        max_leaves=30)


def test_any_metrics_json_gives_tables_and_plots_without_crashing():
    import matplotlib.pyplot as plt
    from hypothesis import HealthCheck, given, settings

    @settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(_json_values())
    def check(data):
        for t in tables_from_json("x.json", data):
            assert all(len(row) == len(t.columns) for row in t.rows)
        for p in plots_from_json("x.json", data):
            assert p.png[:4] == b"\x89PNG"
        assert not plt.get_fignums()  # every figure is closed

    check()
