"""``bench_scaling.py --out`` rewrites its markdown but keeps the hand-written part after the marker."""

from benchmark_modules import load


def test_rewrite_keeps_everything_from_the_marker_on(tmp_path):
    mod = load("bench_scaling")
    out = tmp_path / "bench.md"
    kept = f"{mod.KEEP_MARKER}\n\n### Measured by hand\n\nfigures | 1 | 2\n"
    out.write_text("# old table\n\n| old |\n\n" + kept)
    text = mod.with_kept_sections("# new table\n\n| new |\n", out)
    assert text.startswith("# new table\n\n| new |\n")
    assert "old table" not in text
    assert text.endswith(kept)


def test_a_file_without_the_marker_or_no_file_is_replaced_whole(tmp_path):
    mod = load("bench_scaling")
    out = tmp_path / "bench.md"
    assert mod.with_kept_sections("new\n", out) == "new\n"
    out.write_text("old\n")
    assert mod.with_kept_sections("new\n", out) == "new\n"
