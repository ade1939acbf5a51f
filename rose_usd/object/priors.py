"""Physics priors per object category ('physics as plausibility'): the table rose_usd uses where
the paper asks a VLM. Values are everyday engineering figures; ranges are deliberately wide.

Density is that of the solid for solid categories and of the shell material for hollow ones (a
mug's ceramic, a bottle's plastic); ``shell_thickness_m`` then gives the wall used for the volume.
Friction is a Coulomb coefficient against a wooden table; restitution is for drops on a table.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass

from rose_usd.errors import ConfigError


@dataclass(frozen=True)
class PhysicsPrior:
    category: str
    density_range_kg_m3: tuple[float, float]
    friction: float
    friction_sigma: float
    restitution: float
    restitution_sigma: float
    hollow: bool = False
    shell_thickness_m: float = 0.0
    note: str = ""

    @property
    def density_kg_m3(self) -> float:
        """Point estimate: the middle of the range."""
        lo, hi = self.density_range_kg_m3
        return 0.5 * (lo + hi)

    @property
    def density_sigma_kg_m3(self) -> float:
        """One sigma of a uniform distribution over the range."""
        lo, hi = self.density_range_kg_m3
        return (hi - lo) / 12**0.5


PRIORS: dict[str, PhysicsPrior] = {
    p.category: p
    for p in (
        PhysicsPrior(
            "box", (150.0, 700.0), 0.50, 0.10, 0.10, 0.05, note="packed cardboard box or carton, contents included"
        ),
        PhysicsPrior("block", (450.0, 850.0), 0.45, 0.10, 0.30, 0.10, note="wooden block"),
        PhysicsPrior(
            "can", (850.0, 1100.0), 0.35, 0.10, 0.10, 0.05, note="full beverage or food can (liquid dominates)"
        ),
        PhysicsPrior(
            "mug", (1900.0, 2500.0), 0.50, 0.10, 0.20, 0.10, hollow=True, shell_thickness_m=0.005, note="ceramic mug"
        ),
        PhysicsPrior(
            "cup",
            (900.0, 1200.0),
            0.40,
            0.10,
            0.20,
            0.10,
            hollow=True,
            shell_thickness_m=0.0015,
            note="plastic or paper cup",
        ),
        PhysicsPrior(
            "bowl", (1900.0, 2500.0), 0.50, 0.10, 0.20, 0.10, hollow=True, shell_thickness_m=0.005, note="ceramic bowl"
        ),
        PhysicsPrior(
            "bottle",
            (900.0, 1400.0),
            0.40,
            0.10,
            0.30,
            0.10,
            hollow=True,
            shell_thickness_m=0.001,
            note="empty plastic bottle",
        ),
        PhysicsPrior("fruit", (750.0, 1000.0), 0.60, 0.15, 0.20, 0.10, note="apple, orange"),
        PhysicsPrior("book", (550.0, 950.0), 0.50, 0.10, 0.05, 0.05, note="paper book"),
        PhysicsPrior(
            "marker",
            (300.0, 800.0),
            0.35,
            0.10,
            0.30,
            0.10,
            note="marker or pen: a plastic barrel and cap, mostly hollow (about 10-15 g over 25-30 cm^3)",
        ),
        PhysicsPrior("pen", (300.0, 800.0), 0.35, 0.10, 0.30, 0.10, note="ballpoint pen, hollow plastic barrel"),
        PhysicsPrior("toy", (150.0, 1100.0), 0.50, 0.15, 0.40, 0.15, note="plastic toy, solid or hollow"),
        PhysicsPrior("generic", (200.0, 1500.0), 0.50, 0.20, 0.20, 0.10, note="unknown category: wide prior"),
    )
}


def lookup(category: str) -> tuple[PhysicsPrior, str | None]:
    """The prior of ``category`` and a warning (None if the category is known).

    An unknown category gets the generic prior and a warning naming the closest known one; a
    near-miss (likely typo) is an error so it does not silently lose its physics."""
    key = category.strip().lower()
    if key in PRIORS:
        return PRIORS[key], None
    close = difflib.get_close_matches(key, PRIORS, n=1, cutoff=0.75)
    if close:
        raise ConfigError(
            f"unknown object category {category!r}",
            hint=f"did you mean {close[0]!r}? known: {', '.join(sorted(PRIORS))}",
        )
    return PRIORS[
        "generic"
    ], f"unknown category {category!r}: using the generic prior (known: {', '.join(sorted(PRIORS))})"
