"""``benchmarks.muscle_extension_ceiling.rest_residual_parts``: the split of a rest residual into what a
depth capture sees (translation, normal part) and what it does not (tangential part), sixth pass."""

import numpy as np

from benchmarks.muscle_extension_ceiling import rest_residual_parts
from bodystudio.geometry.mesh import vertex_normals


def test_parts_sum_to_the_residual_and_split_along_the_normals(arm_model_2k):
    model = arm_model_2k
    V = model.base_vertices
    N = vertex_normals(V, model.faces)
    rng = np.random.default_rng(3)
    t = np.array([0.004, -0.007, -0.006])
    normal_offsets = rng.normal(0, 0.003, len(V))
    slide = np.cross(N, [0.0, 1.0, 0.0]) * 0.005  # along the skin
    r = t + normal_offsets[:, None] * N + slide
    p = rest_residual_parts(r, V, model.faces, model.arm_mask)
    np.testing.assert_allclose(p["translation"] + p["normal"] + p["tangential"], r, atol=1e-15)
    np.testing.assert_allclose(p["translation"], np.broadcast_to(r[model.arm_mask].mean(axis=0), r.shape))
    np.testing.assert_allclose((p["tangential"] * N).sum(axis=1), 0.0, atol=1e-15)
    np.testing.assert_allclose(np.cross(p["normal"], N), 0.0, atol=1e-15)
    # the planted fields come back once the translation (their mean) is accounted for
    x = r - p["translation"]
    np.testing.assert_allclose(p["normal"], (x * N).sum(axis=1, keepdims=True) * N, atol=1e-15)
    assert np.median(np.linalg.norm(p["tangential"], axis=1)) > 0.003  # the slide is not taken as normal


def test_a_translation_is_all_translation(arm_model_2k):
    model = arm_model_2k
    r = np.broadcast_to([0.01, -0.02, 0.005], model.base_vertices.shape)
    p = rest_residual_parts(r, model.base_vertices, model.faces, model.arm_mask)
    np.testing.assert_allclose(p["translation"], r, atol=1e-15)
    assert np.abs(p["normal"]).max() < 1e-15 and np.abs(p["tangential"]).max() < 1e-15


def test_the_extension_section_reports_the_point_to_surface_change():
    """The benchmark's extension table gains the held-out point-to-surface change (captures / truth meshes)."""
    from benchmarks.bench_muscle import extension_section

    def err(x):
        return {"median_mm": x}

    held = [{"seed": 611 + i, "set": "A", "label": "x", "gender": 0.0, "bmi": 17.0, "height_m": 1.6,
             "original": err(10.0), "captured": err(9.0), "truth": err(7.0), "original_regressed": err(10.0),
             "extended_regressed": err(9.0), "surface_mm": {"original": 4.0, "captured": 3.0, "truth": 2.0}}
            for i in range(2)]
    data = {"held": held, "added": [], "shape_range": {"bmi": (20, 28), "height_m": (1.7, 1.9)},
            "n_original": 10, "n_extended": 14, "centre": "sex"}
    text = extension_section(data)
    assert "captures / truth meshes: set A -25.0 % / -50.0 %." in text
    assert "mean change -10 %" in text
    del held[0]["surface_mm"]
    assert "point-to-surface" not in extension_section(data)


def test_the_extension_section_measures_the_linear_column_against_the_linear_original():
    """In the body form (eighth pass) the 'linear shape term' column is the change against the prepared (linear)
    model, the others against the body-form original; the section adds the body form against the linear original."""
    from benchmarks.bench_muscle import extension_section

    def err(x):
        return {"median_mm": x}

    held = [{"seed": 611 + i, "set": "A", "label": "x", "gender": 0.0, "bmi": 17.0, "height_m": 1.6,
             "original": err(10.0), "original_linear": err(8.0), "captured": err(6.0), "captured_linear": err(6.0),
             "truth": err(5.0), "original_regressed": err(10.0), "extended_regressed": err(9.0)} for i in range(2)]
    data = {"held": held, "added": [], "shape_range": {"bmi": (20, 28), "height_m": (1.7, 1.9)},
            "n_original": 10, "n_extended": 14, "centre": "sex", "shape_form": "body"}
    text = extension_section(data)
    assert "6.00 (-25 %)" in text and "6.00 (-40 %)" in text  # the linear column against 8, the body one against 10
    assert "mean change -40 %" in text
    assert "Against the prepared (linear) original model instead, the body-form extension from captures: set A " \
           "-25.0 % (8.00 -> 6.00 mm mean)." in text
    data["shape_form"] = "linear"
    assert "Against the prepared" not in extension_section(data)


def test_the_goal_line_gives_every_held_out_set_its_verdict():
    from benchmarks.bench_muscle import _other_sets_goal

    assert _other_sets_goal({("B", "captured"): [-20.0, -26.0]}) == " Set B (other seeds): -23 %: **not met**."
    assert _other_sets_goal({("B", "captured"): [-30.0, -34.0]}) == " Set B (other seeds): -32 %: met."
    assert _other_sets_goal({("A", "captured"): [-40.0]}) == ""
    # set D (twelfth pass) gets its verdict after B's
    assert _other_sets_goal({("D", "captured"): [-29.0, -33.0], ("B", "captured"): [-20.0]}) == \
        " Set B (other seeds): -20 %: **not met**. Set D (other seeds): -31 %: met."
