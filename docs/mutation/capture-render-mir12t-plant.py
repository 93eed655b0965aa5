"""Plant mir12t's mutants that mutmut cannot make (the numba kernel ``_drop_folded``, the ``lru_cache``d root finder,
the ``cached_property`` ``Camera.monotonic_radius``, the call sites) by hand in a scratch copy and run the fold tests."""
# usage (from the repository root): python docs/mutation/capture-render-mir12t-plant.py [TEST_FILE ...]
import os
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from plant import scratch_tree  # noqa: E402

work = "/work/wt-mutAA-work/render-fold-plant"
R, C = "bodystudio/capture/render.py", "bodystudio/geometry/camera.py"
K = "        beyond[i] = min(xc * xc + yc * yc - r2_max * zc * zc, zc)"
ROOTS = "    roots = np.roots([7.0 * k3, 5.0 * k2, 3.0 * k1, 1.0]) if (k1, k2, k3) != (0.0, 0.0, 0.0) else np.empty(0)"
U = "    u = [r.real for r in np.atleast_1d(roots) if abs(r.imag) <= 1e-12 * max(1.0, abs(r)) and r.real > 0.0]"
B = "        if beyond[i] > 0.0:\n"
RET = '    return float(np.sqrt(min(u))) if u else float("inf")'
mutants = [
    (R, K, "        beyond[i] = min(xc * xc + yc * yc - r2_max, zc)", "kernel: r2_max not times z^2"),
    (R, K, "        beyond[i] = min(xc * xc + yc * yc - r2_max * zc * zc, 1.0)", "kernel: z > 0 dropped (min with 1)"),
    (R, K, "        beyond[i] = min(xc * xc - r2_max * zc * zc, zc)", "kernel: y dropped"),
    (R, K, "        beyond[i] = min(xc * xc + yc * yc - r2_max * zc, zc)", "kernel: z not squared"),
    (R, K, "        beyond[i] = max(xc * xc + yc * yc - r2_max * zc * zc, zc)", "kernel: max for min"),
    (R, "        if beyond[i] > 0.0:", "        if beyond[i] >= 0.0:", "kernel: >= 0 (on the radius dropped)"),
    (R, "        if beyond[i] > 0.0:", "        if beyond[i] < 0.0:", "kernel: < 0"),
    (R, B + "            uvf[2 * i] = np.nan\n            uvf[2 * i + 1] = np.nan",
     B + "            uvf[2 * i] = np.nan\n            uvf[2 * i] = np.nan", "kernel: v kept"),
    (R, B + "            uvf[2 * i] = np.nan\n            uvf[2 * i + 1] = np.nan",
     B + "            uvf[2 * i + 1] = np.nan\n            uvf[2 * i + 1] = np.nan", "kernel: u kept"),
    (R, "    for i in range(n):\n        if beyond", "    for i in range(n - 1):\n        if beyond", "kernel: last vertex skipped"),
    (R, "        xc = r00 * X + r01 * Y + r02 * Z + t0", "        xc = r00 * X + r10 * Y + r02 * Z + t0", "kernel: R transposed entry"),
    (R, "        yc = r10 * X + r11 * Y + r12 * Z + t1", "        yc = r10 * X + r11 * Y + r12 * Z", "kernel: t1 dropped"),
    (R, "        zc = r20 * X + r21 * Y + r22 * Z + t2", "        zc = r20 * X + r21 * Y + r22 * Z + t1", "kernel: t1 for t2"),
    (R, "        X, Y, Z = Vf[3 * i], Vf[3 * i + 1], Vf[3 * i + 2]", "        X, Y, Z = Vf[3 * i], Vf[3 * i + 2], Vf[3 * i + 1]", "kernel: Y, Z swapped"),
    (R, "    n = Vf.shape[0] // 3", "    n = Vf.shape[0] // 3 - 1", "kernel: n one short"),
    (R, "    uv, z = _project_drawable(V, camera)\n    H, W = camera.height, camera.width\n    depth",
     "    uv, z = np.empty((len(V), 2)), np.empty(len(V))\n    _project(V, camera.R, camera.t, camera.K, camera.dist, uv, z)\n"
     "    H, W = camera.height, camera.width\n    depth", "render: plain _project"),
    (R, "    return _project_drawable(np.ascontiguousarray(V, dtype=np.float64), camera)",
     "    V = np.ascontiguousarray(V, dtype=np.float64)\n    uv, z = np.empty((len(V), 2)), np.empty(len(V))\n"
     "    _project(V, camera.R, camera.t, camera.K, camera.dist, uv, z)\n    return uv, z", "project_vertices: plain _project"),
    (C, ROOTS, ROOTS.replace("7.0 * k3", "6.0 * k3"), "roots: 6 k3"),
    (C, ROOTS, ROOTS.replace("7.0 * k3", "7.0 * k2"), "roots: k2 for k3"),
    (C, ROOTS, ROOTS.replace("5.0 * k2", "5.0 * k1"), "roots: k1 for k2"),
    (C, ROOTS, ROOTS.replace("3.0 * k1", "3.0 * k2"), "roots: k2 for k1"),
    (C, ROOTS, ROOTS.replace("1.0]", "-1.0]"), "roots: constant -1"),
    (C, ROOTS, ROOTS.replace("!=", "=="), "roots: guard inverted"),
    (C, ROOTS, ROOTS.replace("(k1, k2, k3) != (0.0, 0.0, 0.0)", "(k1, k2) != (0.0, 0.0)"), "roots: guard without k3"),
    (C, U, U.replace("abs(r.imag) <= 1e-12 * max(1.0, abs(r)) and ", ""), "roots: complex roots taken"),
    (C, U, U.replace("r.real > 0.0", "r.real < 0.0"), "roots: negative roots"),
    (C, U, U.replace("r.real > 0.0", "r.real > 1.5"), "roots: roots below 1.5 ignored"),
    (C, RET, RET.replace("min(u)", "max(u)"), "return: largest root"),
    (C, RET, RET.replace("np.sqrt(min(u))", "min(u)"), "return: u not r"),
    (C, RET, RET.replace('float("inf")', "0.0"), "return: 0 without a fold"),
    (C, "    return _radial_monotonic_radius(k1, k2, k3)", "    return _radial_monotonic_radius(k1, k2, 0.0)", "k3 not passed"),
    (C, "    k1, k2, _, _, k3 = (float(c)", "    k1, _, k2, _, k3 = (float(c)", "p1 read as k2"),
    (C, "    k1, k2, _, _, k3 = (float(c)", "    k1, k2, _, k3, _ = (float(c)", "p2 read as k3"),
    (C, "        return distortion_monotonic_radius(self.dist)", "        return distortion_monotonic_radius(np.zeros(5))", "Camera: lens ignored"),
    (C, "        return distortion_monotonic_radius(self.dist)", '        return float("inf")', "Camera: never folds"),
]
tests = sys.argv[1:] or ["tests/capture/test_render_fold_mutants.py", "tests/capture/test_render_fold.py"]
scratch_tree(work)
clean = {f: open(os.path.join(work, f)).read() for f in (R, C)}
env = {**os.environ, "PYTHONPATH": work, "NUMBA_CACHE_DIR": os.path.join(work, ".numba")}
killed = 0
for f, old, new, name in [(R, K, K, "clean")] + mutants:
    at = clean[f].index("def _drop_folded") if f == R and clean[f].count(old) > 1 else 0  # the kernel's own line
    head, tail = clean[f][:at], clean[f][at:]
    assert tail.count(old) >= 1 and (at or tail.count(old) == 1), name
    open(os.path.join(work, f), "w").write(head + tail.replace(old, new, 1))
    r = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *tests], cwd=work,
                       capture_output=True, text=True, env=env)
    first = next((ln for ln in r.stdout.splitlines() if ln.startswith("FAILED")), "")
    killed += bool(r.returncode) and name != "clean"
    print(f"{name}: {'killed' if r.returncode else 'survived'} {first[:150]}", flush=True)
    open(os.path.join(work, f), "w").write(clean[f])
print(f"{killed} / {len(mutants)} killed")
