"""Atomic writes: all or nothing, normal permissions, JSON errors name the file."""

import os
import stat

import numpy as np
import pytest

from bodystudio.errors import FileFormatError
from bodystudio.fileio import atomic_path, atomic_write, read_json, write_json


def test_failed_write_leaves_the_previous_file(tmp_path):
    target = tmp_path / "a.json"
    write_json(target, {"v": 1})
    with pytest.raises(RuntimeError), atomic_write(target, "w") as f:
        f.write('{"v": 2')
        raise RuntimeError("killed midway")
    assert read_json(target) == {"v": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]  # no temp file left behind


def test_written_files_get_umask_permissions(tmp_path):
    old = os.umask(0o022)
    try:
        write_json(tmp_path / "a.json", {"x": np.arange(3)})
        with atomic_path(tmp_path / "b.npz") as tmp:
            np.savez(tmp, x=np.zeros(2))
    finally:
        os.umask(old)
    for name in ("a.json", "b.npz"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o644
    assert read_json(tmp_path / "a.json") == {"x": [0, 1, 2]}


def test_bad_json_names_the_file(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{nope")
    with pytest.raises(FileFormatError, match="bad.json: not a valid"):
        read_json(bad)
    with pytest.raises(FileFormatError, match="not found"):
        read_json(tmp_path / "missing.json")
