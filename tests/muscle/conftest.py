"""Shared fixtures of the arm-muscle tests (owner M-CORE; others append fixtures at the END only)."""

import pytest


@pytest.fixture(scope="session")
def muscular_body_2k():
    """A muscular, lean male body on the decimated 2k template."""
    from bodystudio.body import Phenotype, build_body

    return build_body(Phenotype(gender=1.0, muscle=0.85, weight=0.45), resolution="2k")


@pytest.fixture(scope="session")
def arm_template_2k(muscular_body_2k):
    """The left arm template cut from the muscular 2k body."""
    from bodystudio.muscle.arm import arm_template

    return arm_template(muscular_body_2k, "left")
