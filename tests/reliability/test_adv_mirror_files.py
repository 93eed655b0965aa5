"""A mirror source body edited or damaged after ``mirror init`` (adversarial pass): NaN bone heads, tails or
rolls, or parents out of range, are refused with one line at load time; before, ``mirror run`` went on to a
LinAlgError traceback in the tracker (heads NaN) or tracked with a broken skeleton."""

import numpy as np
import pytest

from bodystudio.errors import FileFormatError
from bodystudio.mirror.init import SourceBody, load_source_body, refit_skeleton, save_source_body


@pytest.fixture(scope="module")
def source_file(tmp_path_factory):
    from bodystudio.body.statistical import load_statistical_model

    model = load_statistical_model("2k", progress=False)
    c = np.zeros(model.n_components)
    path = tmp_path_factory.mktemp("src") / "source_body.npz"
    save_source_body(path, SourceBody(c, model.vertices(c), refit_skeleton(model, c), (0,), 1.0))
    return path


def damaged(source_file, tmp_path, key, change):
    with np.load(source_file) as z:
        arrays = {k: z[k].copy() for k in z.files}
    change(arrays[key])
    path = tmp_path / "damaged.npz"
    np.savez(path, **arrays)
    return path


@pytest.mark.parametrize("key, change", [
    ("heads", lambda a: a.__setitem__(3, np.nan)),
    ("tails", lambda a: a.__setitem__(0, np.inf)),
    ("rolls", lambda a: a.__setitem__(1, np.nan)),
    ("parents", lambda a: a.__setitem__(2, 999)),
    ("parents", lambda a: a.__setitem__(2, -7)),
])
def test_damaged_skeleton_is_refused(source_file, tmp_path, key, change):
    path = damaged(source_file, tmp_path, key, change)
    with pytest.raises(FileFormatError, match="inconsistent or not finite; rerun 'bodystudio mirror init'"):
        load_source_body(path)


def test_the_undamaged_file_loads(source_file):
    assert np.all(np.isfinite(load_source_body(source_file).skeleton.heads))
