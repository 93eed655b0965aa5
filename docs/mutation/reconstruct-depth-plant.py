"""Plant bugs in reconstruct/depth.py's decorated functions (mutmut mutates none): the observation's
pass ``_observe`` and its ``_median9``, the association ``_depth_pairs``, the triangle cull ``_faces_touching``; each in
a scratch copy, and ``DepthObservation.n_points``; the depth files' fast tests run against each (mutJJ)."""
# usage (from the repository root): [PLANT_ONLY="name;name"] python docs/mutation/reconstruct-depth-plant.py [TEST_FILE ...]
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from plant import replay  # noqa: E402

P = "bodystudio/reconstruct/depth.py"
TESTS = sys.argv[1:] or ["tests/reconstruct/test_depth_observation_mutants.py", "tests/reconstruct/test_depth_compiled.py",
                         "tests/reconstruct/test_depth_reach_analytic.py"]
RANGE = "            if not np.isfinite(d) or not (d > lo and d < hi):"
WIN = "                    window[k] = e if np.isfinite(e) and e > lo and e < hi else 0.0"
XY = "            x, y = xy[r, c, 0] * d, xy[r, c, 1] * d"
PXYZ = "            px, py, pz = x - t[0], y - t[1], d - t[2]"
ROT = "                P[r, c, j] = px * R[0, j] + py * R[1, j] + pz * R[2, j]"
NB = "            if not (valid[r, c] and valid[r, c + 1] and valid[r, c - 1] and valid[r + 1, c] and valid[r - 1, c]):"
FLIP = ("            if nx * (center[0] - P[r, c, 0]) + ny * (center[1] - P[r, c, 1]) + nz * (center[2] - P[r, c, 2]) "
        "< 0:")
FACING = "        if not N[i, 0] * tx + N[i, 1] * ty + N[i, 2] * tz > 0.2 * np.sqrt(tx * tx + ty * ty + tz * tz):"
INSIDE = "        if c < 0 or c >= W or r < 0 or r >= H or not valid[r, c]:"
AGREE = ("        if not N[i, 0] * normals[r, c, 0] + N[i, 1] * normals[r, c, 1] + N[i, 2] * normals[r, c, 2] > "
         "min_normal_dot:")
NEAR = "        near = depth_m[r, c] > z[i] - occlusion_m and d < max_distance_m"
TY = "        for ty in range(y0 // _TILE, min(y1 // _TILE, th - 1) + 1):\n            for tx in range(x0 // _TILE, " \
     "min(x1 // _TILE, tw - 1) + 1):\n                if need[ty, tx]:\n                    keep[f] = True\n        # a kept"
mutants = [
    ("        return int(self.valid.sum())", "        return int(self.valid.size)", "n_points: every pixel"),
    (RANGE, RANGE.replace("d > lo", "d >= lo"), "observe: near bound inclusive"),
    (RANGE, RANGE.replace("d < hi", "d <= hi"), "observe: far bound inclusive"),
    (RANGE, "            if not (d > lo and d < hi):", "observe: NaN / inf not checked (comparison only)"),
    (WIN, "                    window[k] = e if np.isfinite(e) else 0.0", "median: out-of-range neighbours counted"),
    (WIN, "                    window[k] = e if np.isfinite(e) and e > lo and e < hi else d",
     "median: out-of-range neighbours as the pixel's own depth"),
    ("                rr = min(max(r + dr, 0), H - 1)", "                rr = (r + dr) % H", "median: rows wrap, not repeat"),
    ("                    cc = min(max(c + dc, 0), W - 1)", "                    cc = (c + dc) % W",
     "median: columns wrap, not repeat"),
    ("            if not abs(d - _median9(window)) < flying_m:", "            if not abs(d - _median9(window)) <= flying_m:",
     "flying: bound inclusive"),
    ("            if not abs(d - _median9(window)) < flying_m:", "            if False:", "flying: no flying-pixel test"),
    ("    return a[4]", "    return a[5]", "median9: the 6th smallest"),
    ("    for i in range(1, 9):", "    for i in range(1, 8):", "median9: last element not sorted in"),
    (XY, "            x, y = xy[r, c, 0] * d, xy[r, c, 1]", "unproject: y not times depth"),
    (XY, "            x, y = xy[r, c, 1] * d, xy[r, c, 0] * d", "unproject: x, y swapped"),
    (PXYZ, "            px, py, pz = x, y, d", "unproject: translation dropped"),
    (PXYZ, "            px, py, pz = x + t[0], y + t[1], d + t[2]", "unproject: translation added"),
    (ROT, "                P[r, c, j] = px * R[j, 0] + py * R[j, 1] + pz * R[j, 2]", "unproject: R for R^T"),
    ("            valid[r, c] = P[r, c, 1] >= floor_m", "            valid[r, c] = P[r, c, 2] >= floor_m",
     "floor: world z for y"),
    ("            valid[r, c] = P[r, c, 1] >= floor_m", "            valid[r, c] = True", "floor: no floor test"),
    (NB, NB.replace(" and valid[r - 1, c]):", "):"), "normals: the row above not required"),
    (NB, NB.replace("valid[r, c] and ", ""), "normals: the pixel itself not required"),
    (FLIP, FLIP.replace("< 0:", "> 0:"), "normals: facing away from the sensor"),
    (FLIP, "            if False:", "normals: never flipped"),
    ("            nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx",
     "            nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy + uy * vx", "normals: cross product's z"),
    ("    for r in numba.prange(1, H - 1):", "    for r in numba.prange(1, H - 2):", "normals: last inner row skipped"),
    ("            depth_out[r, c] = D[r, c]", "            depth_out[r, c] = P[r, c, 2]", "depth_out: world z for depth"),
    (FACING, FACING.replace("> 0.2 *", ">= 0.2 *"), "pairs: facing bound inclusive"),
    (FACING, FACING.replace("> 0.2 *", "> 0.0 *"), "pairs: any facing vertex"),
    (INSIDE, INSIDE.replace("c >= W", "c > W"), "pairs: column W read"),
    (INSIDE, INSIDE.replace("c < 0 or ", ""), "pairs: column -1 read"),
    (AGREE, "        if False:", "pairs: normal agreement dropped"),
    (NEAR, "        near = depth_m[r, c] > z[i] + occlusion_m and d < max_distance_m", "pairs: occlusion sign"),
    (NEAR, "        near = d < max_distance_m", "pairs: no occlusion test"),
    ("        if not near and not d < reach_m:", "        if not near and not d <= reach_m:", "pairs: reach inclusive"),
    ("        ids[m], rc[m, 0], rc[m, 1], dist[m], far[m] = i, r, c, d, not near",
     "        ids[m], rc[m, 0], rc[m, 1], dist[m], far[m] = i, c, r, d, not near", "pairs: (col, row) for (row, col)"),
    (TY, TY.replace("min(y1 // _TILE, th - 1) + 1)", "min(y1 // _TILE, th - 1))"), "cull: last tile row missed"),
    ("        if not (finite[a] and finite[b] and finite[c]):\n            continue\n        x0",
     "        if not (finite[a] and finite[b]):\n            continue\n        x0", "cull: third vertex's finiteness"),
    ("        x1 = min(max(box[a, 1], box[b, 1], box[c, 1]), width - 1)",
     "        x1 = min(max(box[a, 1], box[b, 1]), width - 1)", "cull: third vertex left out of the box"),
]

if __name__ == "__main__":
    only = [n for n in os.environ.get("PLANT_ONLY", "").split(";") if n]
    chosen = [m for m in mutants if not only or m[2] in only]
    sys.exit(0 if replay(P, chosen, TESTS, "/work/wt-mutJJ-work/depth-plant2") == len(chosen) else 1)
