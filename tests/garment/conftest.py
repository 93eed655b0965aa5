"""Garment fixtures: one 2k body and its garments, built once per session."""

import pytest


@pytest.fixture(scope="session")
def garment_body():
    from bodystudio.body import build_body

    return build_body(resolution="2k")


@pytest.fixture(scope="session")
def garments(garment_body):
    from bodystudio.garment.garments import dress

    return {name: dress(garment_body, name, pattern, texture_size=256)
            for name, pattern in (("tights", "checks"), ("skirt", "print"), ("tshirt", "stripes"),
                                  ("longsleeve", "plain"))}
