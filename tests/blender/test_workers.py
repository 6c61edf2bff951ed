"""Worker processes from the bpy module: the installed extension's job on a pool gives the same bits as
in one process, the workers import only the core (from ``bl_ext.<repo>.hemisphere_local_pass``, without
bpy), and cancel leaves no process behind."""

import importlib
import os
import sys

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from test_io_job import build_box  # noqa: E402


def _children() -> set:
    me = str(os.getpid())
    out = set()
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as fh:
                    fields = fh.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if fields[1] == me and fields[0] != "Z":
                out.add(int(entry))
    return out


@pytest.fixture
def mods(extension, scene):
    base = extension.__name__
    return {name: importlib.import_module(f"{base}.{name}") for name in ("blender.job", "core", "core.parallel")}


def test_workers_of_the_installed_extension_import_only_its_core(mods):
    parallel = mods["core.parallel"]
    assert parallel.__name__.startswith("bl_ext.")
    exe = parallel.worker_python()
    assert os.path.basename(exe).startswith("python") and exe.startswith(sys.prefix), (exe, sys.prefix)
    with parallel.WorkerPool(1) as pool:
        modules = pool.submit(eval, "sorted(__import__('sys').modules)").result(timeout=60)
    package = parallel.__name__.rsplit(".", 2)[0]
    assert any(m.startswith(package + ".core.") for m in modules)
    assert not [m for m in modules if m == "bpy" or m.startswith((package + ".blender", "_bpy", "mathutils"))]


def test_job_on_workers_is_bit_identical_and_leaves_no_process(mods, tmp_path, monkeypatch):
    job = mods["blender.job"]
    build_box(resolution=16)
    monkeypatch.setattr(job.__name__.rsplit(".", 1)[0] + ".receiver_chunks.MIN_CHUNK", 32)  # 256 points, 8 job chunks
    before = _children()
    one = job.run_local_pass(output=str(tmp_path / "one.exr"), preview=False, workers=1)
    two = job.run_local_pass(output=str(tmp_path / "two.exr"), preview=False, workers=2)
    assert one.workers == 1 and two.workers == 2 and "2 workers" in two.summary()
    for key in ("radiance", "irradiance", "form_factor_sum"):
        assert np.array_equal(one.result[key], two.result[key]), key
    with open(tmp_path / "one.exr", "rb") as a, open(tmp_path / "two.exr", "rb") as b:
        assert a.read() == b.read()
    assert _children() == before

    # the scene setting (0: every core) is the default; the operator passes it
    settings = bpy.context.scene.hlp_settings
    assert settings.workers == 0
    ops = importlib.import_module(job.__name__.rsplit(".", 1)[0] + ".operators")
    assert ops.job_arguments(bpy.context.scene, settings)["workers"] == 0
    with pytest.raises(ValueError, match="workers"):
        job.run_local_pass(workers=-2)
    assert job.build_parser().parse_args(["render", "-o", "x.exr", "--workers", "3"]).workers == 3
    assert job.build_parser().parse_args(["render", "-o", "x.exr"]).workers is None  # the scene setting


def test_cancel_and_ctrl_c_with_workers_stop_every_process(mods, tmp_path, monkeypatch):
    job, core = mods["blender.job"], mods["core"]
    build_box(resolution=16)
    monkeypatch.setattr(job.__name__.rsplit(".", 1)[0] + ".receiver_chunks.MIN_CHUNK", 32)
    before = _children()
    seen = {"n": 0}

    def progress(done, total):
        seen["n"] += 1

    with pytest.raises(core.Cancelled):
        job.run_local_pass(output=str(tmp_path / "c.exr"), preview=False, workers=2, progress=progress,
                           cancel=lambda: seen["n"] > 0)
    assert _children() == before

    def interrupt(done, total):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):  # the cancelled run's checkpoint is ours to replace
        job.run_local_pass(output=str(tmp_path / "c.exr"), preview=False, workers=2, progress=interrupt,
                           overwrite=True)
    assert _children() == before
    # the finished chunks are in the checkpoint; resuming on one process gives the same file as a clean run
    rep = job.run_local_pass(output=str(tmp_path / "c.exr"), preview=False, workers=1, resume=True)
    assert rep.resumed_points > 0
    job.run_local_pass(output=str(tmp_path / "ref.exr"), preview=False, workers=1)
    with open(tmp_path / "c.exr", "rb") as a, open(tmp_path / "ref.exr", "rb") as b:
        assert a.read() == b.read()


def test_a_killed_worker_fails_the_job_with_a_clear_error(mods, tmp_path, monkeypatch):
    import signal

    job, parallel = mods["blender.job"], mods["core.parallel"]
    build_box(resolution=16)
    monkeypatch.setattr(job.__name__.rsplit(".", 1)[0] + ".receiver_chunks.MIN_CHUNK", 16)  # 16 job chunks
    before = _children()
    killed = []

    def progress(done, total):
        workers = sorted(_children() - before)
        if workers and not killed:
            os.kill(workers[0], signal.SIGKILL)
            killed.append(workers[0])

    with pytest.raises(parallel.WorkerDied, match=r"killed by SIGKILL") as info:
        job.run_local_pass(output=str(tmp_path / "k.exr"), preview=False, workers=2, progress=progress)
    assert str(killed[0]) in str(info.value)
    assert isinstance(info.value, RuntimeError)  # the operator reports RuntimeErrors, the CLI exits 1
    assert _children() == before
