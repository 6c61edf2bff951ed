"""Where outputs may go: resolving an output path, the real reason a location cannot be written,
and the overwrite rule for existing files.

The rule (Blender's own for render outputs, made strict): an existing file is replaced only when

1. the user asked for it (``overwrite=True``: ``--overwrite`` on the command line, *Overwrite* of
   Blender's Output properties or the operator's *Overwrite* property in the UI), and
2. it is a file of ours of the kind being written, recognised by its content, never by its name:

   ==================== ===================================================================
   OpenEXR              the header string attribute ``hlp_software = hemisphere_local_pass``
                        (every EXR the job and ``merge`` write carries it)
   PNG preview          a ``tEXt`` chunk ``Software = hemisphere_local_pass`` before the image
                        data (added to every preview we write)
   checkpoint ``.npz``  a NumPy archive holding our keys (``fingerprint``, ``version``, ``done``)
   ==================== ===================================================================

A .blend file, a file of another program, a device, a FIFO or a directory is never replaced. A file
whose permission bits forbid writing (``chmod a-w``) is not replaced either. Symbolic links are
followed: the file written is the link's target, and the link stays.

Pure Python (no bpy) except :func:`resolve` for ``//`` paths.
"""

from __future__ import annotations

import errno
import os
import stat
import tempfile
import zipfile

__all__ = ["SOFTWARE", "OutputRefused", "check_new_or_ours", "check_writable", "checkpoint_path", "describe",
           "file_kind", "is_ours", "plan_outputs", "resolve", "umask", "unwritable_reason"]

#: Value of our ownership markers (EXR header attribute ``hlp_software``, PNG ``tEXt`` ``Software``).
SOFTWARE = "hemisphere_local_pass"
_EXR_MAGIC = b"\x76\x2f\x31\x01"
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
#: Kernel interfaces that look like directories but hold no user files.
_PSEUDO_FS = {"proc": "the kernel's process information", "sysfs": "the kernel's device and driver interface",
              "cgroup": "the kernel's control groups", "cgroup2": "the kernel's control groups",
              "debugfs": "a kernel debugging interface", "tracefs": "the kernel's tracing interface",
              "securityfs": "the kernel's security modules", "configfs": "a kernel configuration interface",
              "pstore": "kernel crash records", "efivarfs": "firmware variables", "bpf": "BPF objects",
              "fusectl": "the FUSE control interface", "autofs": "an automounter"}


class OutputRefused(ValueError):
    """An output path that must not be written (the message names the path and the reason)."""


def umask() -> int:
    """The process's umask (read from /proc on Linux, else set and restored at once)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    old = os.umask(0o022)
    os.umask(old)
    return old


def resolve(path) -> str:
    """``path`` made absolute: ``//`` relative to the saved .blend file (an error for an unsaved
    file, as Blender's own render output), else to the working directory; symbolic links followed
    to their target (so a link is written through, not replaced)."""
    path = os.fspath(path)
    if path.startswith("//"):
        import bpy

        if not bpy.data.filepath:
            raise OutputRefused(f"the output path '{path}' is relative to the .blend file ('//'), but this file "
                                "has not been saved: save the .blend file first, or give an absolute path")
        path = bpy.path.abspath(path)
    return os.path.realpath(os.path.abspath(path))


def _mount_of(folder: str):
    """(mount point, file-system type) of ``folder`` from /proc/self/mountinfo, or (None, None)."""
    best, kind = None, None
    try:
        with open("/proc/self/mountinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                left, _, right = line.partition(" - ")
                fields = left.split()
                if len(fields) < 5 or not right:
                    continue
                point = fields[4].replace("\\040", " ")
                inside = folder == point or folder.startswith(point.rstrip("/") + "/")
                if inside and (best is None or len(point) >= len(best)):
                    best, kind = point, right.split()[0]
    except OSError:
        return None, None
    return best, kind


def unwritable_reason(folder: str, exc: OSError | None = None) -> str:
    """Why no file can be created in ``folder`` (which exists), in the user's terms."""
    point, kind = _mount_of(folder)
    if kind in _PSEUDO_FS:
        return (f"'{point}' is a {kind} file system ({_PSEUDO_FS[kind]}, not storage): no files can be created "
                "there; choose a directory on a disk")
    code = getattr(exc, "errno", None)
    read_only = code == errno.EROFS
    try:
        read_only = read_only or bool(os.statvfs(folder).f_flag & os.ST_RDONLY)
    except (OSError, AttributeError):
        pass
    if read_only:
        where = f" (mounted read-only at '{point}')" if point else ""
        return f"the file system of '{folder}' is read-only{where}"
    if code in (errno.EACCES, errno.EPERM) or (exc is None and not os.access(folder, os.W_OK)):
        st = os.stat(folder)
        try:
            import pwd

            owner = pwd.getpwuid(st.st_uid).pw_name
        except (ImportError, KeyError):
            owner = str(st.st_uid)
        return (f"permission denied: no write permission in the directory '{folder}' "
                f"(owner {owner}, mode {stat.filemode(st.st_mode)})")
    if code == errno.ENOSPC:
        return f"no space left on the device of '{folder}'"
    if code == errno.EDQUOT:
        return f"disk quota exceeded in '{folder}'"
    return (exc.strerror if exc is not None and exc.strerror else str(exc)) or "unknown reason"


def check_writable(path) -> str:
    """Fail early (:class:`OutputRefused`, a ``ValueError``) when no file can be created at ``path``
    (the message gives the real reason); return the resolved path."""
    path = resolve(path)
    folder = os.path.dirname(path)
    if os.path.isdir(path):
        raise OutputRefused(f"output path '{path}' is a directory")
    if not os.path.exists(folder):
        parent = folder
        while parent and not os.path.exists(parent):
            up = os.path.dirname(parent)
            if os.path.exists(up) and os.path.isdir(up) and not os.access(up, os.X_OK):
                raise OutputRefused(f"cannot write '{path}': permission denied: the directory '{up}' cannot be "
                                    f"entered (mode {stat.filemode(os.stat(up).st_mode)})")
            if up == parent:
                break
            parent = up
        if parent and not os.path.isdir(parent):
            raise OutputRefused(f"cannot write '{path}': '{parent}' is a file, not a directory")
        raise OutputRefused(f"cannot write '{path}': the directory '{folder}' does not exist")
    if not os.path.isdir(folder):
        raise OutputRefused(f"cannot write '{path}': '{folder}' is not a directory")
    try:
        fd, probe = tempfile.mkstemp(prefix=".hlp-probe-", dir=folder)
    except OSError as exc:
        raise OutputRefused(f"cannot write '{path}': {unwritable_reason(folder, exc)}") from None
    os.close(fd)
    os.unlink(probe)
    return path


# ------------------------------------------------------------------------------- what a file is
def _head(path: str, size: int = 1 << 16) -> bytes:
    with open(path, "rb") as fh:
        return fh.read(size)


def file_kind(path: str) -> str:
    """What an existing regular file is, by content: ``exr``, ``png``, ``npz`` (zip), ``blend``
    (also compressed: gzip or zstd), ``empty`` or ``other``."""
    head = _head(path, 16)
    if not head:
        return "empty"
    if head.startswith(_EXR_MAGIC):
        return "exr"
    if head.startswith(_PNG_MAGIC):
        return "png"
    if head.startswith(b"PK\x03\x04"):
        return "npz"
    if head.startswith(b"BLENDER") or head.startswith(b"\x1f\x8b") or head.startswith(b"\x28\xb5\x2f\xfd"):
        return "blend"  # gzip/zstd: Blender's compressed .blend files (or another compressed file)
    return "other"


def _exr_strings(path: str) -> dict:
    """The string attributes of an OpenEXR file's (first) header."""
    buf = _head(path, 1 << 20)
    out, pos = {}, 8
    try:
        while pos < len(buf) and buf[pos] != 0:
            end = buf.index(b"\0", pos)
            end2 = buf.index(b"\0", end + 1)
            size = int.from_bytes(buf[end2 + 1:end2 + 5], "little", signed=True)
            if size < 0:
                break
            if buf[end + 1:end2] == b"string":
                out[buf[pos:end].decode("utf-8", "replace")] = buf[end2 + 5:end2 + 5 + size].decode("utf-8", "replace")
            pos = end2 + 5 + size
    except ValueError:
        pass
    return out


def _png_software(path: str) -> str | None:
    """The ``Software`` tEXt value of a PNG (chunks before the image data), or None."""
    buf = _head(path, 1 << 16)
    pos = 8
    while pos + 8 <= len(buf):
        length = int.from_bytes(buf[pos:pos + 4], "big")
        kind = buf[pos + 4:pos + 8]
        if kind == b"IDAT":
            return None
        if kind == b"tEXt":
            key, _, value = buf[pos + 8:pos + 8 + length].partition(b"\0")
            if key == b"Software":
                return value.decode("latin-1")
        pos += 12 + length
    return None


def is_ours(path: str, kind: str) -> bool:
    """Whether the existing file ``path`` is a ``kind`` (``exr``, ``png``, ``npz``) file we wrote."""
    try:
        found = file_kind(path)
        if found != kind:
            return False
        if kind == "exr":
            return _exr_strings(path).get("hlp_software") == SOFTWARE
        if kind == "png":
            return _png_software(path) == SOFTWARE
        if kind == "npz":
            with zipfile.ZipFile(path) as z:
                return {"fingerprint.npy", "version.npy", "done.npy"} <= set(z.namelist())
    except (OSError, zipfile.BadZipFile):
        return False
    return False


_KIND_NAMES = {"exr": "an OpenEXR image", "png": "a PNG image", "npz": "a NumPy/zip archive",
               "blend": "a .blend file (or a compressed file)", "empty": "an empty file", "other": "a file"}


def describe(path: str) -> str:
    """What the existing ``path`` is, for messages ("a .blend file", "a character device" ...)."""
    try:
        st = os.stat(path)
    except OSError:
        return "missing"
    if stat.S_ISDIR(st.st_mode):
        return "a directory"
    if not stat.S_ISREG(st.st_mode):
        for test, name in ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                           (stat.S_ISFIFO, "a named pipe (FIFO)"), (stat.S_ISSOCK, "a socket")):
            if test(st.st_mode):
                return name
        return "a special file"
    try:
        return _KIND_NAMES[file_kind(path)]
    except OSError as exc:
        return f"an unreadable file ({exc.strerror})"


def check_new_or_ours(path: str, kind: str, *, overwrite: bool, what: str, flag: str = "--overwrite") -> str:
    """Apply the overwrite rule to ``path`` (resolved, writable directory); return it or raise
    :class:`OutputRefused` naming the path and the reason.

    ``kind``: the file type being written (``exr``, ``png``, ``npz``); ``what``: its role in
    messages ("output image", "preview", "checkpoint").
    """
    path = resolve(path)
    if not os.path.lexists(path):
        return path
    st = os.stat(path)
    if not stat.S_ISREG(st.st_mode):
        raise OutputRefused(f"{what} '{path}' exists and is {describe(path)}: it is never replaced")
    if not is_ours(path, kind):
        found = describe(path)
        mine = {"exr": "OpenEXR", "png": "PNG", "npz": "checkpoint"}[kind]
        detail = f"{found} not written by hemisphere_local_pass" if found == _KIND_NAMES.get(kind) else found
        raise OutputRefused(f"{what} '{path}' exists and is {detail}: it is never replaced (only {mine} files "
                            "this extension wrote are); choose another file name")
    if not st.st_mode & 0o222:
        raise OutputRefused(f"{what} '{path}' exists and is read-only (mode {stat.filemode(st.st_mode)}): "
                            "not replaced")
    if not overwrite:
        raise OutputRefused(f"{what} '{path}' exists (written by an earlier local pass); it is replaced only "
                            f"when you ask: {flag} on the command line; in Blender, Output Properties > Output > "
                            "Overwrite (or the operator's Overwrite option)")
    return path


def checkpoint_path(output: str) -> str:
    """The checkpoint file of the job writing ``output``."""
    return output + ".checkpoint.npz"


def plan_outputs(output, *, mode: str, tile=None, preview: bool = True, overwrite: bool = False,
                 resume: bool = False, flag: str = "--overwrite"):
    """Check every file a job will write before it starts -> ``(output, png or None, refused)``.

    ``output`` resolved (absolute, ``//``, symbolic links followed) and writable; pixels mode: the
    EXR follows the overwrite rule (a refusal is an :class:`OutputRefused` error). The checkpoint
    ``OUTPUT.checkpoint.npz`` is never a file of someone else's, and an interrupted run's checkpoint
    is taken over only with ``resume`` (or replaced with ``overwrite``). The PNG preview (pixels
    mode, not for a tile: ``merge`` writes the whole image's) follows the same rule, but a refused
    preview does not stop the job: it is returned in ``refused`` (messages naming the path).
    """
    output = check_writable(output)
    if mode == "pixels":
        check_new_or_ours(output, "exr", overwrite=overwrite, what="output image", flag=flag)
    ck = checkpoint_path(output)
    if os.path.lexists(ck):
        if not os.path.isfile(ck) or not is_ours(ck, "npz"):
            raise OutputRefused(f"checkpoint '{ck}' exists and is {describe(ck)} not written by this extension: "
                                "it is never replaced; move it away or choose another output name")
        if not (resume or overwrite):
            raise OutputRefused(f"checkpoint '{ck}' of an interrupted run exists: pass --resume to continue it, "
                                f"or {flag} to start again and replace it")
    png = None
    refused = []
    if mode == "pixels" and preview and tile is None:
        png = os.path.splitext(output)[0] + ".png"
        try:
            if png == output:
                raise OutputRefused(f"preview '{png}' would be the output image itself: not written")
            png = check_new_or_ours(png, "png", overwrite=overwrite, what="preview", flag=flag)
        except OutputRefused as exc:
            png = None
            refused.append(str(exc))
    return output, png, refused
