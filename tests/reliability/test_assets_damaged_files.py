"""A damaged asset cache is named, never half-read (mutJJ's found-not-fixed items in body/assets.py).

A manifest whose ``files`` (or hashes / verification times) is a list crashed with an AttributeError instead of
reporting an unreadable manifest (which re-extracts the cache); a target row of another number of columns than
MakeHuman's four was read as its first four (five numbers) or failed in numpy's words (three).
"""

import json

import numpy as np
import pytest

from bodystudio.body import assets
from bodystudio.errors import AssetError


def _cache(tmp_path):
    folder = tmp_path / "cache"
    folder.mkdir()
    (folder / "a.txt").write_text("abc")
    return folder


@pytest.mark.parametrize("data", [
    {"files": ["a.txt"]},
    {"files": {"a.txt": 3}, "file_sha256": ["x"]},
    {"files": {"a.txt": 3}, "file_sha256": {"a.txt": "x"}, "verified_mtime_ns": [1]},
    {"files": "a.txt"},
])
def test_a_manifest_of_the_wrong_shape_is_unreadable_not_a_crash(tmp_path, data):
    folder = _cache(tmp_path)
    (folder / "MANIFEST.json").write_text(json.dumps(data))
    assert assets._cache_problem(folder) == "unreadable manifest"
    assert not assets._cache_is_complete(folder)


def test_a_manifest_of_the_right_shape_still_passes(tmp_path):
    folder = _cache(tmp_path)
    (folder / "MANIFEST.json").write_text(json.dumps({"files": {"a.txt": 3}}))
    assert assets._cache_problem(folder) is None


@pytest.mark.parametrize(("rows", "why"), [
    ("0 1.0 2.0 3.0 4.0\n1 1 1 1 1\n", "5 numbers a row"),
    ("0 1.0 2.0\n", "3 numbers a row"),
    ("0 1.0 2.0 3.0\n1 1.0 2.0\n", "the number of columns changed"),
])
def test_a_target_of_another_width_is_refused_naming_the_file(tmp_path, rows, why):
    path = tmp_path / "bad.target"
    path.write_text(rows)
    with pytest.raises(AssetError) as err:
        assets._read_target(path)
    line = str(err.value)
    assert "\n" not in line and str(path) in line and "not a MakeHuman target" in line and "make setup" in line
    assert why in line


def test_a_target_of_four_columns_is_read_as_written(tmp_path):
    path = tmp_path / "ok.target"
    path.write_text("# c\n0 1.0 2.0 3.0\n5 -0.5 0.25 10\n")
    np.testing.assert_array_equal(assets._read_target(path), [[0, 1.0, 2.0, 3.0], [5, -0.5, 0.25, 10]])
