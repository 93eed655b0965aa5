"""Garment stage: Eq. 7 lighting solvers (scipy NNLS, fast NNLS, lstsq), self-shadowing, dressing, rendering."""

from __future__ import annotations

import os

import numpy as np

from benchmarks.timing import markdown_table, median_seconds


def cpu_seconds(fn, repeats: int = 3) -> float:
    """Median CPU seconds of ``fn()`` with one BLAS thread (wall time on the shared 2-core box is mostly load)."""
    import time

    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        fn()
        times = []
        for _ in range(repeats):
            t0 = time.process_time()
            fn()
            times.append(time.process_time() - t0)
    return float(np.median(times))


def lit_scene(shadows: bool, resolution: str = "6k"):
    """A posed body with a three-colour albedo under one known light + ambient, rendered at 480x640."""
    from bodystudio.body import Pose, build_body
    from bodystudio.garment.lighting import Lighting
    from bodystudio.garment.render import render_body
    from bodystudio.geometry.camera import Camera

    body = build_body(resolution=resolution)
    y = body.vertices[:, 1]
    albedo = np.tile([0.8, 0.6, 0.5], (body.n_vertices, 1))
    albedo[y < 0.9] = [0.3, 0.4, 0.7]
    albedo[(y > 0.95) & (y < 1.4)] = [0.7, 0.7, 0.7]
    rot = np.zeros((body.skeleton.n_bones, 3))
    rot[body.skeleton.index("upperarm_l")] = (0, 0, -0.4)
    rot[body.skeleton.index("lowerarm_r")] = (0.9, 0, 0)
    V, _ = body.pose(Pose(rot, np.zeros(3)))
    cam = Camera.look_at("front", (0.3, 1.2, 3.0), (0, 0.9, 0), fx=700, width=480, height=640)
    direction = np.array([0.5, 0.7, 0.5]) / np.linalg.norm([0.5, 0.7, 0.5])
    light = Lighting.single(direction, 0.8, 0.25)
    image, _ = render_body(V, body.faces, cam, light, albedo, shadows=shadows)
    return body, V, cam, light, albedo, np.clip(np.round(image * 255), 0, 255).astype(np.uint8)


def run(quick: bool = False) -> str:
    from bodystudio.garment.garments import dress
    from bodystudio.garment.lighting import (
        dominant_light_direction,
        estimate_lighting,
        golden_spiral_hemisphere,
        lambert_light_matrix,
        light_visibility,
        solve_lights,
        surface_samples,
    )
    from bodystudio.garment.render import render_garment

    rows = []
    for shadowed in (False, True):
        body, V, cam, light, albedo, image = lit_scene(shadowed)
        P, N, A, b = surface_samples(image, V, body.faces, cam, albedo)
        axis = cam.center - V.mean(0)
        axis /= np.linalg.norm(axis)
        D = golden_spiral_hemisphere(400, axis)
        t_vis = median_seconds(lambda P=P, N=N, D=D, V=V, body=body: light_visibility(P + 2e-3 * N, D, V, body.faces),
                               repeats=3)
        for solver in ("nnls", "fast_nnls", "lstsq"):
            for model_shadows in ((False, True) if solver != "lstsq" else (False,)):
                vis = light_visibility(P + 2e-3 * N, D, V, body.faces) if model_shadows else None
                G = lambert_light_matrix(N, D, vis)
                t = cpu_seconds(lambda G=G, solver=solver, A=A, b=b: solve_lights(G, A, b, solver))
                est = estimate_lighting(P, N, A, b, axis, shadows=model_shadows, mesh=(V, body.faces), solver=solver)
                try:
                    d = dominant_light_direction(est.directions, np.abs(est.colors))
                    err = float(np.degrees(np.arccos(np.clip(d @ light.directions[0], -1, 1))))
                except Exception:
                    err = float("nan")
                rows.append([f"{'shadowed' if shadowed else 'unshadowed'} render", solver,
                             "on" if model_shadows else "off", len(b), round(err, 2),
                             np.round(est.ambient, 3).tolist(), len(est.directions), round(1000 * t, 1)])
    G = lambert_light_matrix(N, D, None)
    x_ref = solve_lights(G, A, b, "nnls")
    x_fast = solve_lights(G, A, b, "fast_nnls")
    agree = float(np.abs(x_ref - x_fast).max())
    out = ["## garment lighting (Eq. 7)", "",
           "CPU times with one BLAS thread. One light (0.8, direction (0.5, 0.7, 0.5)) + ambient 0.25 on a posed "
           "6k body with a three-colour "
           "albedo, 480x640 front camera, 400 golden-spiral lights on the camera hemisphere + an ambient column; "
           f"up to 4000 pixel samples. Solve time is the 3 colour channels. Visibility rays (400 x samples, open3d): "
           f"{1000 * t_vis:.0f} ms. scipy NNLS vs fast NNLS: max light difference {agree:.2g}.", "",
           markdown_table(["scene", "solver", "self-shadowing", "samples", "dominant light err (deg)",
                           "ambient", "active lights", "solve CPU ms"], rows)]
    drows = []
    for name in ("tights", "skirt", "tshirt", "longsleeve"):
        t = median_seconds(lambda name=name: dress(body, name), repeats=3)
        g = dress(body, name)
        tr = median_seconds(lambda g=g: render_garment(V, body.faces, g, g.vertices, cam, light), repeats=3)
        drows.append([name, g.n_vertices, len(g.faces), round(1000 * t), round(1000 * tr)])
    out += ["", "Dressing (6k body, 512^2 texture) and rendering body + garment (480x640, no shadows):", "",
            markdown_table(["garment", "vertices", "faces", "dress ms", "render ms"], drows),
            "", f"_cpu count {os.cpu_count()}_"]
    return "\n".join(out)
