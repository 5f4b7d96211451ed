"""Hypothesis settings for the fuzz tests of every reader of untrusted bytes.

The default profile is bounded so the whole suite stays within its budget; `MVPD_FUZZ_EXAMPLES=N` runs N
examples per property instead (a longer soak: `MVPD_FUZZ_EXAMPLES=5000 make test`).
"""

from __future__ import annotations

import os

from hypothesis import HealthCheck, settings

settings.register_profile(
    "mvpd",
    max_examples=int(os.environ.get("MVPD_FUZZ_EXAMPLES", "60")),
    deadline=None,  # a shared 2-core machine: time is bounded per test by the example count, not per example
    derandomize=not os.environ.get("MVPD_FUZZ_EXAMPLES"),  # CI: the same examples every run
    database=None,  # no .hypothesis folder in the work tree
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
settings.load_profile("mvpd")
