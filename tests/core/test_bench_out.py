"""``bench_scaling.py --out`` rewrites its markdown but keeps the hand-written part after the marker."""

import importlib.util
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"


def _bench_scaling():
    sys.path.insert(0, str(BENCH))          # its sibling module _common
    try:
        spec = importlib.util.spec_from_file_location("hlp_bench_scaling", BENCH / "bench_scaling.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(BENCH))
    return mod


def test_rewrite_keeps_everything_from_the_marker_on(tmp_path):
    mod = _bench_scaling()
    out = tmp_path / "bench.md"
    kept = f"{mod.KEEP_MARKER}\n\n### Measured by hand\n\nfigures | 1 | 2\n"
    out.write_text("# old table\n\n| old |\n\n" + kept)
    text = mod.with_kept_sections("# new table\n\n| new |\n", out)
    assert text.startswith("# new table\n\n| new |\n")
    assert "old table" not in text
    assert text.endswith(kept)


def test_a_file_without_the_marker_or_no_file_is_replaced_whole(tmp_path):
    mod = _bench_scaling()
    out = tmp_path / "bench.md"
    assert mod.with_kept_sections("new\n", out) == "new\n"
    out.write_text("old\n")
    assert mod.with_kept_sections("new\n", out) == "new\n"
