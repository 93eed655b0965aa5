"""Analytic checks of §5 in garment/fit.py after the chromaticity materials and the L1 light penalty (b089271):
``_albedo_ratio``, the grouped ``estimate_appearance`` and ``clip_lighting``'s ``sparsity``.

Written for mutation testing (issue 17): a two-material ball (icosphere, 64 px) lit by one known light and
turned over four frames, no body model; each test a second or two. The grouped alternation is written out
step by step and compared to 1e-9, and its result is checked against the truth it is meant to find.
"""

import functools

import numpy as np

from bodystudio.garment import fit as gf
from bodystudio.garment import lighting as lt

TOP, BOTTOM = np.array([0.8, 0.5, 0.4]), np.array([0.3, 0.5, 0.7])


def ball_frames(n=4, size=64, light_dir=(0.4, 0.5, 1.0)):
    """A ball whose top half is one material and bottom half another, yawing over ``n`` frames (fresh copies of
    one rendering per process: mutation testing runs these tests once per mutant)."""
    images, masks, posed, F, cam, light, albedo = _ball_frames(n, size, tuple(light_dir))
    return ([i.copy() for i in images], [m.copy() for m in masks], [V.copy() for V in posed], F.copy(), cam, light,
            albedo.copy())


@functools.lru_cache(maxsize=4)
def _ball_frames(n, size, light_dir):
    """test_fit_analytic's two-material ball (albedo TOP above the equator, BOTTOM below), rendered once."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from test_fit_analytic import ball_frames as render_ball

    return render_ball(n, size, light_dir)


def test_albedo_ratio_sums_intensity_times_shading_per_vertex_or_per_group():
    """§5.1's least squares albedo ``sum_t I S / sum_t S^2``: the sums per vertex, or per material with the
    vertices labelled -1 left out."""
    images, _, posed, F, cam, light, _ = ball_frames(n=3)
    obs = lt.visible_vertex_colors(images, posed, F, cam)
    n = len(posed[0])
    num, den = gf._albedo_ratio(obs, posed, F, light, None, n)
    want_num, want_den = np.zeros((n, 3)), np.zeros((n, 3))
    for (ids, colors), V in zip(obs, posed, strict=True):
        S = lt.vertex_shading(V, F, light)
        for i, c in zip(ids, colors, strict=True):
            want_num[i] += c * S[i]
            want_den[i] += S[i] ** 2
    assert np.abs(num - want_num).max() < 1e-12 and np.abs(den - want_den).max() < 1e-12
    assert np.any(den > 0) and np.all(den[want_den == 0] == 0)
    labels = np.where(posed[0][:, 1] > 0, 0, 1)
    labels[::7] = -1  # left out
    labels[5] = 2  # a group of one vertex
    gnum, gden = gf._albedo_ratio(obs, posed, F, light, labels, 3)
    for g in range(3):
        assert np.abs(gnum[g] - want_num[labels == g].sum(0)).max() < 1e-12
        assert np.abs(gden[g] - want_den[labels == g].sum(0)).max() < 1e-12
    assert gnum.shape == gden.shape == (3, 3)
    # with the true lights the ratio of a rendered material is its albedo (the renderer is this shading model)
    top, bottom = gnum[0] / gden[0], gnum[1] / gden[1]
    assert np.abs(top - TOP).max() < 0.02 and np.abs(bottom - BOTTOM).max() < 0.02


def grouped_reference(images, masks, posed, F, cam, iterations, clip):
    """estimate_appearance(grouped=True) written out: mean colour, materials, lights, rounds, per-vertex end.
    ``clip(albedo)`` gives the clip's lights for an albedo."""
    pick = np.unique(np.linspace(0, len(images) - 1, min(8, len(images))).round().astype(int))
    imgs, Vs = [images[i] for i in pick], [posed[i] for i in pick]
    albedo, count = lt.estimate_albedo(imgs, Vs, F, cam)
    seen = count > 0
    anchor = albedo[seen].mean(0)
    obs = lt.visible_vertex_colors(imgs, Vs, F, cam)
    labels = lt.chromaticity_groups(albedo, seen)
    G = labels.max() + 1
    material = np.stack([albedo[labels == g].mean(0) for g in range(G)])
    albedo[seen] = material[labels[seen]]
    passed = [albedo.copy()]
    lighting = clip(albedo)
    for _ in range(iterations):
        num, den = np.zeros((G, 3)), np.zeros((G, 3))
        for (ids, colors), V in zip(obs, Vs, strict=True):
            S = lt.vertex_shading(V, F, lighting)[ids]
            for g in range(G):
                mine = labels[ids] == g
                num[g] += (colors[mine] * S[mine]).sum(0)
                den[g] += (S[mine] ** 2).sum(0)
        material = num / den
        albedo[seen] = material[labels[seen]]
        albedo = np.clip(albedo * anchor / albedo[seen].mean(0), 0.0, None)
        passed.append(albedo.copy())
        lighting = clip(albedo)
    num, den = np.zeros_like(albedo), np.zeros_like(albedo)
    for (ids, colors), V in zip(obs, Vs, strict=True):
        S = lt.vertex_shading(V, F, lighting)[ids]
        num[ids] += colors * S
        den[ids] += S * S
    ok = seen & np.all(den > 1e-12, axis=1)
    albedo[ok] = num[ok] / den[ok]
    return albedo, passed, labels, seen


def spied(monkeypatch, samples=300):
    """clip_lighting at ``samples`` rows per frame, recording (albedo, keywords, lights) of each call."""
    calls = []
    real = gf.clip_lighting

    def spy(imgs, ms, Vs, F_, camera, a, **kw):
        out = real(imgs, ms, Vs, F_, camera, a, samples_per_frame=samples, **kw)
        calls.append((a.copy(), kw, out))
        return out

    monkeypatch.setattr(gf, "clip_lighting", spy)
    return calls


def test_grouped_appearance_is_materials_then_lights_then_per_vertex_albedo(monkeypatch):
    """Each round: lights for one albedo per material, the material albedo ``sum I S / sum S^2`` over its
    vertices and frames, rescaled to the mean colour's mean; the per-vertex albedo with the final lights.
    (The reference reuses the lights the function solved: NNLS's active set can flip on a 1e-15 change.)"""
    images, masks, posed, F, cam, light, true_albedo = ball_frames()
    calls = spied(monkeypatch)
    got, lighting = gf.estimate_appearance(np.stack(images), np.stack(masks), posed, F, cam, iterations=2)
    assert len(calls) == 3 and all(kw == {"sparsity": gf.LIGHT_SPARSITY} for _, kw, _ in calls)
    assert gf.LIGHT_SPARSITY == 1e-4 and lighting is calls[-1][2]
    lights = iter([out for _, _, out in calls])
    want, passed, labels, seen = grouped_reference(images, masks, posed, F, cam, 2, lambda a: next(lights))
    assert labels.max() + 1 == 2  # the two materials of the ball
    for (a, _, _), b in zip(calls, passed, strict=True):
        assert np.abs(a - b).max() < 1e-12
        for g in range(2):  # ONE albedo per material while the lights are solved
            assert np.ptp(a[labels == g], axis=0).max() < 1e-12
    assert np.abs(got - want).max() < 1e-12
    # and it finds the light: 8.0 degrees on this ball (the per-vertex alternation: 19.5, next test)
    d = lt.dominant_light_direction(lighting.directions, lighting.colors)
    assert np.degrees(np.arccos(np.clip(d @ light.directions[0], -1, 1))) < 11.0
    # the albedo up to one scale per channel (albedo and light share it): median spread 0.130 of the truth
    r = got[seen] / true_albedo[seen]
    assert np.median(np.abs(r / np.median(r, 0) - 1)) < 0.16


def test_per_vertex_alternation_loses_the_light_on_a_ball_that_barely_turns(monkeypatch):
    """grouped=False (the first version): 19.5 degrees with the penalty, 36.3 without, against 8.0 grouped."""
    images, masks, posed, F, cam, light, _ = ball_frames()
    spied(monkeypatch)
    for kw, floor in (({"grouped": False}, 15.0), ({"grouped": False, "sparsity": 0.0}, 25.0)):
        _, lighting = gf.estimate_appearance(np.stack(images), np.stack(masks), posed, F, cam, iterations=2, **kw)
        d = lt.dominant_light_direction(lighting.directions, lighting.colors)
        assert np.degrees(np.arccos(np.clip(d @ light.directions[0], -1, 1))) > floor, kw


def test_appearance_defaults_four_rounds_grouped_and_the_rounds_move_the_albedo(monkeypatch):
    images, masks, posed, F, cam, _, _ = ball_frames()
    calls = spied(monkeypatch)
    a4, _ = gf.estimate_appearance(np.stack(images), np.stack(masks), posed, F, cam)
    assert len(calls) == 5  # the first lights and four rounds
    mean_colour, count = lt.estimate_albedo(images, posed, F, cam)
    seen = count > 0
    labels = lt.chromaticity_groups(mean_colour, seen)
    for a, _, _ in calls:  # grouped by default: constant within each material
        assert all(np.ptp(a[labels == g], axis=0).max() < 1e-12 for g in range(labels.max() + 1))
    # the material albedo changes from round to round (the alternation does something) and keeps the mean
    # colour's mean over the seen vertices (the anchor of the shared scale)
    assert not np.allclose(calls[0][0], calls[1][0], atol=1e-3)
    for a, _, _ in calls[1:]:
        assert np.abs(a[seen].mean(0) - mean_colour[seen].mean(0)).max() < 1e-12
    calls.clear()
    a0, _ = gf.estimate_appearance(np.stack(images), np.stack(masks), posed, F, cam, iterations=0)
    assert len(calls) == 1 and not np.allclose(a0, a4, atol=1e-3)
    # unseen vertices keep the mean colour's fallback through the per-vertex end step
    assert np.array_equal(a0[~seen], mean_colour[~seen])


def test_clip_lighting_passes_its_sparsity_to_eq_7():
    images, masks, posed, F, cam, _, albedo = ball_frames(n=2)
    rows = [lt.surface_samples(img, V, F, cam, albedo, 300, 3, seed=k, pixel_mask=m)
            for k, (img, m, V) in enumerate(zip(images, masks, posed, strict=True))]
    P, N, A, B = (np.concatenate([r[i] for r in rows]) for i in range(4))
    axis = cam.center - np.mean([V.mean(0) for V in posed], axis=0)
    for s in (0.0, 1e-3):
        got = gf.clip_lighting(images, masks, posed, F, cam, albedo, samples_per_frame=300, sparsity=s)
        want = lt.estimate_lighting(P, N, A, B, axis / np.linalg.norm(axis), sparsity=s)
        assert np.array_equal(got.colors, want.colors) and np.array_equal(got.ambient, want.ambient)
    default = gf.clip_lighting(images, masks, posed, F, cam, albedo, samples_per_frame=300)
    penalised = gf.clip_lighting(images, masks, posed, F, cam, albedo, samples_per_frame=300, sparsity=1e-3)
    assert len(penalised.colors) < len(default.colors)


def test_grouped_rounds_step_by_step_with_stand_ins(monkeypatch):
    """Every step of the grouped alternation stood in, so each value is known: eight of twenty frames picked, one
    albedo per material for the lights, a material with little shading (den 0.5) still updated, one without any
    (den 0) kept, the scale anchored, the per-vertex end step only on seen vertices with shading, ``n_out`` the
    number of materials. The per-vertex path (grouped=False) the same way."""
    labels = np.array([0, 0, 0, 1, 1, -1])
    seen = labels >= 0
    albedo0 = np.array([[0.2, 0.3, 0.4], [0.4, 0.3, 0.2], [0.3, 0.3, 0.3], [0.6, 0.1, 0.1], [0.8, 0.3, 0.1],
                        [0.5, 0.5, 0.5]])
    calls = {"albedo_frames": [], "clip": [], "ratio": []}

    def estimate_albedo(imgs, Vs, F, camera):
        calls["albedo_frames"].append([int(i[0, 0, 0]) for i in imgs])
        return albedo0.copy(), seen.astype(int)

    def clip(imgs, ms, Vs, F, camera, a, sparsity):
        calls["clip"].append(a.copy())
        return f"light {len(calls['clip'])}"

    g_num = np.array([[0.3, 0.2, 0.1], [0.9, 0.9, 0.9]])
    g_den = np.array([[0.5, 0.5, 0.5], [0.0, 0.0, 0.0]])  # material 0: little shading; material 1: none
    v_num = np.arange(18, dtype=float).reshape(6, 3) / 10
    v_den = np.array([[1.0] * 3, [2.0] * 3, [0.0] * 3, [1.0] * 3, [4.0] * 3, [1.0] * 3])  # vertex 5 unseen, den > 0

    def ratio(obs, Vs, F, lighting, lab, n_out):
        calls["ratio"].append((lighting, None if lab is None else lab.copy(), n_out))
        return (g_num.copy(), g_den.copy()) if lab is not None else (v_num.copy(), v_den.copy())

    monkeypatch.setattr(lt, "estimate_albedo", estimate_albedo)
    monkeypatch.setattr(lt, "visible_vertex_colors", lambda *a, **k: [])
    monkeypatch.setattr(lt, "chromaticity_groups", lambda a, s: labels.copy())
    monkeypatch.setattr(gf, "clip_lighting", clip)
    monkeypatch.setattr(gf, "_albedo_ratio", ratio)
    images = np.stack([np.full((2, 2, 3), k, np.uint8) for k in range(20)])
    masks = np.ones((20, 2, 2), bool)
    posed = [np.zeros((6, 3))] * 20
    F = np.zeros((1, 3), int)
    got, light = gf.estimate_appearance(images, masks, posed, F, None, iterations=2)
    assert calls["albedo_frames"] == [[0, 3, 5, 8, 11, 14, 16, 19]]  # linspace(0, 19, 8) rounded
    anchor = albedo0[seen].mean(0)
    material = np.stack([albedo0[:3].mean(0), albedo0[3:5].mean(0)])
    want = albedo0.copy()
    want[seen] = material[labels[seen]]
    passed = [want.copy()]
    for _ in range(2):
        material[0] = g_num[0] / g_den[0]  # material 1 (den 0) keeps its value
        want[seen] = material[labels[seen]]
        want = np.clip(want * anchor / want[seen].mean(0), 0, None)
        material = np.stack([want[labels == g].mean(0) for g in range(2)])
        passed.append(want.copy())
    ok = seen & (v_den > 0).all(1)  # vertex 2 (no shading) and 5 (unseen) keep theirs
    want[ok] = v_num[ok] / v_den[ok]
    assert len(calls["clip"]) == 3 and all(np.abs(a - b).max() < 1e-15 for a, b in zip(calls["clip"], passed,
                                                                                          strict=True))
    assert np.abs(got - want).max() < 1e-15 and light == "light 3"
    assert [(lg, n) for lg, _, n in calls["ratio"]] == [("light 1", 2), ("light 2", 2), ("light 3", len(albedo0))]
    assert calls["ratio"][-1][1] is None and np.array_equal(calls["ratio"][0][1], labels)
    # the per-vertex path: each round the seen vertices with shading take num / den, then the anchor's scale
    for key in calls:
        calls[key].clear()
    got, _ = gf.estimate_appearance(images, masks, posed, F, None, iterations=1, grouped=False)
    want = albedo0.copy()
    want[ok] = v_num[ok] / v_den[ok]
    want = np.clip(want * anchor / want[seen].mean(0), 0, None)
    assert np.abs(got - want).max() < 1e-15 and len(calls["clip"]) == 2
    assert [(n, lab) for _, lab, n in calls["ratio"]] == [(6, None)]
