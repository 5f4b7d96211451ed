"""Raw object names drawn from Matterport's `category_mapping.tsv`, weighted by its `count` column,
so the generated vocabulary (including the long tail of "objects" and "misc") matches real scans."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from pipeline.scenes.categories import category_of, raw_names

OBJECTS, MISC = 39, 40
# Annotation artefacts (references to other rooms, "remove", typos with punctuation) are not names
# an annotator would give an object standing in the room.
_NOISE = ("/", "\\", "other room", "otherroom", "remove", "delete", "behind", "outside", "reflection", "?", ";")


def _clean(name: str) -> bool:
    lowered = name.lower()
    return bool(name.strip()) and not any(token in lowered for token in _NOISE) and not any(c.isdigit() for c in name)


@lru_cache(maxsize=64)
def _pool(category: int) -> tuple[tuple[str, ...], np.ndarray]:
    rows = [r for r in raw_names() if r.category_index == category and r.count > 0 and _clean(r.raw_name)]
    names = tuple(r.raw_name for r in rows)
    weights = np.array([r.count for r in rows], dtype=np.float64)
    return names, weights / weights.sum()


@lru_cache(maxsize=256)
def _preferred(category: int, preferred: tuple[str, ...]) -> tuple[tuple[str, ...], np.ndarray]:
    counts = {r.raw_name: r.count for r in raw_names() if r.category_index == category}
    names = tuple(n for n in preferred if n in counts and counts[n] > 0 and category_of(n) == category)
    if not names:
        return _pool(category)
    weights = np.array([counts[n] for n in names], dtype=np.float64)
    return names, weights / weights.sum()


def choose_name(rng: np.random.Generator, category: int, preferred: tuple[str, ...] = ()) -> str:
    """A raw name of `category`: one of `preferred` (those in the table) or any, weighted by count."""
    names, weights = _preferred(category, tuple(preferred)) if preferred else _pool(category)
    return names[int(rng.choice(len(names), p=weights))]


def clutter_name(rng: np.random.Generator) -> tuple[str, int]:
    """A raw name (and its category) for a small object: mostly "objects", sometimes "misc"."""
    category = OBJECTS if rng.random() < 0.8 else MISC
    return choose_name(rng, category), category
