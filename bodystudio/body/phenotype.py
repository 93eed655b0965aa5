"""Macro phenotype and local modifiers, blended exactly as MakeHuman 1.x does.

Macro variables (gender, age, muscle, weight, height, proportions and three ethnic weights) are in
[0, 1]. Each is split into the "low/average/high" values of ``apps/human.py`` (e.g. ``minweightVal =
max(0, 1 - 2 w)``), and every macro target file ``macrodetails[/group]/a-b-c-...`` is weighted by the
product of the values its name parts stand for (``humanmodifier.getTargetWeights``). Local modifiers
(``l-upperarm-fat-decr|incr`` and the like) take a value in [-1, 1]: negative values weight the
"decr" target by ``-v``, positive values the "incr" target by ``v``.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from functools import lru_cache
from pathlib import Path

from bodystudio.errors import InputError

MACRO_NAMES = ("gender", "age", "muscle", "weight", "height", "proportions")
ETHNIC_NAMES = ("african", "asian", "caucasian")


@dataclass(frozen=True)
class Phenotype:
    """MakeHuman macro parameters, each in [0, 1]; defaults are MakeHuman's (age 0.5 = 25 years)."""

    gender: float = 0.5  # 0 female, 1 male
    age: float = 0.5  # 0 = 1 year, 0.1875 = 10, 0.5 = 25, 1 = 90 years (MakeHuman's getAgeYears)
    muscle: float = 0.5
    weight: float = 0.5
    height: float = 0.5
    proportions: float = 0.5
    african: float = 1 / 3
    asian: float = 1 / 3
    caucasian: float = 1 / 3

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if not isinstance(v, (int, float)) or not 0.0 <= float(v) <= 1.0:
                raise InputError(f"phenotype {f.name}={v!r} is out of range; use a value in [0, 1]")
        if self.african + self.asian + self.caucasian <= 0:
            raise InputError("phenotype ethnic weights african+asian+caucasian are all 0; give at least one > 0")

    @classmethod
    def from_dict(cls, values: dict) -> Phenotype:
        valid = [f.name for f in fields(cls)]
        unknown = sorted(set(values) - set(valid))
        if unknown:
            raise InputError(f"unknown phenotype parameter(s) {', '.join(unknown)}; valid: {', '.join(valid)}")
        return cls(**{k: float(v) for k, v in values.items()})

    def to_dict(self) -> dict:
        return asdict(self)

    def macro_values(self) -> dict[str, float]:
        """The per-part values of MakeHuman's ``human.py`` (femaleVal, youngVal, maxweightVal, ...)."""
        g, a = self.gender, self.age
        vals = {"male": g, "female": 1.0 - g}
        if a < 0.5:
            young = max(0.0, (a - 0.1875) * 3.2)
            vals.update(old=0.0, baby=max(0.0, 1 - a * 5.333), young=young, child=max(0.0, min(1.0, 5.333 * a) - young))
        else:
            old = max(0.0, a * 2 - 1)
            vals.update(child=0.0, baby=0.0, old=old, young=1 - old)
        for name, var in (("weight", self.weight), ("muscle", self.muscle)):
            hi, lo = max(0.0, var * 2 - 1), max(0.0, 1 - var * 2)
            vals.update({f"max{name}": hi, f"min{name}": lo, f"average{name}": 1 - (hi + lo)})
        vals["maxheight"] = max(0.0, self.height * 2 - 1)
        vals["minheight"] = max(0.0, 1 - self.height * 2)
        vals["idealproportions"] = max(0.0, self.proportions * 2 - 1)
        vals["uncommonproportions"] = max(0.0, 1 - self.proportions * 2)
        total = self.african + self.asian + self.caucasian
        vals.update(african=self.african / total, asian=self.asian / total, caucasian=self.caucasian / total)
        vals["universal"] = 1.0
        return vals


def macro_target_weights(phenotype: Phenotype, target_names: list[str]) -> dict[str, float]:
    """Weights of the ``macrodetails*`` targets for a phenotype (``getTargetWeights`` of MakeHuman)."""
    values = phenotype.macro_values()
    weights = {}
    for name in target_names:
        if not name.startswith("macrodetails/"):
            continue
        parts = name.rsplit("/", 1)[1].split("-")
        w = 1.0
        for part in parts:
            w *= values[part]
            if w == 0.0:
                break
        if w != 0.0:
            weights[name] = w
    return weights


@lru_cache(maxsize=2)
def local_modifiers(data_dir: Path) -> dict[str, tuple[str, str]]:
    """Local modifier name -> (negative target, positive target), read from ``targets/target.json``.

    Sided modifiers appear as ``l-NAME`` and ``r-NAME``; the unsided ``NAME`` drives both sides.
    """
    with open(data_dir / "targets" / "target.json", encoding="utf-8") as f:
        spec = json.load(f)
    mods: dict[str, tuple[str, str]] = {}
    for entry in spec.values():
        for cat in entry.get("categories", []):
            opp = cat.get("opposites", {})
            name = cat["name"]
            if cat.get("has_left_and_right"):
                for side, word in (("l", "left"), ("r", "right")):
                    mods[f"{side}-{name}"] = (opp.get(f"negative-{word}", ""), opp.get(f"positive-{word}", ""))
            else:
                mods[name] = (opp.get("negative-unsided", ""), opp.get("positive-unsided", ""))
    return mods


def _canonical(name: str) -> str:
    return name.strip().replace("|", "-")


def local_target_weights(local: dict[str, float], data_dir: Path, target_names: list[str]) -> dict[str, float]:
    """Weights of local targets for modifier values in [-1, 1] (unknown names list what is valid)."""
    mods = local_modifiers(data_dir)
    by_basename: dict[str, str] = {}
    for t in target_names:
        if not t.startswith("macrodetails"):
            by_basename.setdefault(t.rsplit("/", 1)[-1], t)
    weights: dict[str, float] = {}
    for raw, value in local.items():
        name = _canonical(raw)
        if not -1.0 <= float(value) <= 1.0:
            raise InputError(f"local modifier {raw}={value} is out of range; use a value in [-1, 1]")
        keys = [name] if name in mods else [f"l-{name}", f"r-{name}"]
        if not all(k in mods for k in keys):
            close = sorted(k for k in mods if name.split("-")[0] in k)[:12]
            hint = ", ".join(close) if close else ", ".join(sorted(mods)[:12])
            raise InputError(f"unknown local modifier {raw!r}; valid names look like: {hint} "
                             f"(full list: 'bodystudio body info --modifiers')")
        for key in keys:
            neg, pos = mods[key]
            target = pos if value > 0 else neg
            if value == 0 or not target:
                continue
            if target not in by_basename:
                raise InputError(f"local modifier {raw!r}: target {target!r} is missing from the MakeHuman data")
            weights[by_basename[target]] = weights.get(by_basename[target], 0.0) + abs(float(value))
    return weights
