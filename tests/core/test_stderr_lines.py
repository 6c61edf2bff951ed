"""The command line's progress lines (``blender/stderr_lines.py``, plain Python: no bpy needed)."""

from __future__ import annotations

import io
import types

from hemisphere_local_pass.blender import stderr_lines


def test_percent_lines_are_not_starved_by_the_heartbeat(monkeypatch):
    """Chunks slower than the heartbeat's poll (interval / 4): the heartbeat's "computing ... (N s)"
    line lands first each time; the percent line must still appear about once per interval (it
    used to wait for an interval without any line, so none came before 100 %: a farm log showed
    no ETA). A fake clock; the heartbeat's writes are made by hand (its thread is not started)."""
    clock = types.SimpleNamespace(t=100.0)
    monkeypatch.setattr(stderr_lines, "time", types.SimpleNamespace(perf_counter=lambda: clock.t))
    out = io.StringIO()
    p = stderr_lines.StderrProgress(stream=out, interval=1.0)
    p._write("computing 100 points")            # the stage line, t = 100.0
    clock.t = 100.3
    p(10, 100)                                  # first chunk: too early for a line
    for k in range(1, 4):
        clock.t = 100.0 + 1.1 * k               # the heartbeat, an interval after the last line
        p._write(f"computing 100 points ({k} s)")
        clock.t = 100.2 + 1.1 * k               # the next chunk ends just after it
        p(10 + 10 * k, 100)
    clock.t = 104.5
    p(100, 100)                                 # the end: always a line
    percent = [line for line in out.getvalue().splitlines() if "points/s" in line]
    assert len(percent) == 4, out.getvalue()
    assert percent[0].endswith("20/100 points, 10 points/s, ETA 8 s"), percent[0]  # 10 points in 1.0 s
    assert "100.0% 100/100" in percent[-1]
