"""Shared fixtures for the core tests: a seeded rng, Hypothesis profiles, the core module.

Hypothesis profiles: ``ci`` (derandomized, >= 1000 examples, no deadline) is loaded when the
environment variable CI is set, ``dev`` (150 random examples: exploration, new failures get pinned)
otherwise; HYPOTHESIS_PROFILE overrides. ``ci-quick`` (derandomized, 150 examples) is for the test
command's extra runs on older numpy: CI must not depend on luck, and random exploration there had
found known open cases about once in 25 runs.
"""

from __future__ import annotations

import os
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

sys.path.insert(0, str(Path(__file__).resolve().parent))  # tests/core/scenes_for_tests.py

_HEALTH = [HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much]
settings.register_profile("ci", derandomize=True, max_examples=1000, deadline=None, database=None,
                          suppress_health_check=_HEALTH, print_blob=True)
settings.register_profile("ci-quick", derandomize=True, max_examples=150, deadline=None, database=None,
                          suppress_health_check=_HEALTH, print_blob=True)
settings.register_profile("dev", max_examples=150, deadline=None, suppress_health_check=_HEALTH)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE") or ("ci" if os.environ.get("CI") else "dev"))


@pytest.fixture
def rng(request) -> np.random.Generator:
    """A numpy Generator seeded from the test's node id: reproducible, different per test."""
    return np.random.default_rng(zlib.crc32(request.node.nodeid.encode()) + 20261122)


@pytest.fixture(scope="session")
def core():
    """The module under test, imported lazily so the test machinery can be checked without it."""
    import hemisphere_local_pass.core as core_module

    return core_module
