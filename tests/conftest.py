"""Shared fixtures. The body model is expensive to load, so it is session-scoped."""

import pytest


@pytest.fixture(scope="session")
def default_body():
    from bodystudio.body import build_body

    return build_body()


@pytest.fixture(scope="session")
def body_2k():
    from bodystudio.body import build_body

    return build_body(resolution="2k")
