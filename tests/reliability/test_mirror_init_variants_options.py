"""``benchmarks/mirror_init_variants.py`` (mir12w): ``--shadow DIR --name NAME.npz`` writes source bodies into shadow
sessions, never into the session; the two options go together and the name must be a ``.npz``."""

import sys

import pytest

from benchmarks.mirror_init_variants import main, shadow_session


def _session(tmp_path):
    s = tmp_path / "S57"
    for d in ("calibration", "kinect", "gt", "mirror"):
        (s / d).mkdir(parents=True)
    (s / "session.json").write_text("{}")
    (s / "mirror" / "source_body.npz").write_bytes(b"body")
    (s / "mirror" / "source_body.json").write_text("{}")
    return s


def test_a_shadow_links_the_session_and_owns_its_mirror_folder(tmp_path):
    s = _session(tmp_path)
    before = sorted(p.relative_to(s) for p in s.rglob("*"))
    shadow = shadow_session(s, tmp_path / "shadows")
    assert shadow == tmp_path / "shadows" / "S57"
    for part in ("calibration", "kinect", "gt", "session.json"):
        assert (shadow / part).is_symlink() and (shadow / part).resolve() == (s / part).resolve()
    mirror = shadow / "mirror"
    assert mirror.is_dir() and not mirror.is_symlink()
    assert (mirror / "source_body.npz").read_bytes() == b"body"  # the session's own body, copied
    (mirror / "extra.npz").write_bytes(b"x")
    (mirror / "source_body.npz").write_bytes(b"changed")
    assert sorted(p.relative_to(s) for p in s.rglob("*")) == before  # nothing written into the session
    assert (s / "mirror" / "source_body.npz").read_bytes() == b"body"
    again = shadow_session(s, tmp_path / "shadows")  # a second call keeps what the shadow holds
    assert (again / "mirror" / "source_body.npz").read_bytes() == b"changed"


@pytest.mark.parametrize("args, phrase", [
    (["--shadow", "W"], "--shadow and --name go together"),
    (["--name", "x.npz"], "--shadow and --name go together"),
    (["--shadow", "W", "--name", "x.json"], "a source body is a .npz file"),
])
def test_bad_shadow_options_exit_2_before_any_work(tmp_path, monkeypatch, capsys, args, phrase):
    monkeypatch.setattr(sys, "argv", ["mirror_init_variants.py", str(tmp_path / "missing"), *args])
    with pytest.raises(SystemExit) as exc:
        main()
    assert exc.value.code == 2
    assert phrase in capsys.readouterr().err
    assert not (tmp_path / "W").exists()
