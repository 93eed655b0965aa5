"""``garment fit clips/a.mp4 --out fits/a`` recorded the source as given, relative to the working directory
of the fit (adversarial pass, round 2): ``garment render fits/a`` / ``eval garment`` / ``view`` from any other
directory then said "the fit's source video or session is gone" (or, had that directory held another
``clips/a.mp4``, only the fingerprint check stood between it and a render of the wrong clip). The fit now
records the absolute path."""

from __future__ import annotations

from pathlib import Path

from bodystudio.garment import fit as gf
from tests.garment.test_fit_analytic import stand_in_fit


def test_fit_records_the_source_as_an_absolute_path(tmp_path, monkeypatch):
    work = tmp_path / "work dir ü"  # a space and a non-ASCII letter on the way
    (work / "clips").mkdir(parents=True)
    monkeypatch.chdir(work)
    stand_in_fit(monkeypatch)
    fit = gf.fit_garment_video("clips/a.mp4", 1.72, Path("fits") / "a", template="6k", focal_px=80.0)
    assert Path(fit.source).is_absolute()
    monkeypatch.chdir(tmp_path)  # the render, eval and view of another day, from elsewhere
    assert Path(fit.source) == work / "clips" / "a.mp4"
