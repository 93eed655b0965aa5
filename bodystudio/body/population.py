"""A documented, seeded population of adult bodies: the distribution subjects are drawn from.

Used to learn the statistical model (PCA, attribute map) and to pick synthetic studio subjects, so
``subject_seed`` always means the same person. Macro parameters (MakeHuman's [0, 1] scale):

* gender ~ Bernoulli(0.5) mixed towards the middle: 0.05 + 0.9 * B + N(0, 0.05), clipped to [0, 1]
* age ~ U(0.5, 0.875)  (25 to ~60 years; adults only)
* muscle ~ Beta(4, 4), weight ~ Beta(3, 3) scaled to [0.15, 0.95]
* height: a stature z-score z ~ N(0, 1) mapped to MakeHuman's height so that stature varies by about
  7 cm per standard deviation, as in adult populations (MakeHuman's height modifier is about twice as
  strong above 0.5 as below: h = 0.5 + 0.096 z for z < 0, 0.5 + 0.048 z otherwise, clipped to
  [0.2, 0.7])
* proportions ~ U(0.3, 0.8)
* ethnic weights ~ Dirichlet(1, 1, 1)
* local modifiers: each of ``LOCAL_SPREAD`` ~ N(0, sigma) clipped to [-1, 1], both sides alike
"""

from __future__ import annotations

import numpy as np

from bodystudio.body.phenotype import Phenotype

# Local modifiers sampled per subject (unsided names drive left and right together), with sigma.
LOCAL_SPREAD: dict[str, float] = {
    "upperarm-fat-decr-incr": 0.25,
    "upperarm-muscle-decr-incr": 0.25,
    "lowerarm-fat-decr-incr": 0.2,
    "upperleg-fat-decr-incr": 0.25,
    "upperleg-muscle-decr-incr": 0.2,
    "lowerleg-fat-decr-incr": 0.2,
    "torso-scale-depth-decr-incr": 0.2,
    "torso-scale-horiz-decr-incr": 0.2,
    "hip-scale-horiz-decr-incr": 0.2,
    "stomach-pregnant-decr-incr": 0.15,
    "buttocks-volume-decr-incr": 0.25,
    "neck-scale-horiz-decr-incr": 0.2,
}


def _height_from_zscore(z: float) -> float:
    return float(np.clip(0.5 + (0.096 if z < 0 else 0.048) * z, 0.2, 0.7))


def sample_subject(seed: int | np.random.Generator) -> tuple[Phenotype, dict[str, float]]:
    """One adult subject (phenotype, local modifier values) from the population; same seed, same person."""
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    gender = float(np.clip(0.05 + 0.9 * rng.integers(0, 2) + rng.normal(0, 0.05), 0, 1))
    ethnic = rng.dirichlet([1.0, 1.0, 1.0])
    phenotype = Phenotype(
        gender=gender,
        age=float(rng.uniform(0.5, 0.875)),
        muscle=float(rng.beta(4, 4)),
        weight=float(0.15 + 0.8 * rng.beta(3, 3)),
        height=_height_from_zscore(float(rng.normal())),
        proportions=float(rng.uniform(0.3, 0.8)),
        african=float(ethnic[0]), asian=float(ethnic[1]), caucasian=float(ethnic[2]),
    )
    local = {name: float(np.clip(rng.normal(0, sigma), -1, 1)) for name, sigma in LOCAL_SPREAD.items()}
    return phenotype, local


def sample_population(n: int, seed: int = 0) -> list[tuple[Phenotype, dict[str, float]]]:
    """``n`` subjects from one seeded generator."""
    rng = np.random.default_rng(seed)
    return [sample_subject(rng) for _ in range(n)]
