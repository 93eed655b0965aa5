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


@pytest.fixture(scope="session")
def arm_training_2k():
    """A small training dataset on the 2k template: 5 men (BMI 20-28), 2 base-pose + 8 posed meshes each."""
    from bodystudio.muscle.synthetic import training_dataset

    return training_dataset("2k", n_subjects=5, n_shapes=2, n_poses=8)


@pytest.fixture(scope="session")
def arm_model_2k(arm_training_2k):
    """The arm model learned from ``arm_training_2k`` (population of 12 for the length term and joints)."""
    from bodystudio.muscle.arm import arm_template
    from bodystudio.muscle.model import learn_arm_model
    from bodystudio.muscle.synthetic import subject_body

    samples, subjects = arm_training_2k
    template = arm_template(subject_body(subjects[0], "2k"), "left")
    return learn_arm_model(samples, template, population_size=12)
