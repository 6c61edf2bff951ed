"""Ctrl-C during a job: the first SIGINT stops it, on every Blender.

Blender in background mode installs its own C handler for SIGINT: Blender 3.4's first Ctrl-C only
prints "Sent an internal break event" (a flag no Python code reads) and the job runs on; a second
kills the process with no message. The bpy module leaves Python's handler (``KeyboardInterrupt``).

:func:`stops_on_first_sigint` wraps the job function: for its duration SIGINT raises
``KeyboardInterrupt`` in the main thread (Python checks for signals between bytecodes, and the core
is numpy calls of milliseconds, so the job stops within a fraction of a second); the job's
``KeyboardInterrupt`` path keeps the finished chunks in the checkpoint. Afterwards the previous
handler is restored exactly: the C-level ``struct sigaction`` is saved and restored with ``sigaction``
through ctypes (Python cannot restore a handler it did not install; ``signal.getsignal`` returns
None for Blender's), and Python's own table is restored too.

Not in the main thread (signals go to the main thread only), nested calls and platforms without
``sigaction`` (Windows: Python's own SIGINT handling is kept) are handled.
"""

from __future__ import annotations

import functools
import signal
import threading

__all__ = ["sigint_raises", "stops_on_first_sigint"]

_depth = 0
#: Bytes reserved for a ``struct sigaction`` (152 on Linux x86-64/arm64, 16 on macOS).
_SIGACTION_SIZE = 512


def _libc_sigaction():
    """libc's ``sigaction`` via ctypes, or None where there is none."""
    try:
        import ctypes
        import os

        if os.name != "posix":
            return None
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.sigaction
    except (ImportError, OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p]
    fn.restype = ctypes.c_int
    return fn


def _raise_keyboard_interrupt(signum, frame):
    raise KeyboardInterrupt("interrupted (Ctrl-C)")


class sigint_raises:  # noqa: N801 (a context manager used like a function)
    """``with sigint_raises():`` SIGINT raises ``KeyboardInterrupt`` inside the block; the previous
    handler (Python's or Blender's C handler) is restored on exit."""

    def __enter__(self):
        global _depth
        self.active = _depth == 0 and threading.current_thread() is threading.main_thread()
        _depth += 1
        if not self.active:
            return self
        import ctypes

        self.saved = None
        self.sigaction = _libc_sigaction()
        if self.sigaction is not None:
            buf = ctypes.create_string_buffer(_SIGACTION_SIZE)
            if self.sigaction(signal.SIGINT, None, ctypes.addressof(buf)) == 0:
                self.saved = buf
        self.python_handler = signal.getsignal(signal.SIGINT)
        signal.signal(signal.SIGINT, _raise_keyboard_interrupt)
        return self

    def __exit__(self, *exc):
        global _depth
        _depth -= 1
        if not self.active:
            return False
        import ctypes

        previous = self.python_handler
        if previous is None:  # a handler Python did not install (Blender's): its table says "ignore"
            # until the C handler is back (SIG_DFL here would let a Ctrl-C in between kill the process)
            previous = signal.SIG_IGN if self.saved is not None else signal.default_int_handler
        signal.signal(signal.SIGINT, previous)
        if self.saved is not None:  # the exact C-level handler, mask and flags
            self.sigaction(signal.SIGINT, ctypes.addressof(self.saved), None)
        return False


def stops_on_first_sigint(fn):
    """Decorator: run ``fn`` inside :class:`sigint_raises`."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with sigint_raises():
            return fn(*args, **kwargs)

    return wrapper
