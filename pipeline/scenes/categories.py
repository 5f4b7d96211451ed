"""The 40 Matterport categories (mpcat40) and the raw-name -> category mapping.

The tables ship with the package (copied from Matterport's `category_mapping.tsv` and `mpcat40.tsv`).
wall (1), floor (2) and ceiling (17) are stuff; raw names that do not map are void (0).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

STUFF_CATEGORIES = frozenset({1, 2, 17})
VOID = 0
MISC = 40  # mpcat40's catch-all: an instance whose raw name the table does not map


@dataclass(frozen=True)
class Category:
    """One mpcat40 category."""

    index: int
    name: str
    hex_color: str

    @property
    def is_stuff(self) -> bool:
        return self.index in STUFF_CATEGORIES

    @property
    def rgb(self) -> tuple[int, int, int]:
        h = self.hex_color.lstrip("#")
        return (int(h[0:2], 16), int(h[2:4], 16), int(h[4:6], 16))


@dataclass(frozen=True)
class RawName:
    """One raw Matterport object name, its category and how often it occurs in Matterport."""

    raw_name: str
    category_index: int
    count: int


def _read_tsv(name: str) -> list[dict[str, str]]:
    text = resources.files("pipeline.data.matterport").joinpath(name).read_text(encoding="utf-8")
    return list(csv.DictReader(text.splitlines(), delimiter="\t"))


@lru_cache(maxsize=1)
def categories() -> dict[int, Category]:
    """mpcat40 index -> Category, including 0 = void."""
    return {
        int(row["mpcat40index"]): Category(int(row["mpcat40index"]), row["mpcat40"], row["hex"])
        for row in _read_tsv("mpcat40.tsv")
    }


@lru_cache(maxsize=1)
def raw_names() -> tuple[RawName, ...]:
    """Every raw name of the mapping table with its category and count, in table order."""
    rows = []
    for row in _read_tsv("category_mapping.tsv"):
        index = row.get("mpcat40index") or ""
        rows.append(RawName(row["raw_category"], int(index) if index.strip() else VOID, int(row["count"] or 0)))
    return tuple(rows)


@lru_cache(maxsize=1)
def _name_to_category() -> dict[str, int]:
    return {r.raw_name.strip().lower(): r.category_index for r in raw_names()}


def category_of(raw_name: str) -> int:
    """The mpcat40 index of a raw object name (case and surrounding spaces ignored); 0 when unmapped."""
    return _name_to_category().get(raw_name.strip().lower(), VOID)
