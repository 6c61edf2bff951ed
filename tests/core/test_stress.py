"""CI version of the stress test (benchmarks/stress.py): 10^4 random and adversarial configurations."""

import importlib.util
from pathlib import Path

import pytest

STRESS = Path(__file__).resolve().parents[2] / "benchmarks" / "stress.py"


@pytest.fixture(scope="module")
def stats():
    spec = importlib.util.spec_from_file_location("hlp_stress", STRESS)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = mod.run(10_000, seed=0)
    print(mod.report(out))
    return out


@pytest.mark.slow
def test_no_crash_nan_inf_or_floating_point_errors(stats):
    assert stats["configurations"] >= 10_000
    assert stats["exceptions"] == 0, stats["worst"]
    assert stats["nan_inf"] == 0 and stats["fp_errors"] == 0, stats["worst"]


@pytest.mark.slow
def test_form_factors_within_zero_and_one(stats):
    assert stats["negative"] == 0, f"min F {stats['min_F']!r}"
    assert stats["above_one"] == 0, f"max F {stats['max_F']!r}"
