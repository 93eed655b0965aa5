"""The §7.1 flow gate's percentile (garment/refine.py ``flow_correction_is_significant``; issue 17 mutation row):
the 90th percentile of |D|, not a neighbouring one."""

import numpy as np

from bodystudio.garment.refine import flow_correction_is_significant


def test_the_gate_reads_the_90th_percentile_exactly():
    """100 garment pixels with |D| = 0, 0.02, ..., 1.98 px: numpy's 90th percentile is 1.782 px, the 91st 1.8018 px;
    a 1.79 px threshold lies between them."""
    field = np.zeros((10, 10, 2))
    field[..., 0] = (np.arange(100) / 50.0).reshape(10, 10)
    mask = np.ones((10, 10), bool)
    assert np.percentile(np.arange(100) / 50.0, 90) < 1.79 < np.percentile(np.arange(100) / 50.0, 91)
    assert not flow_correction_is_significant(field, mask, min_px=1.79)
    assert flow_correction_is_significant(field, mask, min_px=1.78)
    assert flow_correction_is_significant(field, mask, min_px=1.79, quantile=91.0)
