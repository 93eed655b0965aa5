"""Capture stage: rasteriser throughput (numba z-buffer vs VTK offscreen) and Kinect simulation cost."""

from __future__ import annotations

import itertools
import os
import time

import numpy as np

from benchmarks.timing import markdown_table, median_seconds


def _median_cpu_seconds(fn, repeats: int = 5) -> float:
    """Median process CPU seconds of ``fn()``: the figure an idle core would give on this shared machine."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return float(np.median(times))


def _vtk_renderer(V, F, camera):
    """A pyvista/VTK offscreen renderer set up with ``camera``'s pinhole (no distortion); None if unavailable."""
    try:
        import pyvista as pv
    except ImportError:
        return None
    mesh = pv.PolyData(V.copy(), np.c_[np.full(len(F), 3), F].ravel())
    plotter = pv.Plotter(off_screen=True, window_size=(camera.width, camera.height))
    plotter.add_mesh(mesh, color=(0.87, 0.68, 0.57))
    eye = camera.center
    forward = camera.R[2]
    plotter.camera.position = tuple(eye)
    plotter.camera.focal_point = tuple(eye + forward)
    plotter.camera.up = tuple(-camera.R[1])
    plotter.camera.view_angle = float(np.degrees(2 * np.arctan(camera.height / 2 / camera.fy)))
    plotter.camera.clipping_range = (0.1, 10.0)

    def frame():
        mesh.points = V  # a new pose each frame
        plotter.render()
        img = plotter.screenshot(return_img=True)
        depth = plotter.get_image_depth()
        return img, depth

    try:
        frame()
    except Exception:  # no usable OpenGL context on this machine
        return None
    return frame, plotter


def run(quick: bool = False) -> str:
    from bodystudio.body import build_body
    from bodystudio.capture.kinect import simulate_kinect_depth
    from bodystudio.capture.render import background_plate, render, render_rgb, vertex_normals_area_weighted
    from bodystudio.geometry.camera import kinect_v1, ring_rig

    body = build_body(resolution="2k" if quick else "full")
    V, F = body.vertices, body.faces
    rig = ring_rig(10)
    render(V, F, rig[0])  # compile
    t_mask = median_seconds(lambda: [render(V, F, c) for c in rig])
    cpu_mask = _median_cpu_seconds(lambda: [render(V, F, c) for c in rig])
    results = [render(V, F, c) for c in rig]
    backgrounds = [background_plate(c, 0) for c in rig]

    def rgb_frame():
        normals = vertex_normals_area_weighted(V, F)  # once per frame, shared by the views
        return [render_rgb(V, F, c, background=b, result=r, normals=normals)
                for c, b, r in zip(rig, backgrounds, results, strict=True)]

    t_rgb = median_seconds(rgb_frame)
    cpu_rgb = _median_cpu_seconds(rgb_frame)
    seeds = itertools.count(100)  # fresh seeds: time the plate itself, not the cache
    t_bg = median_seconds(lambda: background_plate(rig[0], next(seeds)), repeats=5, warmup=0)
    rows = [["numba z-buffer: mask+depth+ids+barycentrics (incl. distorted projection)", 10, t_mask * 1e3,
             1.0 / t_mask, cpu_mask * 1e3, 1.0 / cpu_mask],
            ["numba z-buffer + Lambert RGB compositing", 10, (t_mask + t_rgb) * 1e3, 1.0 / (t_mask + t_rgb),
             (cpu_mask + cpu_rgb) * 1e3, 1.0 / (cpu_mask + cpu_rgb)]]
    vtk = _vtk_renderer(V, F, rig[0])
    if vtk is not None:
        frame, plotter = vtk
        t_vtk = median_seconds(frame)
        cpu_vtk = _median_cpu_seconds(frame)
        rows.append(["pyvista/VTK offscreen: RGB + depth buffer", 10, t_vtk * 10e3, 1.0 / (10 * t_vtk),
                     cpu_vtk * 10e3, 1.0 / (10 * cpu_vtk)])
        plotter.close()
        vtk_note = (f"VTK offscreen renders one 640x480 view in {t_vtk * 1e3:.1f} ms (software OpenGL here), "
                    f"{t_vtk / (t_mask / 10):.1f}x the numba rasteriser's time, so bodystudio keeps the numba one.")
    else:
        vtk_note = "pyvista/VTK offscreen rendering is unavailable on this machine; no comparison figure."
    sensor = kinect_v1("640x480")
    rng = np.random.default_rng(0)
    simulate_kinect_depth(V, F, sensor, rng)
    t_kinect = median_seconds(lambda: simulate_kinect_depth(V, F, sensor, rng))
    table = markdown_table(["renderer (640x480)", "views", "wall ms / 10 views", "frames/s (wall)",
                            "CPU ms / 10 views", "frames/s (CPU time)"], rows)
    return (f"## Capture: rendering and Kinect simulation\n\n"
            f"Body mesh: {len(V)} vertices, {len(F)} triangles; Rapid-Skin ring of 10 cameras at 640x480 "
            f"(`benchmarks/bench_capture.py`). Target: >= 10 frames/s for 10 views. Wall-clock figures "
            f"depend on how many other jobs share the 2 cores (load average {os.getloadavg()[0]:.1f} at the end "
            f"of this run); process CPU time is the single-core cost.\n\n{table}\n\n{vtk_note}\n\n"
            f"Background plate (one camera, first call; later calls hit the cache): {t_bg * 1e3:.0f} ms. "
            f"Kinect v1 depth frame (640x480, noise, quantisation, projector shadow, flying pixels, holes): "
            f"{t_kinect * 1e3:.1f} ms.\n")
