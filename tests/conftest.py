"""Shared fixtures. The body model is expensive to load, so it is session-scoped.

Also the sharing of the test files between the side-by-side pytest processes of `make test`
(scripts/test_shards.py).
"""

import json
import os
from pathlib import Path

import pytest

SHARD_WEIGHTS = Path(__file__).parent / "shard_weights.json"
SECONDS_PER_UNLISTED_TEST = 0.35  # the suite's mean; for test files not yet in shard_weights.json


def files_longest_first(items) -> list[list]:
    """The items grouped by test file (collection order inside a file), the files by their measured seconds
    (tests/shard_weights.json; an unlisted file counts SECONDS_PER_UNLISTED_TEST a test), longest first."""
    measured = json.loads(SHARD_WEIGHTS.read_text()) if SHARD_WEIGHTS.is_file() else {}
    files: dict[str, list] = {}
    for item in items:
        files.setdefault(item.nodeid.split("::")[0], []).append(item)
    seconds = {name: measured.get(name, SECONDS_PER_UNLISTED_TEST * len(group)) for name, group in files.items()}
    return [files[name] for name in sorted(files, key=lambda n: (-seconds[n], n))]


def _claim(claims: Path, test_file: str) -> bool:
    """Take ``test_file`` for this process: the first process to create its claim file runs it."""
    try:
        os.close(os.open(claims / test_file.replace("/", "__"), os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return False
    return True


@pytest.hookimpl(tryfirst=True)
def pytest_runtestloop(session):
    """With BODYSTUDIO_TEST_CLAIMS=DIR (scripts/test_shards.py, `make test`), several pytest processes share
    the collected tests: each takes the next unclaimed test file, longest first, and runs all of its tests;
    a file another process took is left out here. Without it, pytest's own loop runs everything."""
    claims = os.environ.get("BODYSTUDIO_TEST_CLAIMS")
    if not claims or session.testsfailed or session.config.option.collectonly:
        return None
    mine = (group for group in files_longest_first(session.items)
            if _claim(Path(claims), group[0].nodeid.split("::")[0]))
    group = next(mine, None)
    while group is not None:
        following = None
        for i, item in enumerate(group):
            if i + 1 < len(group):
                nextitem = group[i + 1]
            else:  # claim the next file first: the fixtures torn down after this test depend on what comes next
                following = next(mine, None)
                nextitem = following[0] if following else None
            item.config.hook.pytest_runtest_protocol(item=item, nextitem=nextitem)
            if session.shouldfail:
                raise session.Failed(session.shouldfail)
            if session.shouldstop:
                raise session.Interrupted(session.shouldstop)
        group = following
    return True


@pytest.fixture(scope="session")
def default_body():
    from bodystudio.body import build_body

    return build_body()


@pytest.fixture(scope="session")
def body_2k():
    from bodystudio.body import build_body

    return build_body(resolution="2k")


@pytest.fixture(scope="session")
def small_synth_session(tmp_path_factory):
    """A noisy 4-camera, 3-frame, 320x240 synthetic studio session with a Kinect v1 (read-only: copy to modify)."""
    from bodystudio.capture.synth import synth_session

    path = tmp_path_factory.mktemp("synth") / "session"
    synth_session(path, n_cameras=4, n_frames=3, motion="arms_raise", subject_seed=7, kinect="v1",
                  resolution=(320, 240))
    return path


@pytest.fixture(scope="session")
def tiny_arm_model_path(tmp_path_factory):
    """A statistical arm model on the 2k left arm from two synthetic subjects and a 3-body population, saved
    as .npz (fast; for tests where the model's numbers do not matter). Read-only: copy to modify."""
    from bodystudio.body import build_body
    from bodystudio.muscle.arm import arm_template
    from bodystudio.muscle.model import learn_arm_model, save_arm_model
    from bodystudio.muscle.synthetic import sample_arm_subject, subject_arm_samples

    samples = subject_arm_samples(sample_arm_subject(1000), "2k", n_shapes=1, n_poses=2)
    samples += subject_arm_samples(sample_arm_subject(1001), "2k", n_shapes=1, n_poses=2)
    model = learn_arm_model(samples, arm_template(build_body(resolution="2k"), "left"), population_size=3)
    path = tmp_path_factory.mktemp("arm_model") / "tiny.npz"
    save_arm_model(path, model)
    return path
