"""SilhouetteFields' transform pool across a fork (mutN): a child forked after the parent built fields on two
threads builds its own, the same arrays, instead of waiting on the parent's pool, whose threads it has not."""

import os
import signal

import numba
import numpy as np
import pytest

from bodystudio.geometry.camera import Camera
from bodystudio.reconstruct import tracking
from bodystudio.reconstruct.tracking import SilhouetteFields


@pytest.mark.skipif(not hasattr(os, "fork") or numba.config.NUMBA_NUM_THREADS < 2, reason="needs fork, 2 threads")
def test_fields_built_in_a_forked_child_do_not_wait_on_the_parents_pool():
    cams = [Camera.look_at(f"c{i}", (3 * np.sin(a), 0.4, 3 * np.cos(a)), (0, 0, 0), fx=300.0, width=80, height=60)
            for i, a in enumerate((0.0, 1.5, 3.0))]
    masks = {c.name: np.zeros((60, 80), bool) for c in cams}
    for k, c in enumerate(cams):
        masks[c.name][20:40, 30 + k:50] = True
    before = numba.get_num_threads()
    numba.set_num_threads(2)
    try:
        parent = SilhouetteFields(cams, masks, exact=False)
        assert tracking._FIELD_POOLS  # the parent's pool exists, with its threads
        pid = os.fork()
        if pid == 0:
            code = 1
            try:
                signal.alarm(20)
                child = SilhouetteFields(cams, masks, exact=False)
                code = 0 if np.array_equal(child._packed_sdf, parent._packed_sdf) else 2
            finally:
                os._exit(code)
        _, status = os.waitpid(pid, 0)
    finally:
        numba.set_num_threads(before)
    assert os.waitstatus_to_exitcode(status) == 0  # -14 (SIGALRM): the child waited on a pool with no thread


def test_one_named_pool_per_size_is_kept():
    """The transform pool of a size is made once and kept (not one leaked executor per frame), with that many
    workers, its threads named after the fields (what a profiler shows)."""
    pool = tracking._field_pool(2)
    assert tracking._field_pool(2) is pool and tracking._FIELD_POOLS[2] is pool
    assert pool._max_workers == 2 and pool._thread_name_prefix == "bodystudio-fields"
    assert tracking._field_pool(1) is not pool and tracking._field_pool(1)._max_workers == 1


def test_chamfer_fields_are_opencvs_mask_5_transform_inside_and_out():
    """``exact=False``: both transforms (the outside one and the inside core's) are OpenCV's 5x5 chamfer one,
    shifted by the half pixel, over the box of the default 48 px margin."""
    import cv2

    cam = Camera.look_at("c0", (0.0, 0.4, 3.0), (0, 0, 0), fx=300.0, width=160, height=120)
    mask = np.zeros((120, 160), bool)
    mask[30:90, 50:100] = True
    mask[40:50, 100:130] = True
    f = SilhouetteFields([cam], {"c0": mask}, exact=False)
    assert f.margin_px == 48.0
    x0, y0 = f.offset["c0"]
    assert (x0, y0) == (2, 0)  # the box 50..130 x 30..90 widened by 48 px, clipped to the image
    sdf = f.sdf["c0"]
    crop = mask[y0:y0 + sdf.shape[0], x0:x0 + sdf.shape[1]]
    out = cv2.distanceTransform((~crop).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5) - np.float32(0.5)
    np.testing.assert_array_equal(sdf[~crop], out[~crop])
    core = np.ascontiguousarray(mask[29:91, 49:131]).astype(np.uint8)  # the box and one pixel around
    inside = np.float32(0.5) - cv2.distanceTransform(core, cv2.DIST_L2, cv2.DIST_MASK_5)
    got = sdf[29 - y0:91 - y0, 49 - x0:131 - x0]
    np.testing.assert_array_equal(got[core.astype(bool)], inside[core.astype(bool)])


def test_each_views_field_is_its_box_of_the_packed_array():
    """Views of different boxes: each ``sdf`` is exactly its box (the packed array is padded to the largest)."""
    cams = [Camera.look_at(f"c{i}", (0.0, 0.4, 3.0), (0, 0, 0), fx=300.0, width=160, height=120) for i in range(2)]
    big, small = np.zeros((120, 160), bool), np.zeros((120, 160), bool)
    big[30:90, 50:130] = True
    small[50:60, 70:80] = True
    f = SilhouetteFields(cams, {"c0": big, "c1": small}, exact=False)
    assert f._packed_sdf.shape == (2, 120, 158)
    assert f.offset["c1"] == (22, 2) and f.sdf["c1"].shape == (106, 106)
    assert f.offset["c0"] == (2, 0) and f.sdf["c0"].shape == (120, 158)
    assert f.sdf["c1"].max() > 40 and f.sdf["c1"].min() < -4  # a field, not padding
