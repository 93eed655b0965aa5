"""Body measurements: plausible values, invariants under scaling, closed-volume mass, bad input."""

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bodystudio.body import Phenotype, build_body
from bodystudio.body.measure import (
    BODY_DENSITY_KG_M3,
    body_mass,
    close_boundary_loops,
    enclosed_volume,
    has_boundary,
    horizontal_section_curves,
    landmark_vertices,
    measure_attributes,
    measure_body,
    torso_girth,
)
from bodystudio.errors import InputError


@pytest.fixture(scope="module")
def female_male():
    return (measure_body(build_body(Phenotype(gender=0.0), resolution="6k")),
            measure_body(build_body(Phenotype(gender=1.0), resolution="6k")))


def test_default_bodies_are_plausible(female_male):
    female, male = female_male
    for m in (female, male):
        assert 1.5 < m["stature_m"] < 1.9
        assert 45.0 < m["mass_kg"] < 90.0
        assert 0.75 < m["chest_m"] < 1.1
        assert 0.6 < m["waist_m"] < 0.9
        assert 0.85 < m["hip_m"] < 1.1
        assert m["waist_m"] < min(m["chest_m"], m["hip_m"])
        assert 0.40 < m["leg_length_m"] / m["stature_m"] < 0.52
        assert 0.28 < m["arm_length_m"] / m["stature_m"] < 0.38
        assert m["muscularity"] == 0.5
    assert male["stature_m"] > female["stature_m"] + 0.05
    assert male["mass_kg"] > female["mass_kg"]
    assert male["chest_m"] > female["chest_m"] and male["waist_m"] > female["waist_m"]


def test_stature_is_floor_to_crown(body_2k):
    m = measure_body(body_2k)
    assert m["stature_m"] == pytest.approx(body_2k.vertices[:, 1].max() - body_2k.vertices[:, 1].min())
    lifted = body_2k.vertices + [0.3, 0.5, -0.2]
    assert measure_attributes(lifted, body_2k.faces)["stature_m"] == pytest.approx(m["stature_m"])


@pytest.mark.parametrize("scale", [0.9, 1.1])
def test_measurements_scale_with_the_body(body_2k, scale):
    m = measure_body(body_2k)
    s = measure_attributes(body_2k.vertices * scale, body_2k.faces)
    for name in ("stature_m", "chest_m", "waist_m", "hip_m", "arm_length_m", "leg_length_m"):
        assert s[name] == pytest.approx(scale * m[name], rel=2e-3), name
    assert s["mass_kg"] == pytest.approx(scale ** 3 * m["mass_kg"], rel=1e-9)


def test_body_surface_is_closed_and_volume_positive(body_2k):
    V, F = close_boundary_loops(body_2k.vertices, body_2k.faces)
    assert not has_boundary(F)
    assert enclosed_volume(V, F) > 0.03


def test_holes_are_filled_watertight_with_nearly_the_same_volume(body_2k):
    V, F = body_2k.vertices, body_2k.faces
    # Cut two holes: the faces around the crown of the head and around one hand.
    top = np.argmax(V[:, 1])
    hand = np.argmax(V[:, 0])
    near = (np.linalg.norm(V - V[top], axis=1) < 0.03) | (np.linalg.norm(V - V[hand], axis=1) < 0.02)
    holed = F[~near[F].any(1)]
    assert has_boundary(holed)
    Vc, Fc = close_boundary_loops(V, holed)
    assert not has_boundary(Fc)
    import igl

    assert len(igl.boundary_loop_all(Fc)) == 0
    assert len(Vc) == len(V) + 2
    closed_mass = enclosed_volume(V, F) * BODY_DENSITY_KG_M3
    assert body_mass(V, holed) == pytest.approx(closed_mass, abs=0.15)
    # Without closing, the open surface's "volume" depends on the origin: translate and it changes.
    open_shift = enclosed_volume(V + 5.0, holed) - enclosed_volume(V, holed)
    assert abs(open_shift) * BODY_DENSITY_KG_M3 > 0.1
    assert body_mass(V + 5.0, holed) == pytest.approx(body_mass(V, holed), abs=1e-6)


def test_section_of_a_box_is_its_perimeter():
    import trimesh

    box = trimesh.creation.box(extents=(0.3, 1.0, 0.2))
    curves = horizontal_section_curves(np.asarray(box.vertices), np.asarray(box.faces), 0.1)
    assert len(curves) == 1
    assert torso_girth(np.asarray(box.vertices), np.asarray(box.faces), 0.1) == pytest.approx(1.0)


@settings(max_examples=15, deadline=None)
@given(st.floats(0.05, 0.4), st.floats(0.05, 0.4), st.floats(-0.2, 0.2))
def test_girth_of_a_cylinder_is_its_circumference(radius, offset, height):
    import trimesh

    cyl = trimesh.creation.cylinder(radius=radius, height=0.5, sections=256)
    V = np.asarray(cyl.vertices)[:, [0, 2, 1]] + [offset, 0.0, 0.0]  # axis along y
    girth = torso_girth(V, np.asarray(cyl.faces), height)
    assert girth == pytest.approx(2 * np.pi * radius, rel=1e-3)


def test_arm_section_is_not_counted_in_the_chest(body_2k):
    """The bust-level cut also crosses both arms; the girth is the torso's only."""
    L = landmark_vertices(body_2k.vertex_ids)
    h = body_2k.vertices[list(L.bust), 1].mean()
    curves = horizontal_section_curves(body_2k.vertices, body_2k.faces, h)
    assert len(curves) >= 3
    torso = max(curves, key=lambda p: np.ptp(p[:, 0]) * np.ptp(p[:, 1]))
    assert np.all(np.abs(torso[:, 0]) < 0.2)
    assert measure_body(body_2k)["chest_m"] < 1.2


def test_landmarks_follow_the_shape_across_templates():
    """The same landmarks measured on the full and 6k template agree within a few millimetres."""
    full = measure_body(build_body(Phenotype(gender=1.0, weight=0.8)))
    six = measure_body(build_body(Phenotype(gender=1.0, weight=0.8), resolution="6k"))
    for name in ("stature_m", "chest_m", "waist_m", "hip_m", "leg_length_m"):
        assert six[name] == pytest.approx(full[name], abs=5e-3), name
    assert six["arm_length_m"] == pytest.approx(full["arm_length_m"], abs=0.015)
    assert six["mass_kg"] == pytest.approx(full["mass_kg"], rel=5e-3)


def test_mesh_not_in_our_topology_is_rejected():
    V = np.random.default_rng(0).normal(size=(100, 3))
    with pytest.raises(InputError, match="13380"):
        measure_attributes(V, np.array([[0, 1, 2]]))
    with pytest.raises(InputError, match="6k template has 6002"):
        measure_attributes(V, np.array([[0, 1, 2]]), resolution="6k")
    with pytest.raises(InputError, match=r"\(n, 3\)"):
        measure_attributes(V[:, :2], np.array([[0, 1, 2]]))


def test_cli_measure(tmp_path, body_2k, capsys):
    import trimesh

    from bodystudio.cli.main import main
    from bodystudio.geometry.mesh import Mesh, save_mesh

    path = tmp_path / "body.ply"
    save_mesh(path, Mesh(body_2k.vertices, body_2k.faces))
    assert main(["body", "measure", str(path)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["stature_m"] == pytest.approx(measure_body(body_2k)["stature_m"], abs=1e-4)
    assert out["mass_kg"] == pytest.approx(measure_body(body_2k)["mass_kg"], abs=1e-3)
    bad = tmp_path / "cube.ply"
    trimesh.creation.box().export(bad)
    assert main(["body", "measure", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "cube.ply" in err and "13380" in err


def test_landmarks_sit_where_their_names_say(default_body):
    V = default_body.vertices
    L = landmark_vertices()
    assert abs(V[L.crotch, 0]) < 1e-6 and V[L.crotch, 1] < V[L.bust[0], 1]
    for left, right in (L.bust, L.acromion, L.elbow, L.wrist):
        assert V[left, 0] > 0.05 and V[right, 0] == pytest.approx(-V[left, 0], abs=1e-3)
    assert V[L.acromion[0], 1] > V[L.bust[0], 1] > V[L.wrist[0], 1]
    assert V[L.acromion[0], 1] > V[L.elbow[0], 1] > V[L.wrist[0], 1]
    assert V[L.bust[0], 2] > 0.1  # on the front of the chest


def test_cli_info_reports_default_body_attributes(capsys):
    from bodystudio.cli.main import main

    assert main(["body", "info"]) == 0
    attributes = json.loads(capsys.readouterr().out)["default_body"]["attributes"]
    assert 1.6 < attributes["stature_m"] < 1.7 and 45 < attributes["mass_kg"] < 70
