"""pyproject.toml: the `all` extra installs every optional feature, so a new extra cannot be left out of it."""

from __future__ import annotations

import tomllib
from pathlib import Path

from packaging.requirements import Requirement

PROJECT = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]
NOT_FEATURES = {"test", "bench"}  # the suite's tools and a benchmark's peer renderer (see the comment on `all`)


def test_all_is_every_feature_extra_of_this_project() -> None:
    extras = PROJECT["optional-dependencies"]
    requirements = [Requirement(line) for line in extras["all"]]
    assert [r.name for r in requirements] == [PROJECT["name"]]  # named by extra, so no version range is copied
    assert requirements[0].extras == set(extras) - NOT_FEATURES - {"all"}
    assert NOT_FEATURES <= set(extras)  # a renamed tool extra must be renamed here too
