"""Atomic writes: all or nothing, normal permissions, JSON errors name the file."""

import os
import stat
from pathlib import Path

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


def test_output_paths_are_checked_before_the_work(tmp_path):
    from bodystudio.errors import InputError
    from bodystudio.fileio import check_output_file, check_output_folder

    (tmp_path / "f").write_text("x")
    (tmp_path / "d.ply").mkdir()
    for bad, phrase in ((tmp_path / "f" / "a.ply", "is a file"), (tmp_path / "d.ply", "is a folder"),
                        (tmp_path / "a.txt", "unsupported output format"), (Path("/sys/a.ply"), "cannot write")):
        with pytest.raises(InputError, match=phrase):
            check_output_file(bad, "out", (".ply",))
    assert check_output_file(tmp_path / "new" / "deeper" / "a.ply", "out", (".ply",))
    assert not (tmp_path / "new").exists()  # the check creates nothing
    with pytest.raises(InputError, match="is a file"):
        check_output_folder(tmp_path / "f")
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    with pytest.raises(InputError, match="not empty"):
        check_output_folder(tmp_path / "full", new=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.ply", "f", "full"]  # no probe files left


def test_decoder_warnings_are_errors_naming_the_file(tmp_path, capfd):
    """A JPEG cut short decodes to an image with a grey bottom and a nameless libjpeg warning: refuse it."""
    import cv2

    from bodystudio.fileio import read_image

    y, x = np.mgrid[:120, :160]
    img = np.dstack([x * 1.5, y * 2, x + y]).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "ok.jpg"), img)
    data = (tmp_path / "ok.jpg").read_bytes()
    assert read_image(tmp_path / "ok.jpg").shape == (120, 160, 3)
    for fraction in (0.5, 0.9, 0.99):
        (tmp_path / "cut.jpg").write_bytes(data[: int(len(data) * fraction)])
        with pytest.raises(FileFormatError, match="cut.jpg"):
            read_image(tmp_path / "cut.jpg")
    assert "JPEG" not in capfd.readouterr().err  # the library's own line does not reach the terminal
    os.mkfifo(tmp_path / "pipe.png")
    with pytest.raises(FileFormatError, match="not a regular file"):
        read_image(tmp_path / "pipe.png")
