"""What the commands (``render``, ``merge``, ``solve``) write on stderr: progress lines while a job
runs (:class:`StderrProgress`), the one line of a failed command (:func:`error_line`), and the exit
codes every command shares (:func:`run_command`)."""

from __future__ import annotations

import math
import sys
import threading
import time

__all__ = ["PREFIX", "StderrProgress", "error_line", "run_command"]

#: what starts every line the commands print
PREFIX = "hemisphere_local_pass: "


class StderrProgress:
    """Percent, points/s and ETA on stderr, at most every ``interval`` seconds (and at the end);
    before the points, the job's stages (``stage(text)``), and while nothing else is printed a line
    every ``interval`` seconds saying what is running and for how long (from a daemon thread, stopped
    by ``stage(None)``), so a long export or preparation is never silent. The percent lines are spaced
    from each other, not from the heartbeat's lines: with chunks slower than ``interval / 4`` the
    heartbeat would otherwise always print first and no percent line would appear before 100 %."""

    def __init__(self, stream=None, interval=1.0):
        self.stream = stream if stream is not None else sys.stderr
        self.interval = interval
        self.start = None
        self.first = None
        self.last = 0.0
        self.last_points = 0.0  # when the last percent line was written
        self.text = None
        self.since = 0.0
        self.lock = threading.Lock()
        self.stop = None

    def _write(self, line):
        with self.lock:
            self.last = time.perf_counter()
            self.stream.write(f"{PREFIX}{line}\n")
            self.stream.flush()

    def stage(self, text):
        """A stage begins (None: the job is over)."""
        if text is None:
            if self.stop is not None:
                self.stop.set()
                self.stop = None
            self.text = None
            return
        now = time.perf_counter()
        head = text.split(":")[0]  # "exporting the scene: 3 objects ..." moves on within one stage
        if self.text is None or head != self.text.split(":")[0]:
            self.text, self.since = text, now
            self._write(text)
        else:
            self.text = text  # printed now if a line is due, else by the heartbeat
            if now - self.last >= self.interval:
                self._write(f"{text} ({now - self.since:.0f} s)")
        if self.stop is None:
            self.stop = threading.Event()
            threading.Thread(target=self._heartbeat, args=(self.stop,), daemon=True,
                             name="hlp-progress").start()

    def _heartbeat(self, stop):
        while not stop.wait(self.interval / 4):
            now = time.perf_counter()
            text = self.text
            if text is not None and now - self.last >= self.interval:
                self._write(f"{text} ({now - self.since:.0f} s)")

    def __call__(self, done, total):
        now = time.perf_counter()
        if self.start is None:
            self.start, self.first = now, done
            self.last_points = self.last  # the first percent line: an interval after the last line
        if now - self.last_points < self.interval and done < total:
            return
        self.last_points = now
        rate = (done - self.first) / (now - self.start) if now > self.start else 0.0
        eta = (total - done) / rate if rate > 0 else float("nan")
        pct = 100.0 * done / total if total else 100.0
        eta_s = f"{eta:.0f} s" if math.isfinite(eta) else "?"
        line = f"{pct:5.1f}% {done}/{total} points, {rate:.0f} points/s, ETA {eta_s}"
        self.text, self.since = line, now
        self._write(line)


def error_line(exc: BaseException) -> str:
    """``error: ...``, the one stderr line of a failed command: the first line of the message, prefixed
    by the exception's type unless it is a user error (ValueError, OSError)."""
    text = str(exc).strip()
    msg = text.splitlines()[0] if text else type(exc).__name__
    kind = "" if isinstance(exc, (ValueError, OSError)) else f"{type(exc).__name__}: "
    return f"error: {kind}{msg}"


def run_command(job, *, interrupted, cancelled) -> int:
    """Run one command's ``job()`` and return its exit code, the same way for every command.

    ``job()`` returns a report with ``summary()``, ``outputs`` (paths written) and optionally ``refused``
    (messages of outputs not written). Printed: the summary and one ``wrote PATH`` line per output on
    stdout, the refusals on stderr; exit 0. Ctrl-C: ``interrupted()`` (a callable: what is kept is known
    only then) on stderr, exit 130; the job's ``Cancelled``: ``cancelled`` on stderr, exit 130; any
    other error: its one line (:func:`error_line`) on stderr, exit 1 — the commands are for scripts and
    render farms, so every failure exits non-zero."""
    try:
        report = job()
    except KeyboardInterrupt:
        print(f"{PREFIX}{interrupted()}", file=sys.stderr)
        return 130
    except Exception as exc:
        from ..core import Cancelled

        if isinstance(exc, Cancelled):
            print(f"{PREFIX}{cancelled}", file=sys.stderr)
            return 130
        print(f"{PREFIX}{error_line(exc)}", file=sys.stderr)
        return 1
    print(f"{PREFIX}{report.summary()}")
    for path in report.outputs:
        print(f"{PREFIX}wrote {path}")
    for message in getattr(report, "refused", ()):
        print(f"{PREFIX}not written: {message}", file=sys.stderr)
    return 0
