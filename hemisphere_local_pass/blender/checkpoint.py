"""Checkpoint and resume of a job's receivers.

Receivers are evaluated in chunks of fixed size (a function of the job only, :mod:`.receiver_chunks`),
so a run that was interrupted and resumed computes exactly the same chunks as an uninterrupted one
and writes the same file. Finished chunks go to ``<output>.checkpoint.npz`` (replaced atomically
after each chunk, removed when the job completes); ``resume=True`` continues from it if its
fingerprint (:func:`digest` of the scene and the receivers) matches the job.
"""

from __future__ import annotations

import hashlib
import os

import numpy as np

__all__ = ["CHECKPOINT_VERSION", "Checkpoint", "digest"]

CHECKPOINT_VERSION = 2  # 2: the error bound of H (far field) is stored too


def digest(*arrays) -> str:
    """SHA-1 of arrays (dtype, shape and bytes) and other values (their repr): a job's fingerprint."""
    h = hashlib.sha1()
    for a in arrays:
        if isinstance(a, np.ndarray):
            h.update(str(a.dtype).encode() + str(a.shape).encode())
            h.update(np.ascontiguousarray(a).tobytes())
        else:
            h.update(repr(a).encode())
    return h.hexdigest()


class Checkpoint:
    """Finished chunks of a job: ``<output>.checkpoint.npz``, replaced atomically after each chunk."""

    def __init__(self, path, fingerprint, m, chunk):
        self.path = path
        self.fingerprint = fingerprint
        self.chunk = chunk
        n_chunks = (m + chunk - 1) // chunk
        self.done = np.zeros(n_chunks, dtype=bool)
        self.h = np.zeros((m, 3))
        self.fsum = np.zeros(m)
        self.bound = np.zeros((m, 3))  # bound on |H - exact H| (W m^-2), 0 where exact

    def load(self) -> bool:
        """Take over a matching checkpoint file; False when there is none or it belongs to another job."""
        if self.path is None or not os.path.isfile(self.path):
            return False
        try:
            with np.load(self.path, allow_pickle=False) as z:
                if (str(z["fingerprint"]) != self.fingerprint or int(z["chunk"]) != self.chunk
                        or z["h"].shape != self.h.shape or int(z["version"]) != CHECKPOINT_VERSION):
                    return False
                self.done[:] = z["done"]
                self.h[:] = z["h"]
                self.fsum[:] = z["fsum"]
                self.bound[:] = z["bound"]
        except (OSError, KeyError, ValueError):
            return False
        return True

    def save(self):
        if self.path is None:
            return
        from .outputs import replace_atomically

        def write(tmp):
            with open(tmp, "wb") as fh:
                np.savez(fh, fingerprint=np.array(self.fingerprint), chunk=np.array(self.chunk), done=self.done,
                         h=self.h, fsum=self.fsum, bound=self.bound, version=np.array(CHECKPOINT_VERSION))

        replace_atomically(self.path, write)

    def remove(self):
        if self.path is not None and os.path.isfile(self.path):
            os.unlink(self.path)
