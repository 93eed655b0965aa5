"""``bodystudio report`` of a folder with nothing in it (adversarial pass): an empty page ('No metrics JSON
found') was written with exit 0, e.g. for a mistyped sub-folder or an arm capture with --no-3d. It is now a
one-line error naming the fix, and no page is written."""

from .conftest import run_bad


def test_report_of_an_empty_folder_is_refused(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    out = tmp_path / "r.html"
    run_bad(["report", tmp_path / "empty", "--out", out], capsys, "nothing to report")
    assert not out.exists()
    run_bad(["report", tmp_path / "empty", "--out", out, "--no-3d"], capsys, "drop --no-3d")
    assert not out.exists()
