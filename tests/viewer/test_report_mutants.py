"""The report's tables, plots, number formatting and sections checked against independent references (mutMM).

The written page is parsed with the standard library's ``html.parser`` and every number it shows is compared with
the input; plots are checked through the figure matplotlib was handed (the lines' data, the histogram's counts
against ``np.histogram``, the bars) and embedded images are decoded with PIL. The session, mirror and garment
sections run on stand-in views (the viewer functions they call replaced by spies), so each case takes
milliseconds.
"""

from __future__ import annotations

import base64
import html.parser
import io
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from bodystudio.errors import BodyStudioError, InputError
from bodystudio.viewer import report as rp

# --- an HTML reader (the independent reference for what the page shows) -------------------------------------------

_VOID = {"img", "meta", "input", "br", "hr", "link"}


class _Node:
    def __init__(self, tag, attrs, parent=None):
        self.tag, self.attrs, self.parent, self.children, self.parts = tag, dict(attrs), parent, [], []

    def text(self) -> str:
        return "".join(p if isinstance(p, str) else p.text() for p in self.parts)

    def find_all(self, tag):
        out = []
        for c in self.children:
            if c.tag == tag:
                out.append(c)
            out += c.find_all(tag)
        return out


class _Tree(html.parser.HTMLParser):
    def __init__(self, text: str):
        super().__init__(convert_charrefs=True)
        self.root = _Node("root", {})
        self.cur = self.root
        self.feed(text)
        self.close()

    def handle_starttag(self, tag, attrs):
        node = _Node(tag, attrs, self.cur)
        self.cur.children.append(node)
        self.cur.parts.append(node)
        if tag not in _VOID:
            self.cur = node

    def handle_startendtag(self, tag, attrs):
        node = _Node(tag, attrs, self.cur)
        self.cur.children.append(node)
        self.cur.parts.append(node)

    def handle_endtag(self, tag):
        if tag in _VOID:
            return
        node = self.cur
        while node is not self.root and node.tag != tag:
            node = node.parent
        assert node is not self.root, f"</{tag}> closes nothing"
        self.cur = node.parent

    def handle_data(self, data):
        self.cur.parts.append(data)


def _page(text: str) -> _Node:
    return _Tree(text).root


def _stray_text(root: _Node) -> list[str]:
    """Text outside any heading, caption, cell or paragraph: the page's own words never float loose."""
    loose = [p for p in root.parts if isinstance(p, str) and p.strip()]
    for div in root.find_all("div"):
        if div.attrs.get("class") in ("grid", "scroll"):  # the report's own containers (the 3D view's have words)
            loose += [p for p in div.parts if isinstance(p, str) and p.strip()]
    for tag in ("table", "thead", "tbody", "tr", "ul", "body"):
        for node in root.find_all(tag):
            loose += [p for p in node.parts if isinstance(p, str) and p.strip()]
    return loose


def _tables(root: _Node) -> list[dict]:
    """Each ``<h3>title</h3><div><table>`` of the page: title, header cells, rows of (text, class)."""
    out = []
    for div in root.find_all("div"):
        tables = [c for c in div.children if c.tag == "table"]
        if not tables:
            continue
        parent = div.parent
        k = parent.children.index(div)
        h3 = parent.children[k - 1]
        assert h3.tag == "h3"
        t = tables[0]
        head = [th.text() for th in t.find_all("th")]
        rows = [[(td.text(), td.attrs.get("class")) for td in tr.find_all("td")]
                for tr in t.find_all("tbody")[0].find_all("tr")]
        out.append({"title": h3.text(), "columns": head, "rows": rows})
    return out


def _figures(node: _Node) -> list[tuple[str, np.ndarray, str]]:
    """(alt, decoded image, caption) of every figure under ``node``."""
    from PIL import Image

    out = []
    for fig in node.find_all("figure"):
        (img,) = fig.find_all("img")
        src = img.attrs["src"]
        assert src.startswith("data:image/png;base64,")
        png = base64.b64decode(src.split(",", 1)[1])
        out.append((img.attrs["alt"], np.asarray(Image.open(io.BytesIO(png))), fig.find_all("figcaption")[0].text()))
    return out


def _png(image: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG")
    return buf.getvalue()


def _decode(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)))


# --- tables ---------------------------------------------------------------------------------------------------------


def test_flatten_record_keeps_scalars_two_levels_deep_with_dotted_keys():
    record = {"a": 1, "s": "x", "n": None, "t": True, "l": [1, 2],
              "b": {"c": 2.5, "d": {"e": 3, "f": {"g": 4}}, "m": [3]}}
    assert rp.flatten_record(record) == {"a": 1, "s": "x", "n": None, "t": True, "b.c": 2.5, "b.d.e": 3}
    assert rp.flatten_record(record, depth=0) == {"a": 1, "s": "x", "n": None, "t": True}
    assert rp.flatten_record(record, depth=1) == {"a": 1, "s": "x", "n": None, "t": True, "b.c": 2.5}
    assert rp.flatten_record(record, prefix="p.", depth=3) == {
        "p.a": 1, "p.s": "x", "p.n": None, "p.t": True, "p.b.c": 2.5, "p.b.d.e": 3, "p.b.d.f.g": 4}


def test_record_lists_and_their_tables():
    assert rp._record_list([]) is None
    assert rp._record_list({"a": 1}) is None
    assert rp._record_list([{"a": 1}, 2]) is None
    assert rp._record_list([{"a": 1}, {"l": [1]}]) is None  # a record with nothing to show
    assert rp._record_list([{"a": 1, "b": {"c": 2}}, {"d": "x"}]) == [{"a": 1, "b.c": 2}, {"d": "x"}]
    t = rp._records_table("T", [{"a": 1, "b": 2}, {"c": 3, "a": 4}, {"b": 5}])
    assert (t.title, t.columns, t.rows) == ("T", ["a", "b", "c"], [[1, 2, None], [4, None, 3], [None, 5, None]])
    t = rp._records_table("T", [{"a": 1}, {"a": 2}], "name", ["x", "y"])
    assert (t.columns, t.rows) == (["name", "a"], [["x", 1], ["y", 2]])
    t = rp._records_table("T", [{"a": 1}], None, ["x"])
    assert t.columns == ["", "a"]
    many = [{"i": i} for i in range(rp.MAX_ROWS + 5)]
    t = rp._records_table("T", many + [{"late": 1}])
    assert t.columns == ["i", "late"]  # columns come from every record, rows stop at MAX_ROWS
    assert len(t.rows) == rp.MAX_ROWS == 200 and t.rows[-1] == [199, None]


def test_tables_from_json_names_places_and_summarises_every_value():
    data = {"rms_px": 0.5, "name": "cam", "flag": False, "none": None,
            "errors": [1.0, 2.0, 6.0],
            "cameras": {"c0": {"rms": 1.0, "n": 3}, "c1": {"rms": 2.0}},
            "frames": [{"frame": 0, "err": 1.5}, {"frame": 1, "err": 2.5}],
            "nested": {"deep": {"x": 1, "ys": [4, 6]}, "k": 7, "mixed": [1, "a"]}}
    tables = rp.tables_from_json("m.json", data)
    got = [(t.title, t.columns, t.rows) for t in tables]
    assert got == [
        ("m.json", ["quantity", "value"], [["rms_px", 0.5], ["name", "cam"], ["flag", False], ["none", None],
                                           ["errors (n=3)", "mean 3, min 1, max 6"]]),
        ("m.json / cameras", ["name", "rms", "n"], [["c0", 1.0, 3], ["c1", 2.0, None]]),
        ("m.json / frames", ["frame", "err"], [[0, 1.5], [1, 2.5]]),
        ("m.json / nested", ["quantity", "value"], [["k", 7]]),
        ("m.json / nested / deep", ["quantity", "value"], [["x", 1], ["ys (n=2)", "mean 5, min 4, max 6"]]),
    ]
    (t,) = rp.tables_from_json("v.json", {"e": [1.23456789, 2.0, 10.5]})
    assert t.rows == [["e (n=3)", "mean 4.578, min 1.235, max 10.5"]]
    assert rp.tables_from_json("l.json", [{"a": 1}, {"a": 2}])[0].title == "l.json"
    assert rp.tables_from_json("s.json", 3.0) == [] and rp.tables_from_json("e.json", {}) == []
    # a map of records that is empty or holds a non-record is walked, not tabled
    walked = rp.tables_from_json("w.json", {"m": {"a": {"x": 1}, "b": 2}})
    assert [(t.title, t.rows) for t in walked] == [("w.json / m", [["b", 2]]), ("w.json / m / a", [["x", 1]])]
    # an empty record and a record holding a list are not records: walked, not tabled
    assert rp.tables_from_json("w.json", {"m": {"a": {}, "b": {}}}) == []
    walked = rp.tables_from_json("w.json", {"m": {"a": {"x": [1.0]}, "b": {"x": [2.0]}}})
    assert [(t.title, t.rows) for t in walked] == [("w.json / m / a", [["x (n=1)", "mean 1, min 1, max 1"]]),
                                                   ("w.json / m / b", [["x (n=1)", "mean 2, min 2, max 2"]])]
    assert rp.tables_from_json("e.json", {"e": []}) == []  # an empty list is no series (no mean of nothing)
    (t,) = rp.tables_from_json("o.json", {"cams": {"only": {"rms": 1.0}}})  # a map of one record is a table too
    assert (t.title, t.columns, t.rows) == ("o.json / cams", ["name", "rms"], [["only", 1.0]])
    big = {f"c{k:03d}": {"v": k} for k in range(rp.MAX_ROWS + 5)}
    (t,) = rp.tables_from_json("b.json", {"cams": big})
    assert len(t.rows) == rp.MAX_ROWS and t.rows[-1] == [f"c{rp.MAX_ROWS - 1:03d}", rp.MAX_ROWS - 1]


def test_series_and_frame_records_find_every_path():
    data = {"a": {"b": 1, "c": [{"d": 2}, {"d": 3}]}, "e": [1, 2]}
    assert rp._series(data) == [("a", data["a"]), ("a.b", 1), ("a.c", data["a"]["c"]), ("a.c[0].d", 2),
                                ("a.c[1].d", 3), ("e", [1, 2])]
    long = {"r": [{"x": i} for i in range(rp.MAX_ROWS + 3)]}
    assert [p for p, _ in rp._series(long)][-1] == f"r[{rp.MAX_ROWS - 1}].x"
    assert rp._series([{"q": 1}], "top") == [("top[0].q", 1)]
    assert rp._series(5) == [] and rp._series([1, 2]) == []
    per_frame = {"frames": [{"frame_id": 3, "e": 1.0}, {"frame_id": 4, "e": 2.0}],
                 "other": [{"frame": 1}, {"x": 2}],
                 "by_id": {"7": {"err": 1.0}, "12": {"err": 3.0}}, "bad": {"7": {"err": 1.0}, "x": {"err": 2}},
                 "lists": {"1": [1.0], "2": [2.0]}, "empty": {"1": {}, "2": {}}}
    found = rp._frame_records(per_frame)
    assert found == [("frames", per_frame["frames"]),
                     ("by_id", [{"frame": 7, "err": 1.0}, {"frame": 12, "err": 3.0}])]
    assert rp._frame_records([{"frame_index": 0, "v": 1}]) == [("", [{"frame_index": 0, "v": 1}])]
    assert rp._frame_records([{"frame_idx": 0}]) == [("", [{"frame_idx": 0}])]


def test_fmt_and_table_html_show_each_value_and_escape_text():
    assert rp._fmt(float("nan")) == "n/a"
    assert rp._fmt(1234567.0) == "1.235e+06" and rp._fmt(0.000123456) == "0.0001235" and rp._fmt(2.0) == "2"
    assert rp._fmt(7) == "7" and rp._fmt(True) == "True" and rp._fmt(None) == "None"
    assert rp._fmt("<a&b>") == "&lt;a&amp;b&gt;"
    t = rp.Table("T <1>", ["k<", "v"], [["a<b", 1.23456], ["n", float("nan")], ["i", 3], ["s", "x&y"]])
    text = rp._table_html(t)
    assert _stray_text(_page(text)) == []
    (parsed,) = _tables(_page(text))
    assert parsed == {"title": "T <1>", "columns": ["k<", "v"],
                      "rows": [[("a<b", "t"), ("1.235", None)], [("n", "t"), ("n/a", None)],
                               [("i", "t"), ("3", None)], [("s", "t"), ("x&y", "t")]]}
    assert text.endswith("</tbody></table></div>\n") and '<div class="scroll"><table><thead><tr>' in text


def test_png_bytes_and_img_tag_embed_the_exact_pixels():
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)
    assert np.array_equal(_decode(rp._png_bytes(image)), image)
    tag = rp._img_tag(_png(image), 'a "b" <c>')
    (img,) = _page(tag).find_all("img")
    assert img.attrs["alt"] == 'a "b" <c>'
    assert np.array_equal(_decode(base64.b64decode(img.attrs["src"].split(",", 1)[1])), image)


def test_strict_json_replaces_every_non_finite_float():
    value = {"a": float("inf"), "b": [1.0, float("nan"), {"c": -float("inf"), "d": 2}], "e": "x", "f": 3.5}
    assert rp._strict_json(value) == {"a": None, "b": [1.0, None, {"c": None, "d": 2}], "e": "x", "f": 3.5}
    assert rp._strict_json(float("nan")) is None and rp._strict_json(1.5) == 1.5


# --- plots: what matplotlib was handed ---------------------------------------------------------------------------


def _capture_figures(monkeypatch) -> list[dict]:
    """Replace the PNG step by a recorder of each figure's axes (lines, bars, labels, scales, size)."""
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    drawn = []

    def record(fig):
        (ax,) = fig.axes
        bars = [p for p in ax.patches if isinstance(p, Rectangle)]
        drawn.append({
            "size": tuple(fig.get_size_inches()), "title": ax.get_title(),
            "title_size": ax.title.get_fontsize(),
            "grid_alpha": [g.get_alpha() for g in ax.get_xgridlines()][:1],
            "grid_on": all(g.get_visible() for g in ax.get_xgridlines()),
            "lines": [(ln.get_label(), np.asarray(ln.get_xdata(), float), np.asarray(ln.get_ydata(), float),
                       ln.get_marker(), ln.get_linestyle()) for ln in ax.get_lines()],
            "bars": [(b.get_x(), b.get_width(), b.get_height()) for b in bars],
            "bar_colors": {tuple(np.round(b.get_facecolor(), 3)) for b in bars},
            "xticklabels": [t.get_text() for t in ax.get_xticklabels()],
            "xtick_rotation": [t.get_rotation() for t in ax.get_xticklabels()][:1],
            "xtick_size": [t.get_fontsize() for t in ax.get_xticklabels()][:1],
            "ytick_rotation": [t.get_rotation() for t in ax.get_yticklabels()][:1],
            "ytick_size": [t.get_fontsize() for t in ax.get_yticklabels()][:1],
            "line_colors": [tuple(np.round(__import__("matplotlib").colors.to_rgba(ln.get_color()), 3))
                            for ln in ax.get_lines()],
            "xlabel": ax.get_xlabel(), "ylabel": ax.get_ylabel(), "yscale": ax.get_yscale(),
            "legend": None if ax.get_legend() is None else
            ([t.get_text() for t in ax.get_legend().get_texts()], ax.get_legend().get_texts()[0].get_fontsize()),
            "xlocator": ax.xaxis.get_major_locator(),
        })
        plt.close(fig)
        return b"\x89PNG-stand-in"

    monkeypatch.setattr(rp, "_figure_png", record)
    return drawn


def _hist_counts(bars) -> np.ndarray:
    return np.array([h for _x, _w, h in bars])


def test_error_per_frame_plot_draws_the_error_columns_in_order(monkeypatch):
    drawn = _capture_figures(monkeypatch)
    records = [{"frame": f, "solver_ms": 1.0, "region_a_mm": 5.0 + f, "zz.err": 10.0 + f, "p.q.rmse": 2.0 * f,
                "median_mm": 1.0 + f, "name": "x", "half_err": (1.0 if f else "n")} for f in (0, 5, 9)]
    plots = rp.plots_from_json("f.json", {"frames": records})
    assert [p.title for p in plots] == ["Error per frame (f.json)"]
    assert plots[0].png == b"\x89PNG-stand-in"
    (fig,) = drawn
    # main statistics first, region columns last, then by depth (half_err has a text value: left out)
    order = ["median_mm", "p.q.rmse", "zz.err", "region_a_mm"]
    assert [ln[0] for ln in fig["lines"]] == order
    for label, x, y, marker, _ in fig["lines"]:
        assert np.array_equal(x, [0, 5, 9]) and marker == "o"
        assert np.array_equal(y, [r[label] for r in records])
    assert fig["title"] == "error per frame: f.json frames"
    assert (fig["xlabel"], fig["ylabel"]) == ("frame", "error (mm)")
    assert fig["legend"] == (order, 8.0)
    from matplotlib.ticker import MaxNLocator

    loc = fig["xlocator"]
    assert isinstance(loc, MaxNLocator) and loc._integer
    assert fig["size"] == (6.4, 3.6) and fig["title_size"] == 11.0
    assert fig["grid_on"] and fig["grid_alpha"] == [0.3]


def test_error_per_frame_plot_caps_at_six_columns_and_says_no_unit_without_mm(monkeypatch):
    drawn = _capture_figures(monkeypatch)
    records = [{"frame_id": f, **{f"e{k}_err": float(k + f) for k in range(8)}} for f in range(3)]
    (plot,) = rp.plots_from_json("g.json", records)
    (fig,) = drawn
    assert [ln[0] for ln in fig["lines"]] == [f"e{k}_err" for k in range(6)]
    assert fig["ylabel"] == "error" and fig["title"] == "error per frame: g.json"
    assert plot.title == "Error per frame (g.json)"
    # a single record is still a plot; a table with no error column is not
    drawn.clear()
    assert len(rp.plots_from_json("h.json", [{"frame": 0, "rmse": 1.0}])) == 1
    assert [ln[0] for ln in drawn[0]["lines"]] == ["rmse"]
    assert rp.plots_from_json("i.json", [{"frame": 0, "time": 1.0}, {"frame": 1, "time": 2.0}]) == []


def test_convergence_plots_and_their_log_scale(monkeypatch):
    drawn = _capture_figures(monkeypatch)
    data = {"solve": {"energy_history": [100.0, 10.0, 2.0, 1.0], "cost": [3.0, 2.0, 1.0],
                      "loss": [1.0, 2.0], "objective": [5.0, 4.0, 0.0], "flat_convergence": [21.0, 1.0, 1.5]}}
    plots = rp.plots_from_json("s.json", data)
    assert [p.title for p in plots] == ["Solver convergence (s.json: solve.energy_history)",
                                        "Solver convergence (s.json: solve.cost)",
                                        "Solver convergence (s.json: solve.objective)",
                                        "Solver convergence (s.json: solve.flat_convergence)"]
    assert [f["yscale"] for f in drawn] == ["log", "linear", "linear", "log"]  # ratio 100, 3, a zero, 21
    assert [f["ylabel"] for f in drawn] == ["energy_history", "cost", "objective", "flat_convergence"]
    label, x, y, marker, _ = drawn[0]["lines"][0]
    assert np.array_equal(x, [0, 1, 2, 3]) and np.array_equal(y, [100, 10, 2, 1]) and marker == "."
    assert drawn[0]["xlabel"] == "iteration" and drawn[0]["title"] == "solver convergence: s.json solve.energy_history"
    drawn.clear()
    rp.plots_from_json("t.json", {"cost": [20.0, 1.0, 1.0], "a": {"b": {"loss": [30.0, 20.0, 10.0]}},
                                  "small_cost": [0.9, 0.5, 0.01]})
    # a ratio of exactly 20 stays linear; 3 (large values) linear; 90 (values under 1) logarithmic
    assert [f["yscale"] for f in drawn] == ["linear", "linear", "log"]
    assert [f["ylabel"] for f in drawn] == ["cost", "loss", "small_cost"]  # the last key of a deep path


def test_residual_and_error_histograms_and_per_camera_bars(monkeypatch):
    drawn = _capture_figures(monkeypatch)
    rng = np.random.default_rng(5)
    resid = rng.normal(0, 1, 57).tolist() + [float("nan"), float("inf")]
    errs = rng.uniform(0, 3, 10).tolist()
    data = {"residuals_px": resid, "vertex_err_mm": errs, "short_err": list(range(9)),
            "reproj": {"cam_b": 0.5, "cam_a": 0.25}, "one_residual": {"c": 1.0}, "bad_residual": {"c": 1.0, "d": "x"}}
    plots = rp.plots_from_json("c.json", data)
    assert [p.title for p in plots] == ["Calibration residuals (c.json: residuals_px)",
                                        "Error histogram (c.json: vertex_err_mm)",
                                        "Calibration residuals (c.json: reproj)"]
    finite = np.asarray(resid)[np.isfinite(resid)]
    counts, edges = np.histogram(finite, bins=40)
    assert np.array_equal(_hist_counts(drawn[0]["bars"]), counts)
    assert np.allclose([b[0] for b in drawn[0]["bars"]], edges[:-1])
    assert drawn[0]["bar_colors"] == {(0.29, 0.498, 0.71, 1.0)}
    assert (drawn[0]["xlabel"], drawn[0]["ylabel"]) == ("residuals_px", "count")
    assert drawn[0]["title"] == "calibration residuals: c.json residuals_px"
    assert np.array_equal(_hist_counts(drawn[1]["bars"]), np.histogram(errs, bins=40)[0])
    assert drawn[1]["title"] == "error histogram: c.json vertex_err_mm"
    bars = drawn[2]
    assert bars["xticklabels"] == ["cam_b", "cam_a"] and [b[2] for b in bars["bars"]] == [0.5, 0.25]
    assert bars["ylabel"] == "reproj" and bars["title"] == "calibration residuals: c.json reproj"
    assert bars["bar_colors"] == {(0.29, 0.498, 0.71, 1.0)}
    assert bars["xtick_rotation"] == [45.0] and bars["xtick_size"] == [8.0]
    assert bars["ytick_rotation"] == [0.0] and bars["ytick_size"] != [8.0]  # only the camera names turn


def test_plots_per_file_stop_at_the_cap(monkeypatch):
    _capture_figures(monkeypatch)
    data = {f"cost_{k}": [3.0, 2.0, 1.0] for k in range(rp.MAX_PLOTS_PER_FILE + 3)}
    assert len(rp.plots_from_json("m.json", data)) == rp.MAX_PLOTS_PER_FILE == 8


def test_error_histogram_counts_and_marks_the_mean(monkeypatch):
    drawn = _capture_figures(monkeypatch)
    err = np.array([1.0, 2.0, 2.5, 7.0, 12.25])
    plot = rp.error_histogram(err, "H")
    assert plot.title == "H"
    (fig,) = drawn
    assert np.array_equal(_hist_counts(fig["bars"]), np.histogram(err, bins=50)[0])
    assert fig["bar_colors"] == {(0.753, 0.314, 0.302, 1.0)}
    ((label, x, _y, _m, style),) = fig["lines"]
    assert np.allclose(x, err.mean()) and style == "--" and label == "mean 5.0 mm"
    assert fig["line_colors"] == [(0.0, 0.0, 0.0, 1.0)]  # black
    assert (fig["xlabel"], fig["ylabel"], fig["legend"]) == ("error (mm)", "vertices", (["mean 5.0 mm"], 8.0))


def test_figure_png_is_a_640_by_360_png_and_closes_the_figure():
    import matplotlib.pyplot as plt

    fig, ax = rp._new_figure("T")
    ax.plot([0, 1], [0, 1])
    png = rp._figure_png(fig)
    assert _decode(png).shape[:2] == (360, 640)
    assert not plt.get_fignums()


# --- files -----------------------------------------------------------------------------------------------------------


def _write(path, text="{}"):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_metrics_files_skip_streams_manifests_hidden_big_and_arm_capture_files(tmp_path):
    keep = [_write(tmp_path / "a.json"), _write(tmp_path / "calibration" / "report.json"),
            _write(tmp_path / "x" / "camera" / "m.json"), _write(tmp_path / "masks" / "m.json"),
            _write(tmp_path / "plain" / "params.json"), _write(tmp_path / "edge.json", " " * rp.MAX_JSON_BYTES)]
    for part in ("cam_00", "kinect", "gt", ".staging", "calibration_images", "background", "rgb", "mask"):
        _write(tmp_path / "s" / part / "f.json")
    _write(tmp_path / "x" / "cam_data" / "m.json")
    for name in ("session.json", "cameras.json", "commit.json", "board.json", ".hidden.json"):
        _write(tmp_path / "d" / name)
    _write(tmp_path / "big.json", " " * (rp.MAX_JSON_BYTES + 1))
    arm = tmp_path / "arm"
    _write(arm / "manifest.json", json.dumps({"format": "bodystudio-arm-capture"}))
    _write(arm / "params.json")
    _write(arm / "eval.json")
    keep.append(arm / "eval.json")
    assert rp.metrics_files(tmp_path) == sorted(keep)


def test_screenshot_files_skip_streams_run_frames_fit_masks_and_the_report(tmp_path):
    shot = _png(np.zeros((2, 2, 3), np.uint8))

    def put(rel):
        p = tmp_path / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(shot)
        return p

    keep = [put("a.png"), put("views/b.png"), put("fit/c.png")]
    put("run/b.png")  # anything inside a mirror run folder: the mirror section shows it
    for rel in ("s/cam_01/x.png", "s/rgb/x.png", "s/mask/x.png", "s/gt/x.png", ".h.png", "d/.h.png",
                "run/frames/00001.png", "fit/masks/00001.png", "fit/render/00001.png", "out.png"):
        put(rel)
    _write(tmp_path / "run" / "run.json", json.dumps({"format": "bodystudio-mirror-run"}))
    _write(tmp_path / "other" / "run.json", json.dumps({"format": "other"}))
    keep.append(put("other/frames/1.png"))
    _write(tmp_path / "fit" / "fit.json")
    assert rp.screenshot_files(tmp_path, exclude=tmp_path / "out.png") == sorted(keep)
    assert tmp_path / "out.png" in rp.screenshot_files(tmp_path)
    for k in range(rp.MAX_SCREENSHOTS + 2):
        put(f"many/{k:02d}.png")
    assert len(rp.screenshot_files(tmp_path)) == rp.MAX_SCREENSHOTS == 12


def test_sessions_and_garment_fit_folders_under_a_root(tmp_path):
    assert rp._sessions_under(tmp_path) == []
    for name in ("b", "a"):
        _write(tmp_path / name / "session.json")
    _write(tmp_path / "c" / "d" / "session.json")
    assert rp._sessions_under(tmp_path) == [tmp_path / "a", tmp_path / "b"]
    assert rp._sessions_under(tmp_path / "a") == [tmp_path / "a"]
    g = tmp_path / "g"
    for rel in ("f1", "x/y/f2", "x/y/z/w/f3", ".h/f4", "cam_0/f5", "k/kinect/f6", "x/y/z/f7", "k/.h/f8",
                "f1/sub/f9"):
        _write(g / rel / "fit.json")
    assert rp.garment_fit_dirs(g) == [g / "f1", g / "f1" / "sub" / "f9", g / "x" / "y" / "f2"]
    assert rp.garment_fit_dirs(g / "f1") == [g / "f1"]  # a fit folder is its own fit, not those inside it
    (g / "f1" / "plain").mkdir()
    assert rp.garment_fit_dirs(g / "f1" / "plain") == []  # a folder inside a fit is not its render
    assert rp.garment_fit_dirs(g / "x" / "y" / "z") == [g / "x" / "y" / "z" / "f7", g / "x" / "y" / "z" / "w" / "f3"]
    render = g / "f1" / "render"
    _write(render / "render.json", json.dumps({"format": "bodystudio-garment-render"}))
    from bodystudio.viewer.garment import is_garment_render

    if is_garment_render(render):
        assert rp.garment_fit_dirs(render) == [g / "f1"]


# --- the session section: reconstruction vs ground truth ------------------------------------------------------------


def _square_gt():
    from bodystudio.geometry.mesh import Mesh

    V = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    return Mesh(V, np.array([[0, 1, 2], [0, 2, 3]]))


def _lifted(tmp_path, name, heights_mm):
    """A mesh whose vertices stand ``heights_mm`` above the ground-truth square's inside (their distances)."""
    from bodystudio.geometry.mesh import Mesh, save_mesh

    xy = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
    V = np.c_[xy, np.asarray(heights_mm, float) / 1000.0]
    path = tmp_path / f"{name}.ply"
    save_mesh(path, Mesh(V, np.array([[0, 1, 2], [0, 2, 3]])))
    return path


def _stand_in_session(monkeypatch, tmp_path, recon: dict, gt_frames: set, frame_ids):
    from types import SimpleNamespace

    import bodystudio.capture.session as cs
    import bodystudio.viewer.views as vv

    gt = _square_gt()
    session = SimpleNamespace(path=tmp_path / "sess", frame_ids=list(frame_ids),
                              frame=lambda fid: SimpleNamespace(gt_mesh=gt if fid in gt_frames else None))
    def open_session(p):
        assert p == tmp_path / "sess"
        return session

    def mesh_path(path, fid):
        assert path == session.path
        return recon.get(fid)

    monkeypatch.setattr(cs, "open_session", open_session)
    monkeypatch.setattr(vv, "reconstructed_mesh_path", mesh_path)
    return session


def test_session_figures_table_and_plots_match_hand_computed_errors(monkeypatch, tmp_path):
    drawn = _capture_figures(monkeypatch)
    recon = {1: _lifted(tmp_path, "f1", [1.0, 2.0, 4.0, 10.0]), 3: _lifted(tmp_path, "f3", [5.0] * 4),
             4: _lifted(tmp_path, "f4", [0.5, 1.5, 2.5, 3.5])}
    _stand_in_session(monkeypatch, tmp_path, recon, gt_frames={1, 2, 4}, frame_ids=[1, 2, 3, 4])
    plots, tables = rp.session_figures(tmp_path / "sess")
    (table,) = tables
    assert table.title == "sess: reconstruction vs ground truth (per-vertex distance, mm)"
    assert table.columns == ["frame", "mean_mm", "rms_mm", "p95_mm", "max_mm"]
    # by hand: mean, sqrt(mean of squares), linear-interpolated 95th percentile (position 0.95 * 3), max
    expected = [[1, 4.25, 5.5, 4.0 + 0.85 * 6.0, 10.0], [4, 2.0, math.sqrt(5.25), 2.5 + 0.85 * 1.0, 3.5]]
    assert [r[0] for r in table.rows] == [1, 4]
    assert np.allclose([r[1:] for r in table.rows], [r[1:] for r in expected], atol=1e-6)
    assert all(isinstance(v, float) for r in table.rows for v in r[1:])
    assert [p.title for p in plots] == ["Error per frame (sess)", "Error histogram, sess, all frames"]
    hist, per_frame = drawn  # the histogram is drawn first and shown second
    assert [(ln[0], list(ln[1]), ln[3]) for ln in per_frame["lines"]] == [("mean", [1, 4], "o"), ("p95", [1, 4], "o")]
    assert np.allclose(per_frame["lines"][0][2], [4.25, 2.0], atol=1e-6)
    assert np.allclose(per_frame["lines"][1][2], [9.1, 3.35], atol=1e-6)
    assert per_frame["title"] == "error per frame: sess" and per_frame["ylabel"] == "error (mm)"
    assert per_frame["xlabel"] == "frame" and per_frame["legend"] == (["mean", "p95"], 8.0)
    assert per_frame["xlocator"]._integer
    all_err = [1.0, 2.0, 4.0, 10.0, 0.5, 1.5, 2.5, 3.5]
    counts = np.histogram(all_err, bins=50)[0]
    assert np.array_equal(_hist_counts(hist["bars"]), counts)
    assert hist["title"] == "Error histogram, sess, all frames"


def test_session_figures_of_one_frame_and_of_none(monkeypatch, tmp_path):
    drawn = _capture_figures(monkeypatch)
    _stand_in_session(monkeypatch, tmp_path, {2: _lifted(tmp_path, "f2", [3.0] * 4)}, {2}, [1, 2])
    plots, tables = rp.session_figures(tmp_path / "sess")
    assert [p.title for p in plots] == ["Error histogram, sess, all frames"] and len(drawn) == 1
    assert np.allclose(tables[0].rows, [[2, 3.0, 3.0, 3.0, 3.0]], atol=1e-6)
    _stand_in_session(monkeypatch, tmp_path, {2: _lifted(tmp_path, "f2", [3.0] * 4)}, set(), [1, 2])
    assert rp.session_figures(tmp_path / "sess") == ([], [])


# --- the mirror section --------------------------------------------------------------------------------------------


def _strip(fid: int, shape=(6, 10, 3)) -> np.ndarray:
    """A strip whose every pixel says its frame and place."""
    h, w, _ = shape
    img = np.zeros(shape, np.uint8)
    img[..., 0] = fid
    img[..., 1] = np.arange(h)[:, None] * 7 % 256
    img[..., 2] = np.arange(w)[None, :] * 5 % 256
    return img


def _mirror_stand_ins(monkeypatch, tmp_path, views, scores_of=None, fingerprints=None):
    import bodystudio.mirror.evaluate as me
    import bodystudio.mirror.init as mi
    import bodystudio.viewer.mirror as vm

    asked = []

    def frames(view, n):
        asked.append(n)
        return view.frame_ids

    monkeypatch.setattr(vm, "mirror_frames", frames)
    def strip(view, fid):
        assert fid in view.frame_ids
        return _strip(fid)

    monkeypatch.setattr(vm, "before_after_strip", strip)
    monkeypatch.setattr(vm, "open_mirror_view", lambda p: views[str(p)])

    def evaluate(session, run_dir):
        assert str(run_dir).startswith(session.path)
        result = (scores_of or {})[str(run_dir)]
        if isinstance(result, Exception):
            raise result
        return result

    monkeypatch.setattr(me, "evaluate_mirror", evaluate)

    def load(path):
        if str(path).endswith("gone.npz"):
            raise BodyStudioError("gone")
        return str(path)

    monkeypatch.setattr(mi, "load_source_body", load)
    monkeypatch.setattr(mi, "source_fingerprint", lambda body: (fingerprints or {}).get(body))
    return asked


def _mirror_session(root, name, run_id=None, saved=None, source=None):
    """A folder the mirror section finds (session.json + kinect/player) and its stand-in view."""
    from types import SimpleNamespace

    path = root / name
    _write(path / "session.json")
    (path / "kinect" / "player").mkdir(parents=True)
    if saved is not None:
        _write(path / "mirror" / "eval.json", saved if isinstance(saved, str) else json.dumps(saved))
    run_dir = path / "mirror" / "run" if run_id is not None else None
    view = SimpleNamespace(session=SimpleNamespace(path=str(path)), run_dir=run_dir,
                           run=None if run_id is None else {"run": {"run_id": run_id}},
                           source_path=None if source is None else path / source, frame_ids=[2, 5])
    return str(path), view


def test_mirror_sections_strips_and_every_way_to_scores(monkeypatch, tmp_path):
    views = dict([
        _mirror_session(tmp_path, "a_saved", saved={"iou": 0.9, "psnr_person": float("inf")}),
        _mirror_session(tmp_path, "b_broken", saved="{nope"),
        _mirror_session(tmp_path, "c_list", saved="[1, 2]"),
        _mirror_session(tmp_path, "d_no_run"),
        _mirror_session(tmp_path, "e_scored", run_id="r1"),
        _mirror_session(tmp_path, "f_fails", run_id="r2"),
        _mirror_session(tmp_path, "g_stale", run_id="r3", saved={"run_id": "old", "iou": 0.1}),
        _mirror_session(tmp_path, "h_stale_fails", run_id="r4", saved={"run_id": "old"}),
        _mirror_session(tmp_path, "i_this_run", run_id="r5", saved={"run_id": "r5", "iou": 0.7}),
        _mirror_session(tmp_path, "j_this_body", run_id="r6", saved={"run_id": "r6", "source_fingerprint": "fp"},
                        source="body.npz"),
        _mirror_session(tmp_path, "k_other_body", run_id="r7", saved={"run_id": "r7", "source_fingerprint": "x"},
                        source="body.npz"),
        _mirror_session(tmp_path, "l_body_gone", run_id="r8", saved={"run_id": "r8", "source_fingerprint": "fp"},
                        source="gone.npz"),
        _mirror_session(tmp_path, "m_no_body_print", run_id="r9", saved={"run_id": "r9", "source_fingerprint": "fp"}),
    ])
    run = {str(Path(p) / "mirror" / "run"): v for p, v in [
        (tmp_path / "e_scored", {"iou": 0.8}), (tmp_path / "f_fails", BodyStudioError("no mask")),
        (tmp_path / "g_stale", {"iou": 0.6}), (tmp_path / "h_stale_fails", BodyStudioError("bad run")),
        (tmp_path / "k_other_body", {"iou": 0.5}), (tmp_path / "l_body_gone", {"iou": 0.4}),
        (tmp_path / "m_no_body_print", {"iou": 0.3})]}
    fingerprints = {str(tmp_path / "j_this_body" / "body.npz"): "fp", str(tmp_path / "k_other_body" / "body.npz"): "y"}
    asked = _mirror_stand_ins(monkeypatch, tmp_path, views, run, fingerprints)
    sections = {s.name: s for s in rp.mirror_sections(tmp_path)}
    assert list(sections) == sorted(sections) and len(sections) == 13
    assert asked == [rp.MIRROR_FRAMES] * 13 and rp.MIRROR_FRAMES == 3
    a = sections["a_saved"]
    assert [c for c, _ in a.strips] == ["a_saved frame 2", "a_saved frame 5"]
    for (_, png), fid in zip(a.strips, (2, 5), strict=True):
        assert np.array_equal(_decode(png), _strip(fid)[::2, ::2])
    assert (a.scores, a.note) == ({"iou": 0.9, "psnr_person": None, "psnr_person_identical": True}, None)
    saved = lambda name: tmp_path / name / "mirror" / "eval.json"  # noqa: E731
    b = sections["b_broken"]
    assert b.scores is None and b.note.startswith(f"{saved('b_broken')}: not valid JSON (Expecting")
    assert (sections["c_list"].scores, sections["c_list"].note) == (None, f"{saved('c_list')}: not a JSON object")
    assert sections["d_no_run"].scores is None
    assert sections["d_no_run"].note == "no mirror run yet (`bodystudio mirror run`)"
    assert (sections["e_scored"].scores, sections["e_scored"].note) == ({"iou": 0.8}, None)
    assert (sections["f_fails"].scores, sections["f_fails"].note) == (None, "not scored: no mask")
    assert sections["g_stale"].scores == {"iou": 0.6}
    assert sections["g_stale"].note == f"{saved('g_stale')} scores an earlier run or source body; scores recomputed"
    assert sections["h_stale_fails"].scores is None
    assert sections["h_stale_fails"].note == (f"{saved('h_stale_fails')} scores an earlier run or source body; "
                                              "not scored: bad run")
    assert (sections["i_this_run"].scores, sections["i_this_run"].note) == ({"run_id": "r5", "iou": 0.7}, None)
    assert sections["j_this_body"].scores == {"run_id": "r6", "source_fingerprint": "fp"}
    assert sections["j_this_body"].note is None
    for name, iou in (("k_other_body", 0.5), ("l_body_gone", 0.4), ("m_no_body_print", 0.3)):
        assert sections[name].scores == {"iou": iou}
        assert sections[name].note.endswith("scores an earlier run or source body; scores recomputed")


def test_scores_of_this_run_needs_the_run_id_and_the_source_fingerprint(monkeypatch, tmp_path):
    from types import SimpleNamespace

    _mirror_stand_ins(monkeypatch, tmp_path, {}, fingerprints={str(tmp_path / "b.npz"): "fp"})
    view = SimpleNamespace(run={"run": {"run_id": "r"}}, source_path=None)
    assert rp._scores_of_this_run({"run_id": "r"}, view)
    assert not rp._scores_of_this_run({"run_id": "r", "source_fingerprint": "fp"}, view)
    assert not rp._scores_of_this_run({"run_id": "q"}, view)
    assert not rp._scores_of_this_run({"run_id": None}, SimpleNamespace(run={"run": "r"}, source_path=None))
    assert not rp._scores_of_this_run({"run_id": None}, SimpleNamespace(run=None, source_path=None))
    assert rp._scores_of_this_run({"run_id": None}, SimpleNamespace(run={"run": {}}, source_path=None))
    body = SimpleNamespace(run={"run": {"run_id": "r"}}, source_path=tmp_path / "b.npz")
    assert rp._scores_of_this_run({"run_id": "r", "source_fingerprint": "fp"}, body)
    assert not rp._scores_of_this_run({"run_id": "r", "source_fingerprint": "other"}, body)
    assert not rp._scores_of_this_run({"run_id": "r", "source_fingerprint": None},
                                      SimpleNamespace(run={"run": {"run_id": "r"}}, source_path=tmp_path / "gone.npz"))


def test_mirror_views_of_a_run_folder_and_of_the_sessions_under_a_root(monkeypatch, tmp_path):
    import bodystudio.viewer.mirror as vm

    opened = []
    monkeypatch.setattr(vm, "open_mirror_view", lambda p: opened.append(p) or p)
    run = tmp_path / "run"
    _write(run / "run.json", json.dumps({"format": "bodystudio-mirror-run"}))
    assert rp._mirror_views(run) == [run]
    for name in ("s2", "s1", "plain"):
        _write(tmp_path / "r" / name / "session.json")
    for name in ("s2", "s1"):
        (tmp_path / "r" / name / "kinect" / "player").mkdir(parents=True)
    assert rp._mirror_views(tmp_path / "r") == [tmp_path / "r" / "s1", tmp_path / "r" / "s2"]


def test_strips_and_scores_html_shows_each_score_and_the_raw_json():
    strips = [("x frame 1", _png(_strip(1))), ("x frame <2>", _png(_strip(2)))]
    scores = {"iou": 0.912345, "per": {"a": 1, "b": None}, "label": "ok"}
    root = _page("\n".join(rp._strips_and_scores_html("x <s>", strips, scores, "eval mirror")))
    assert _stray_text(root) == []
    assert root.find_all("h3")[0].text() == "x <s>"
    figs = _figures(root)
    assert [(a, c) for a, _, c in figs] == [("x frame 1", "x frame 1"), ("x frame <2>", "x frame <2>")]
    assert np.array_equal(figs[1][1], _strip(2))
    (table,) = _tables(root)
    assert table == {"title": "x <s>: eval mirror", "columns": ["score", "value"],
                     "rows": [[("iou", "t"), ("0.9123", None)], [("per.a", "t"), ("1", None)],
                              [("per.b", "t"), ("None", None)], [("label", "t"), ("ok", "t")]]}
    (pre,) = root.find_all("pre")
    assert json.loads(pre.text()) == scores and pre.text() == json.dumps(scores, indent=2)
    assert root.find_all("summary")[0].text() == "eval JSON"
    bare = _page("\n".join(rp._strips_and_scores_html("y", [], None, "eval garment")))
    assert _tables(bare) == [] and bare.find_all("pre") == [] and bare.find_all("figure") == []
    with pytest.raises(ValueError):
        rp._strips_and_scores_html("z", [], {"a": float("nan")}, "eval")  # the page's JSON is strict


def test_mirror_and_garment_html_sections():
    m = [rp.MirrorSection("s1", [("s1 frame 1", _png(_strip(1)))], {"iou": 0.5}, "a <note>"),
         rp.MirrorSection("s2", [], None, None)]
    root = _page(rp._mirror_html(m))
    assert _stray_text(root) == []
    assert [h.text() for h in root.find_all("h2")] == ["Mirror: before / after"]
    assert [h.text() for h in root.find_all("h3")] == ["s1", "s1: eval mirror", "s2"]
    metas = [p.text() for p in root.find_all("p") if p.attrs.get("class") == "meta"]
    assert metas == ["Each strip: the Kinect input | the mirror's output | the truth (the actor rendered with the "
                     "edited body; synthetic sessions only).", "a <note>"]
    g = [rp.GarmentSection("f1", [("f1 frame 0", _png(_strip(0)))], {"psnr": 30.0}, ["n1 <x>", "n2"]),
         rp.GarmentSection("f2", [], None, [])]
    root = _page(rp._garment_html(g))
    assert _stray_text(root) == []
    assert [h.text() for h in root.find_all("h2")] == ["Garment: before / after"]
    assert [h.text() for h in root.find_all("h3")] == ["f1", "f1: eval garment", "f2"]
    notes = [p.text() for p in root.find_all("p") if p.attrs.get("class") == "meta garment-note"]
    assert notes == ["n1 <x>", "n2"]
    assert root.find_all("p")[0].text().startswith("Each strip: the input video frame | the composite of `garment "
                                                   "render` (the new garment on the fitted actor after the "
                                                   "image-space refinement) | the truth (the actor rendered wearing "
                                                   "the target garment; synthetic sessions only).")


# --- the garment section -------------------------------------------------------------------------------------------


def _garment_stand_ins(monkeypatch, now_ids=None, fit_result=None, composite_result=None):
    import bodystudio.garment.composite as gc
    import bodystudio.garment.evaluate as ge

    def result(value):
        def call(*args):
            if isinstance(value, Exception):
                raise value
            return dict(value)
        return call

    def run_ids(fit_dir):
        assert fit_dir.name == "fit"
        return dict(now_ids or {})

    def fit_errors(fit, session):
        assert (fit, session) == ("F", "s")
        return result(fit_result or {})()

    def composite_errors(fit_dir, session):
        assert (fit_dir.name, session) == ("fit", "s")
        return result(composite_result or {})()

    monkeypatch.setattr(ge, "scored_run_ids", run_ids)
    monkeypatch.setattr(ge, "fit_errors", fit_errors)
    monkeypatch.setattr(gc, "composite_errors", composite_errors)


def _gview(tmp_path, saved=None, session="s", render="r", **extra):
    from types import SimpleNamespace

    fit_dir = tmp_path / "fit" if tmp_path.name != "fit" else tmp_path
    return SimpleNamespace(saved_scores=saved, fit_dir=fit_dir, session=session, fit="F", render=render,
                           notes=extra.get("notes", []), has_source=extra.get("has_source", True),
                           frame_ids=extra.get("frame_ids", [0, 4]), strip_shape=extra.get("strip_shape", (6, 10, 3)))


def test_garment_scores_saved_recomputed_or_said_why_not(monkeypatch, tmp_path):
    _garment_stand_ins(monkeypatch, {"fit_run_id": "a", "render_run_id": "b"},
                       {"joint_mm": 3.0, "psnr": float("inf")}, {"composite_psnr": 31.0})
    saved = {"fit_run_id": "a", "render_run_id": "b", "psnr": float("inf"), "x": [float("nan"), 1.0]}
    assert rp.garment_scores(_gview(tmp_path, saved)) == (
        {"fit_run_id": "a", "render_run_id": "b", "psnr": None, "x": [None, 1.0]}, [])
    stale = {"fit_run_id": "old", "render_run_id": "b"}
    note = (f"{tmp_path / 'fit' / 'eval.json'} scores an earlier fit or render (or predates run ids); "
            "scores recomputed")
    assert rp.garment_scores(_gview(tmp_path, stale)) == (
        {"joint_mm": 3.0, "psnr": None, "composite_psnr": 31.0}, [note])
    assert rp.garment_scores(_gview(tmp_path, {"fit_run_id": "a"})) == (
        {"joint_mm": 3.0, "psnr": None, "composite_psnr": 31.0}, [note])
    assert rp.garment_scores(_gview(tmp_path, None, render=None)) == ({"joint_mm": 3.0, "psnr": None}, [])
    assert rp.garment_scores(_gview(tmp_path, stale, session=None)) == (None, [
        note, "not scored: the fit's source is not a session folder; `eval garment` needs a synthetic session "
              "(`bodystudio synth garment`)"])
    _garment_stand_ins(monkeypatch, {}, BodyStudioError("no truth"), BodyStudioError("no render"))
    assert rp.garment_scores(_gview(tmp_path)) == (None, ["fit not scored: no truth",
                                                          "composite not scored: no render"])
    assert rp.garment_scores(_gview(tmp_path, render=None)) == (None, ["fit not scored: no truth"])
    _garment_stand_ins(monkeypatch, {}, BodyStudioError("no truth"), {"c": 1.0})
    assert rp.garment_scores(_gview(tmp_path)) == ({"c": 1.0}, ["fit not scored: no truth"])


def test_garment_sections_strips_notes_and_scores(monkeypatch, tmp_path):
    import bodystudio.viewer.garment as vg

    _garment_stand_ins(monkeypatch, {}, {"joint_mm": 2.0})
    root = tmp_path / "root"
    for name in ("a_ok", "b_broken", "c_big", "d_no_frames", "e_gone"):
        _write(root / name / "fit.json")
    views = {"a_ok": _gview(root / "a_ok", notes=["view note"], frame_ids=[0, 4, 9]),
             "c_big": _gview(root / "c_big", frame_ids=[1], strip_shape=(480, 8, 3)),
             "d_no_frames": _gview(root / "d_no_frames", frame_ids=[3]),
             "e_gone": _gview(root / "e_gone", frame_ids=[3], has_source=False, notes=["source gone"])}
    asked = []

    def open_view(fit_dir):
        if fit_dir.name == "b_broken":
            raise BodyStudioError("damaged fit.json")
        return views[fit_dir.name]

    def frames(view, n):
        asked.append(n)
        return view.frame_ids

    def inputs(view, ids):
        if view.frame_ids == [3]:
            raise BodyStudioError("video unreadable")
        return {fid: f"frame {fid}" for fid in ids}

    def panels(view, fid, frames):
        if fid == 4:
            raise BodyStudioError("no render of frame 4")
        assert frames == ({} if view.frame_ids == [3] else {f: f"frame {f}" for f in view.frame_ids})
        return ["P"]

    def missing(view, fid, panel_list):
        assert panel_list == ["P"] and view in views.values()
        return {0: ["truth"], 9: ["truth", "input"]}.get(fid, [])

    monkeypatch.setattr(vg, "open_garment_view", open_view)
    monkeypatch.setattr(vg, "garment_frames", frames)
    monkeypatch.setattr(vg, "input_frames", inputs)
    monkeypatch.setattr(vg, "before_after_panels", panels)
    monkeypatch.setattr(vg, "missing_panels", missing)
    def strip(view, fid, frames):
        assert frames == ({} if view.frame_ids == [3] else {f: f"frame {f}" for f in view.frame_ids})
        return _strip(fid, view.strip_shape)

    monkeypatch.setattr(vg, "before_after_strip", strip)
    sections = rp.garment_sections(root)
    assert [s.name for s in sections] == ["a_ok", "b_broken", "c_big", "d_no_frames", "e_gone"]
    assert asked == [rp.GARMENT_FRAMES] * 4 and rp.GARMENT_FRAMES == 3
    a, b, c, d, e = sections
    assert [cap for cap, _ in a.strips] == ["a_ok frame 0", "a_ok frame 9"]
    assert np.array_equal(_decode(a.strips[1][1]), _strip(9))  # under 480 rows: every pixel
    assert a.notes == ["strips lack: truth; input", "view note", "frame 4: no render of frame 4"]
    assert a.scores == {"joint_mm": 2.0}
    assert (b.strips, b.scores, b.notes) == ([], None, ["not shown: damaged fit.json"])
    assert np.array_equal(_decode(c.strips[0][1]), _strip(1, (480, 8, 3))[::2, ::2])  # 480 rows: every 2nd
    assert c.notes == []
    assert d.notes == ["no input frames: video unreadable"] and len(d.strips) == 1
    assert e.notes == ["source gone"]  # a source that is gone is noted once, by the view
    assert views["a_ok"].notes == ["view note"]  # the view's own list is not changed


# --- the 3D view -----------------------------------------------------------------------------------------------------


class _Plotter:
    def __init__(self, name):
        self.name, self.closed = name, False

    def close(self):
        self.closed = True


def _scene_stand_ins(monkeypatch, kinds):
    """Stand-ins for the viewer's openers, builders and renderers; records what was built and rendered."""
    from types import SimpleNamespace

    import bodystudio.viewer.arm as va
    import bodystudio.viewer.views as vv

    calls = []
    monkeypatch.setattr(va, "is_arm_capture", lambda p: kinds.get(str(p)) == "arm")
    monkeypatch.setattr(va, "arm_payload", lambda data, plotter: {"arm": data, "plotter": plotter.name})
    monkeypatch.setattr(vv, "open_viewable", lambda p: SimpleNamespace(path=p, kind=kinds.get(str(p), "mesh"),
                                                                       data=f"data of {Path(p).name}"))

    def build(item):
        name = item.path if hasattr(item, "kind") else item  # an opened item, or a mesh's path
        calls.append(("build", str(name)))
        return _Plotter(str(name))

    monkeypatch.setattr(vv, "build_view", build)
    monkeypatch.setattr(vv, "session_payload", lambda data, plotter: {"session": data, "plotter": plotter.name})
    monkeypatch.setattr(rp, "render_image", lambda plotter: f"still of {plotter.name}")
    monkeypatch.setattr(rp, "scene_payload", lambda plotter: {"scene": plotter.name})
    monkeypatch.setattr(rp, "_garment_scene", lambda root: kinds.get(("garment", str(root))))
    return calls


def test_default_scene_picks_arm_garment_session_run_avatar_then_mesh(monkeypatch, tmp_path):
    kinds = {}
    calls = _scene_stand_ins(monkeypatch, kinds)
    arm = tmp_path / "arm"
    arm.mkdir()
    kinds[str(arm)] = "arm"
    plotter, payload, still = rp.default_scene(arm)
    assert (plotter.name, payload, still) == (str(arm), {"arm": "data of arm", "plotter": str(arm)}, f"still of {arm}")
    g = tmp_path / "g"
    g.mkdir()
    kinds[("garment", str(g))] = ("gp", {"garment": 1}, "gs")
    assert rp.default_scene(g) == ("gp", {"garment": 1}, "gs")
    sess = tmp_path / "sess"
    for name in ("b", "a"):
        _write(sess / name / "session.json")
    kinds[str(sess / "a")] = "session"
    plotter, payload, still = rp.default_scene(sess)
    assert (plotter.name, payload, still) == (str(sess / "a"), {"session": "data of a", "plotter": str(sess / "a")},
                                              f"still of {sess / 'a'}")
    run = tmp_path / "run"
    _write(run / "run.json")
    kinds[str(run)] = "mirror"
    plotter, payload, still = rp.default_scene(run)
    assert (plotter.name, payload, still) == (str(run), {"scene": str(run)}, f"still of {run}")
    meshes = tmp_path / "meshes"
    for rel in ("b.ply", "a.obj", "c.GLB", "notes.txt", "x/cam_0/z.ply"):
        _write(meshes / rel)
    kinds[str(meshes / "c.GLB")] = "avatar"
    kinds[str(meshes / "x" / "cam_0" / "z.ply")] = "avatar"  # inside a camera stream: never picked
    plotter, payload, still = rp.default_scene(meshes)
    assert (plotter.name, payload, still) == (str(meshes / "c.GLB"), {"scene": str(meshes / "c.GLB")},
                                              f"still of {meshes / 'c.GLB'}")
    del kinds[str(meshes / "c.GLB")]
    assert rp.default_scene(meshes)[0].name == str(meshes / "a.obj")
    empty = tmp_path / "empty"
    _write(empty / "x.txt")
    _write(empty / "kinect" / "y.ply")
    assert rp.default_scene(empty) is None
    other = tmp_path / "other_session"
    _write(other / "s" / "session.json")
    kinds[str(other / "s")] = "garment"  # a session folder that opens as neither session nor mirror: meshes next
    _write(other / "m.ply")
    assert rp.default_scene(other)[0].name == str(other / "m.ply")
    assert ("build", str(other / "s")) not in calls


def test_garment_scene_is_the_first_fit_that_opens(monkeypatch, tmp_path, caplog):
    import logging

    import bodystudio.viewer.garment as vg
    import bodystudio.viewer.scene as vs

    for name in ("a", "b", "c"):
        _write(tmp_path / name / "fit.json")
    made = []

    def open_view(fit_dir):
        if fit_dir.name == "a":
            raise BodyStudioError("damaged")
        return f"view {fit_dir.name}"

    monkeypatch.setattr(vg, "open_garment_view", open_view)
    monkeypatch.setattr(vg, "dress_fitted_body", lambda view: f"dressed {view}")
    monkeypatch.setattr(vs, "make_plotter", lambda: made.append(1) or _Plotter("p"))

    def scene(view, plotter, dressed):
        plotter.name = f"{view} / {dressed}"
        return plotter

    monkeypatch.setattr(vg, "scene_for_garment", scene)
    monkeypatch.setattr(vg, "garment_payload", lambda view, plotter, dressed: {"v": view, "d": dressed,
                                                                              "p": plotter.name})
    monkeypatch.setattr(rp, "render_image", lambda plotter: f"still {plotter.name}")
    with caplog.at_level(logging.WARNING, logger="bodystudio.viewer.report"):
        plotter, payload, still = rp._garment_scene(tmp_path)
    assert plotter.name == "view b / dressed view b" and still == "still view b / dressed view b"
    assert payload == {"v": "view b", "d": "dressed view b", "p": plotter.name} and len(made) == 1
    assert [r.getMessage() for r in caplog.records] == [f"{tmp_path / 'a'}: no 3D view of the garment fit (damaged)"]
    assert rp._garment_scene(tmp_path / "a") is None


# --- the whole page ----------------------------------------------------------------------------------------------


def _report_folder(tmp_path):
    from bodystudio.fileio import write_json

    root = tmp_path / "run <x>"
    write_json(root / "calib" / "report.json", {"reproj_rms_px": 0.3141592, "cameras": {
        "c0": {"rms_px": 0.25, "n": 10}, "c1": {"rms_px": 0.5, "n": 12}}, "reproj": {"c0": 0.25, "c1": 0.5}})
    write_json(root / "rig" / "eval.json", {"energy_history": [9.0, 3.0, 1.0], "joint_error_mm": 12.5})
    (root / "bad.json").write_text("{nope")
    (root / "shots").mkdir()
    (root / "shots" / "b.png").write_bytes(_png(_strip(11)))
    (root / "shots" / "a.png").write_bytes(_png(_strip(10)))
    return root


def _sections(monkeypatch, mirrors=(), garments=()):
    seen = []
    monkeypatch.setattr(rp, "mirror_sections", lambda root: seen.append(("mirror", root)) or list(mirrors))
    monkeypatch.setattr(rp, "garment_sections", lambda root: seen.append(("garment", root)) or list(garments))
    return seen


def test_write_report_page_holds_each_section_in_order_with_the_inputs_numbers(monkeypatch, tmp_path, caplog):
    import logging
    import time

    root = _report_folder(tmp_path)
    monkeypatch.setenv("TZ", "Asia/Kolkata")  # the stamp says UTC: local time must not leak in
    time.tzset()
    mirrors = [rp.MirrorSection("ms", [("ms frame 1", _png(_strip(1)))], {"iou": 0.75}, None)]
    garments = [rp.GarmentSection("gs", [("gs frame 2", _png(_strip(2)))], None, ["g note"])]
    seen = _sections(monkeypatch, mirrors, garments)
    payload = {"objects": [], "camera": {}, "colorBars": []}
    out = tmp_path / "page.HTML"
    handed = []
    monkeypatch.setattr(rp, "scene_payload", lambda plotter: handed.append(plotter) or {"objects": [{"name": "p"}]})
    plotter = _Plotter("given")
    try:
        with caplog.at_level(logging.INFO, logger="bodystudio.viewer.report"):
            result = rp.write_report(root, out, scenes=[("", payload), ("second <view>", plotter)],
                                     notes=["stage <a> ran", "stage b"], title="My <report>")
    finally:
        monkeypatch.delenv("TZ")
        time.tzset()
    assert handed == [plotter]
    messages = [(r.levelname, r.getMessage()) for r in caplog.records]
    assert messages[0][0] == "WARNING" and messages[0][1].startswith(
        f"{root / 'bad.json'}: skipped, not valid JSON (Expecting property name enclosed in double quotes")
    assert messages[-1] == ("INFO", f"wrote {out}")
    assert seen == [("mirror", root), ("garment", root)]
    text = out.read_text()
    page = _page(text)
    assert _stray_text(page.find_all("body")[0]) == []
    assert page.find_all("title")[0].text() == "My <report>" and page.find_all("h1")[0].text() == "My <report>"
    meta = [p.text() for p in page.find_all("p") if p.attrs.get("class") == "meta"][0]
    m = re.fullmatch(re.escape(str(root.resolve())) + r" \u00b7 (\d{4}-\d\d-\d\d \d\d:\d\d) UTC", meta)
    import datetime as dt

    stamp = dt.datetime.strptime(m.group(1), "%Y-%m-%d %H:%M").replace(tzinfo=dt.UTC)
    assert abs((dt.datetime.now(dt.UTC) - stamp).total_seconds()) < 120  # UTC, not local time
    assert [li.text() for li in page.find_all("li")] == ["stage <a> ran", "stage b"]
    assert [h.text() for h in page.find_all("h2")] == ["3D view", "Mirror: before / after", "Garment: before / after",
                                                       "Screenshots", "Plots", "Metrics"]
    assert [c.attrs["id"] for c in page.find_all("canvas")] == ["view3d_0", "view3d_1"]
    assert [h.text() for h in page.find_all("h3")][0] == "second <view>"  # the first view has no caption
    data = {s.attrs.get("id"): s.text() for s in page.find_all("script") if s.attrs.get("id")}
    assert json.loads(data["view3d_0-data"])["objects"] == []
    assert json.loads(data["view3d_1-data"])["objects"] == [{"name": "p"}]
    from bodystudio.viewer.webgl import VIEWER_CSS

    assert page.find_all("style")[0].text() == VIEWER_CSS + rp.REPORT_CSS
    figs = _figures(page)
    caps = [c for _, _, c in figs]
    assert caps[:4] == ["ms frame 1", "gs frame 2", "shots/a.png", "shots/b.png"]
    assert np.array_equal(figs[2][1], _strip(10)) and np.array_equal(figs[3][1], _strip(11))
    assert caps[4:] == ["Calibration residuals (calib/report.json: reproj)",
                        "Solver convergence (rig/eval.json: energy_history)"] and figs[4][0] == caps[4]
    assert figs[4][1].shape[:2] == (360, 640)
    tables = {t["title"]: t for t in _tables(page)}
    assert tables["calib/report.json"]["rows"] == [[("reproj_rms_px", "t"), ("0.3142", None)]]
    assert tables["calib/report.json / reproj"]["rows"] == [[("c0", "t"), ("0.25", None)], [("c1", "t"), ("0.5", None)]]
    assert tables["calib/report.json / cameras"]["rows"] == [[("c0", "t"), ("0.25", None), ("10", None)],
                                                             [("c1", "t"), ("0.5", None), ("12", None)]]
    assert tables["rig/eval.json"]["rows"] == [[("energy_history (n=3)", "t"), ("mean 4.333, min 1, max 9", "t")],
                                               [("joint_error_mm", "t"), ("12.5", None)]]
    assert tables["ms: eval mirror"]["rows"] == [[("iou", "t"), ("0.75", None)]]
    assert result.path == out and result.has_3d and result.mirrors == mirrors and result.garments == garments
    assert [t.title for t in result.tables] == ["calib/report.json", "calib/report.json / cameras",
                                                "calib/report.json / reproj", "rig/eval.json"]
    assert [p.title for p in result.plots] == caps[4:]
    assert [n for n, _ in result.screenshots] == ["shots/a.png", "shots/b.png"]
    assert text.endswith("</body></html>\n") and text.startswith("<!DOCTYPE html>")
    assert not list(tmp_path.glob(".*")) and not list(tmp_path.glob("*.tmp*"))  # written atomically


def test_write_report_default_scene_still_only_without_screenshots(monkeypatch, tmp_path):
    _sections(monkeypatch)
    plotters = []

    def scene(root):
        assert root == tmp_path / "r"
        plotters.append(_Plotter("p"))
        return plotters[-1], {"objects": [{"name": "body"}]}, _strip(7)

    monkeypatch.setattr(rp, "default_scene", scene)
    root = tmp_path / "r"
    _write(root / "m.json", json.dumps({"a": 1}))
    result = rp.write_report(root, tmp_path / "a.html")
    assert plotters[-1].closed and result.has_3d
    assert [n for n, _ in result.screenshots] == ["3D view (rendered)"]
    assert np.array_equal(_decode(result.screenshots[0][1]), _strip(7))
    page = _page((tmp_path / "a.html").read_text())
    assert [c for _, _, c in _figures(page)] == ["3D view (rendered)"]
    assert page.find_all("h1")[0].text() == "bodystudio report: r"
    assert page.find_all("h3")[0].text() == "m.json"  # no caption over the default view
    (root / "s.png").write_bytes(_png(_strip(3)))
    result = rp.write_report(root, tmp_path / "b.html")
    assert [n for n, _ in result.screenshots] == ["s.png"]
    result = rp.write_report(root, tmp_path / "c.html", with_3d=False)
    assert not result.has_3d and len(plotters) == 2 and "<canvas" not in (tmp_path / "c.html").read_text()
    monkeypatch.setattr(rp, "default_scene", lambda root: None)
    result = rp.write_report(root, tmp_path / "d.html")
    assert not result.has_3d and "3D view" not in [h.text() for h in _page((tmp_path / "d.html").read_text())
                                                   .find_all("h2")]


def test_write_report_refusals_and_an_empty_metrics_section(monkeypatch, tmp_path):
    _sections(monkeypatch)
    monkeypatch.setattr(rp, "default_scene", lambda root: None)
    with pytest.raises(InputError) as exc:
        rp.write_report(tmp_path / "nope", tmp_path / "r.html")
    assert str(exc.value) == (f"{tmp_path / 'nope'}: not a folder; give a run folder (e.g. the demo's output) or a "
                              "session folder")
    with pytest.raises(InputError) as exc:
        rp.write_report(tmp_path, tmp_path / "r.pdf")
    assert str(exc.value) == f"{tmp_path / 'r.pdf'}: the report is an HTML page; give a path ending in .html"
    empty = tmp_path / "empty"
    empty.mkdir()
    message = (f"{empty}: nothing to report (no metrics JSON, session, mirror or garment folder, screenshot or 3D "
               "scene under it); give a run folder or a session folder")
    with pytest.raises(InputError) as exc:
        rp.write_report(empty, tmp_path / "r.html")
    assert str(exc.value) == message
    with pytest.raises(InputError) as exc:
        rp.write_report(empty, tmp_path / "r.html", with_3d=False)
    assert str(exc.value) == message + " (or drop --no-3d: a mesh folder has only its 3D view)"
    assert not (tmp_path / "r.html").exists()
    result = rp.write_report(empty, tmp_path / "n.htm", notes=["only a note"])
    page = _page((tmp_path / "n.htm").read_text())
    assert [p.text() for p in page.find_all("p")][-1] == "No metrics JSON found under this folder."
    assert _stray_text(page) == []
    assert result.tables == [] and [li.text() for li in page.find_all("li")] == ["only a note"]
    (empty / "bad.json").write_text("[1, 2")  # a metrics file that does not parse still counts as found
    result = rp.write_report(empty, tmp_path / "m.html")
    assert result.tables == []


def test_write_report_reads_the_sessions_under_the_folder(monkeypatch, tmp_path):
    _sections(monkeypatch)
    monkeypatch.setattr(rp, "default_scene", lambda root: None)
    root = tmp_path / "root"
    for name in ("s1", "s2"):
        _write(root / name / "session.json")
    asked = []

    def figures(path):
        asked.append(path)
        return [rp.Plot(f"plot {path.name}", _png(_strip(4)))], [rp.Table(f"table {path.name}", ["a"], [[1.5]])]

    monkeypatch.setattr(rp, "session_figures", figures)
    result = rp.write_report(root, tmp_path / "r.html")
    assert asked == [root / "s1", root / "s2"]
    assert [p.title for p in result.plots] == ["plot s1", "plot s2"]
    assert [t["title"] for t in _tables(_page((tmp_path / "r.html").read_text()))] == ["table s1", "table s2"]


@pytest.mark.parametrize("only", ["shots", "garments", "mirrors", "plots", "tables"])
def test_write_report_needs_only_one_thing_to_show(monkeypatch, tmp_path, only):
    mirrors = [rp.MirrorSection("m", [], None, "no run")] if only == "mirrors" else []
    garments = [rp.GarmentSection("g", [], None, ["no fit"])] if only == "garments" else []
    _sections(monkeypatch, mirrors, garments)
    root = tmp_path / "r"
    root.mkdir()
    if only == "shots":
        (root / "a.png").write_bytes(_png(_strip(1)))
    if only in ("plots", "tables"):
        _write(root / "s" / "session.json")
        plot, table = rp.Plot("p", _png(_strip(2))), rp.Table("t", ["a"], [[1]])
        monkeypatch.setattr(rp, "session_figures", lambda p: ([plot], []) if only == "plots" else ([], [table]))
    result = rp.write_report(root, tmp_path / "r.html", with_3d=False)
    assert len(getattr(result, {"shots": "screenshots"}.get(only, only))) == 1
