"""Scene split: which scenes are train, val and test (a scene is never in two splits).

Two steps, so that the zero-shot clustering (which needs to know the training scenes) can run before
the held-out pool is cut:
1. `train_and_pool`: train scenes vs the held-out pool (HM3D numbering, a seeded shuffle by fractions,
   or explicit lists).
2. `assign_scenes`: the pool is cut into val and test by a seeded shuffle stratified by whether a scene
   holds a zero-shot object, as the authors halve HM3D's 36 validation scenes (each stratum is
   shuffled and its first int(n * share) scenes go to val).
Both are cheap, deterministic functions of the scene ids and the config: every unit recomputes them.
"""

from __future__ import annotations

import re
from collections.abc import Iterable

from pipeline.config import SPLIT_NAMES, ConfigError, SceneSplitConfig
from pipeline.runtime.stage import seeded_rng

HM3D_ID = re.compile(r"^(\d{5})-")
HM3D_FIRST_VALIDATION = 800
HM3D_LAST = 899


class SceneSplitError(ConfigError):
    """The scene split cannot be made for this run's scenes; the message names the field and the fix."""


def resolved_mode(scene_ids: Iterable[str], config: SceneSplitConfig) -> str:
    """`config.mode`, with `auto` resolved: hm3d when every scene id is HM3D-numbered, else fractions."""
    if config.mode != "auto":
        return config.mode
    return "hm3d" if all(HM3D_ID.match(s) for s in scene_ids) else "fractions"


def train_and_pool(scene_ids: Iterable[str], config: SceneSplitConfig, job_seed: int) -> tuple[list[str], list[str]]:
    """(training scenes, held-out pool), each sorted."""
    scenes = sorted(set(scene_ids))
    mode = resolved_mode(scenes, config)
    if mode == "lists":
        assert config.lists is not None
        _check_listed(scenes, config)
        listed = set(scenes)
        return (sorted(s for s in config.lists.train if s in listed),
                sorted(s for s in [*config.lists.val, *config.lists.test] if s in listed))
    if len(scenes) < len(SPLIT_NAMES):
        raise SceneSplitError(f"split.scenes: the run has {len(scenes)} scene(s), fewer than the {len(SPLIT_NAMES)} "
                              "splits; add scenes or give split.scenes.lists")
    if mode == "hm3d":
        return _hm3d_train_and_pool(scenes)
    shuffled = _shuffled(scenes, config, job_seed, "train")
    fractions = config.fractions
    held_out = fractions.val + fractions.test
    count = len(scenes) if held_out == 0 else min(len(scenes) - 1, max(1, round(fractions.train * len(scenes))))
    if fractions.train == 0:
        count = 0
    return sorted(shuffled[:count]), sorted(shuffled[count:])


def assign_scenes(scene_ids: Iterable[str], config: SceneSplitConfig, job_seed: int,
                  zero_shot_scenes: set[str]) -> dict[str, str]:
    """Scene id -> 'train' | 'val' | 'test' (scenes in no explicit list are absent)."""
    scenes = sorted(set(scene_ids))
    train, pool = train_and_pool(scenes, config, job_seed)
    assignment = {scene: "train" for scene in train}
    if resolved_mode(scenes, config) == "lists":
        assert config.lists is not None
        listed = set(scenes)
        assignment.update({s: "val" for s in config.lists.val if s in listed})
        assignment.update({s: "test" for s in config.lists.test if s in listed})
        return assignment
    share = config.val_share if resolved_mode(scenes, config) == "hm3d" else _val_share(config)
    val: list[str] = []
    test: list[str] = []
    for stratum, scenes_of in (("zero-shot", [s for s in pool if s in zero_shot_scenes]),
                               ("other", [s for s in pool if s not in zero_shot_scenes])):
        shuffled = _shuffled(scenes_of, config, job_seed, "pool", stratum)
        cut = int(len(shuffled) * share)
        val += shuffled[:cut]
        test += shuffled[cut:]
    _keep_both_non_empty(val, test, share)
    for name, chosen in (("val", val), ("test", test)):
        if not chosen and (resolved_mode(scenes, config) == "hm3d" or getattr(config.fractions, name) > 0):
            raise SceneSplitError(f"split.scenes.fractions: {len(scenes)} scenes leave {name} without a scene; "
                                  "add scenes, change the fractions or give split.scenes.lists")
    assignment.update({s: "val" for s in val})
    assignment.update({s: "test" for s in test})
    return assignment


def _val_share(config: SceneSplitConfig) -> float:
    held_out = config.fractions.val + config.fractions.test
    return 0.5 if held_out == 0 else config.fractions.val / held_out


def _keep_both_non_empty(val: list[str], test: list[str], share: float) -> None:
    """int() truncation can leave val empty on a small pool (1 + 1 scenes in two strata): move one scene."""
    if not val and len(test) >= 2 and share > 0:
        val.append(test.pop(0))
    elif not test and len(val) >= 2 and share < 1:
        test.append(val.pop())


def _shuffled(scenes: list[str], config: SceneSplitConfig, job_seed: int, *keys: str) -> list[str]:
    rng = seeded_rng(job_seed, "split", "scenes", config.seed, *keys)
    order = rng.permutation(len(scenes))
    return [scenes[i] for i in order]


def _hm3d_train_and_pool(scenes: list[str]) -> tuple[list[str], list[str]]:
    train, pool = [], []
    for scene in scenes:
        match = HM3D_ID.match(scene)
        number = int(match.group(1)) if match else -1
        if not 0 <= number <= HM3D_LAST:
            raise SceneSplitError(f"split.scenes.mode: hm3d needs HM3D-numbered scene ids (00000-00899), got {scene!r}; "
                                  "use mode fractions or lists")
        (train if number < HM3D_FIRST_VALIDATION else pool).append(scene)
    if not train or len(pool) < 2:
        raise SceneSplitError(f"split.scenes.mode: hm3d gives {len(train)} training and {len(pool)} held-out scenes; "
                              "it needs at least 1 and 2; use mode fractions or lists")
    return train, pool


def _check_listed(scenes: list[str], config: SceneSplitConfig) -> None:
    assert config.lists is not None
    known = set(scenes)
    for name in SPLIT_NAMES:
        unknown = [s for s in getattr(config.lists, name) if s not in known]
        if unknown:
            raise SceneSplitError(f"split.scenes.lists.{name}: scene {unknown[0]!r} is not in the run's scenes table; "
                                  "fix the list (scene ids: mvpd query RUN \"select scene_id from scenes\")")
        if not getattr(config.lists, name):
            raise SceneSplitError(f"split.scenes.lists.{name}: empty; every split needs at least one scene")
