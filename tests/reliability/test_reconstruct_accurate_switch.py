"""``bodystudio reconstruct --accurate`` (issue 15, rec15h): one switch for rec15g's accurate setting
(``bodystudio.reconstruct.presets``). It sets exactly the preset's keywords of ``reconstruct_session`` and
``RapidSkinParams`` fields, nothing else; the cluster path (which cannot track or smooth: a chunk lacks its
neighbours) refuses it in one line with exit 2 and writes nothing; so does a clashing ``--joint-smoothing``."""

from __future__ import annotations

import inspect
import shutil
from dataclasses import asdict

import pytest

from .conftest import run_inprocess


@pytest.mark.parametrize("extra", [["--workers", "2"], ["--scheduler", "tcp://127.0.0.1:1"], ["--chunk", "1"]])
def test_accurate_on_the_cluster_path_is_refused(studio, tmp_path, capfd, extra):
    session = shutil.copytree(studio.session, tmp_path / "S")
    result = run_inprocess(["reconstruct", session, "--accurate", *extra], capfd)
    assert result.crashed is None and result.rc == 2, result.text[-1500:]
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "--accurate" in lines[0], result.stderr
    assert "sequential path" in lines[0]
    assert not (session / "reconstruct").exists()


def test_accurate_on_the_cluster_from_the_environment_is_refused(studio, tmp_path, capfd, monkeypatch):
    from bodystudio.batch import ENV_SCHEDULER

    monkeypatch.setenv(ENV_SCHEDULER, "tcp://127.0.0.1:1")
    session = shutil.copytree(studio.session, tmp_path / "S")
    result = run_inprocess(["reconstruct", session, "--accurate"], capfd)
    assert result.rc == 2 and "--accurate" in result.stderr and ENV_SCHEDULER in result.stderr, result.text[-800:]
    assert not (session / "reconstruct").exists()


def test_accurate_with_another_joint_smoothing_is_refused(studio, tmp_path, capfd):
    session = shutil.copytree(studio.session, tmp_path / "S")
    result = run_inprocess(["reconstruct", session, "--accurate", "--joint-smoothing", "3"], capfd)
    assert result.rc == 2, result.text[-800:]
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "--joint-smoothing 3" in lines[0] and "--accurate" in lines[0], result.stderr
    assert not (session / "reconstruct").exists()


def _stub(monkeypatch) -> list[dict]:
    """Replace ``reconstruct_session`` (the CLI imports it from ``sequence`` at call time) by a recorder."""
    import bodystudio.reconstruct.sequence as sequence

    calls: list[dict] = []

    def fake(path, **kw):
        calls.append(kw)
        return {"median_mm": 1.0}

    monkeypatch.setattr(sequence, "reconstruct_session", fake)
    return calls


def _defaults() -> dict:
    from bodystudio.reconstruct.sequence import reconstruct_session

    return {k: p.default for k, p in inspect.signature(reconstruct_session).parameters.items()}


@pytest.mark.parametrize("joint_smoothing", [[], ["--joint-smoothing", "2"]])
def test_accurate_passes_exactly_the_preset(studio, tmp_path, capfd, monkeypatch, joint_smoothing):
    from bodystudio.reconstruct.presets import ACCURATE_PARAMS, ACCURATE_SETTINGS
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams

    defaults = _defaults()  # the real function's, before the stub replaces it
    calls = _stub(monkeypatch)
    session = shutil.copytree(studio.session, tmp_path / "S")
    plain = run_inprocess(["reconstruct", session, "--outer", "5", "--constraints", "silhouette,depth"], capfd)
    accurate = run_inprocess(["reconstruct", session, "--outer", "5", "--constraints", "silhouette,depth",
                              "--accurate", *joint_smoothing], capfd)
    assert plain.rc == 0 and accurate.rc == 0, (plain.text[-800:], accurate.text[-800:])
    off, on = calls
    # the switch changes exactly the preset's keywords, to the preset's values
    changed = {k for k in set(off) | set(on) if k != "params" and off.get(k) != on.get(k)}
    assert changed == set(ACCURATE_SETTINGS), changed
    assert {k: on[k] for k in ACCURATE_SETTINGS} == ACCURATE_SETTINGS
    # without it, the run keeps reconstruct_session's defaults (the switch does not leak)
    assert all(off.get(k, defaults[k]) == defaults[k] for k in ACCURATE_SETTINGS), off
    # the fit's parameters: the caller's (--outer 5, both constraints) with only the preset's fields over them
    p_off, p_on = asdict(off["params"]), asdict(on["params"])
    assert {k for k in p_off if p_off[k] != p_on[k]} == set(ACCURATE_PARAMS)
    assert {k: p_on[k] for k in ACCURATE_PARAMS} == ACCURATE_PARAMS
    assert p_on["outer_iterations"] == 5 and tuple(p_on["constraints"]) == ("silhouette", "depth")
    assert p_off["surface_hold_k"] == RapidSkinParams().surface_hold_k == 0.0


def test_the_preset_is_accepted_by_reconstruct_session():
    """Every key is a keyword of ``reconstruct_session`` (or a ``RapidSkinParams`` field) with a valid value,
    each differs from the default it replaces, and the defaults themselves are not the preset."""
    from bodystudio.reconstruct.presets import ACCURATE_PARAMS, ACCURATE_SETTINGS, accurate_keywords
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams
    from bodystudio.reconstruct.sequence import reconstruct_session

    sig = inspect.signature(reconstruct_session)
    sig.bind("SESSION", **accurate_keywords())  # raises TypeError on an unknown keyword
    defaults = _defaults()
    assert all(defaults[k] != v for k, v in ACCURATE_SETTINGS.items()), "a preset key equal to its default"
    params = RapidSkinParams(**ACCURATE_PARAMS)  # validated in __post_init__
    assert all(getattr(RapidSkinParams(), k) != v for k, v in ACCURATE_PARAMS.items())
    assert accurate_keywords(RapidSkinParams(outer_iterations=3))["params"] == \
        RapidSkinParams(outer_iterations=3, **ACCURATE_PARAMS)
    assert params.surface_hold_region == "torso"
