"""Body model: build and posing times per resolution, measurement, statistical model build, PCA error, edits."""

from __future__ import annotations

import time

import numpy as np

from benchmarks.timing import markdown_table, median_seconds


def _random_pose(n_bones: int, seed: int = 0):
    from bodystudio.body import Pose

    rng = np.random.default_rng(seed)
    return Pose(rotations=rng.normal(0, 0.3, (n_bones, 3)), translation=np.zeros(3))


def run(quick: bool = False) -> str:
    from bodystudio.body import Phenotype, build_body
    from bodystudio.body.measure import measure_body
    from bodystudio.body.population import sample_population
    from bodystudio.body.statistical import build_statistical_model, population_shapes

    resolutions = ("full", "6k", "2k")
    rows = []
    for res in resolutions:
        body = build_body(resolution=res)  # warms the asset, rig and template caches
        pose = _random_pose(body.skeleton.n_bones)
        shape = (Phenotype(gender=0.3, weight=0.7), {"upperarm-fat-decr-incr": 0.4})
        t_build = median_seconds(lambda res=res, shape=shape: build_body(*shape, resolution=res))
        t_lbs = median_seconds(lambda body=body, pose=pose: body.pose(pose, method="lbs"))
        t_dqs = median_seconds(lambda body=body, pose=pose: body.pose(pose, method="dqs"))
        t_measure = median_seconds(lambda body=body: measure_body(body))
        rows.append([res, body.n_vertices, len(body.faces), body.skeleton.n_bones, 1e3 * t_build, 1e3 * t_lbs,
                     1e3 * t_dqs, 1e3 * t_measure])
    out = ["## Body model (bench_body)", "",
           "`build_body` of a new shape (phenotype + local targets, skeleton, weights; asset caches warm), "
           "posing one random pose with linear-blend and dual-quaternion skinning, and `measure_body` "
           "(stature, closed-volume mass, 19 planar sections for chest/waist/hip, limb lengths). Milliseconds, "
           "medians of 5 runs.", "",
           markdown_table(["resolution", "vertices", "faces", "bones", "build ms", "LBS pose ms", "DQS pose ms",
                           "measure ms"], rows), ""]

    rows = []
    for gender, label in ((0.0, "female"), (1.0, "male"), (0.5, "neutral (MakeHuman default)")):
        m = measure_body(build_body(Phenotype(gender=gender)))
        rows.append([label, m["stature_m"], m["mass_kg"], m["chest_m"], m["waist_m"], m["hip_m"], m["arm_length_m"],
                     m["leg_length_m"]])
    out += ["Default bodies measured on the full mesh (`bodystudio body measure`):", "",
            markdown_table(["body", "stature m", "mass kg", "chest m", "waist m", "hip m", "arm m", "leg m"], rows), ""]

    # Statistical model: one build per resolution (too slow to repeat), then accuracy on held-out bodies.
    n_samples = 120 if quick else 300
    k_max = 20
    rows, err_rows, edit_rows = [], [], []
    for res in (("2k",) if quick else ("6k", "2k")):
        t0 = time.perf_counter()
        sm = build_statistical_model(res, n_components=k_max, n_samples=n_samples, progress=False)
        t_model = time.perf_counter() - t0
        rows.append([res, n_samples, k_max, t_model])
        held = list(population_shapes(sample_population(20, seed=20261121), sm.vertex_ids, sm.rig))
        basis = sm.basis.reshape(k_max, -1).T
        errs = []
        for k in (5, 10, 15, 20):
            e = []
            for V, _, _ in held:
                c, *_ = np.linalg.lstsq(basis[:, :k], (V - sm.mean).ravel(), rcond=None)
                e.append(np.linalg.norm((sm.mean.ravel() + basis[:, :k] @ c).reshape(-1, 3) - V, axis=1).mean())
            errs.append(1e3 * float(np.mean(e)))
        err_rows.append([res] + errs)
        starts = [sm.project(V) for V, _, _ in held[: (3 if quick else 8)]]
        for delta in ({"stature_m": 0.05}, {"mass_kg": 5.0}):
            name, amount = next(iter(delta.items()))
            got, others, times = [], [], []
            for c0 in starts:
                before = sm.measure(c0)
                t0 = time.perf_counter()
                c = sm.edit(c0, delta)
                times.append(time.perf_counter() - t0)
                after = sm.measure(c)
                got.append(after[name] - before[name] - amount)
                others.append(max(abs(after[n] - before[n]) for n in ("chest_m", "waist_m", "hip_m")))
            unit = 1e3 if name.endswith("_m") else 1.0
            edit_rows.append([res, f"{name} +{amount:g}", len(starts), unit * float(np.mean(np.abs(got))),
                              unit * float(np.max(np.abs(got))), 1e3 * float(np.max(others)),
                              float(np.median(times))])
    out += [f"Statistical model (`build_statistical_model`, {n_samples} seeded population bodies, joints stacked "
            "into the PCA; one timed build each):", "",
            markdown_table(["template", "bodies", "components", "build s"], rows), "",
            "Held-out PCA reconstruction (20 bodies, other seed), mean vertex error in mm:", "",
            markdown_table(["template", "k=5", "k=10", "k=15", "k=20"], err_rows), "",
            "Semantic edits `sm.edit(c, {...})` from held-out bodies (default 20-component model): error of the "
            "measured change (mm for stature, kg for mass), largest change of chest/waist/hip (mm), median seconds "
            "per edit:", "",
            markdown_table(["template", "edit", "bodies", "mean abs err", "max abs err", "max girth drift mm",
                            "s per edit"], edit_rows)]
    return "\n".join(out)
