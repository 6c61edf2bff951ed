"""Progress from the job's first moment (issue 14.16): the export, the ray casting and the scene
preparation are stages the job names as they begin, and while a stage runs a line goes out about
once a second, so a minute of export or preparation is never a minute of silence."""

import importlib
import importlib.util
import threading
import time

import pytest

bpy = pytest.importorskip("bpy")

from sample_loader import sample_module  # noqa: E402

SLOW = 2.6  # seconds the export is made to take


@pytest.fixture
def job(extension, scene):
    sample_module().build(1, resolution=6, reset=False)
    return importlib.import_module(extension.__name__ + ".blender.job")


class Recorder:
    """A stream that timestamps every line."""

    def __init__(self):
        self.lines = []
        self.t0 = time.perf_counter()

    def write(self, text):
        for line in text.splitlines():
            if line.strip():
                self.lines.append((time.perf_counter() - self.t0, line))

    def flush(self):
        pass


def slow_export(job, monkeypatch):
    export = importlib.import_module(job.__name__.rsplit(".", 1)[0] + ".scene_export")
    real = export.export_scene

    def slow(*args, **kw):
        time.sleep(SLOW)
        return real(*args, **kw)

    monkeypatch.setattr(export, "export_scene", slow)


def heartbeat_threads():
    time.sleep(0.3)
    return [t for t in threading.enumerate() if t.name == "hlp-progress" and t.is_alive()]


def test_cli_reports_every_stage_from_the_first_second(job, tmp_path, monkeypatch):
    slow_export(job, monkeypatch)
    rec = Recorder()
    real = importlib.import_module(job.__name__.rsplit(".", 1)[0] + ".stderr_lines").StderrProgress
    monkeypatch.setattr(job.__name__.rsplit(".", 1)[0] + ".cli.StderrProgress", lambda: real(stream=rec, interval=0.5))
    assert job.cli_main(["render", "-o", str(tmp_path / "x.exr"), "--no-preview"]) == 0
    times = [t for t, _ in rec.lines]
    text = [line for _, line in rec.lines]
    print("\n".join(f"{t:5.2f} {line}" for t, line in rec.lines))
    assert text[0] == "hemisphere_local_pass: exporting the scene" and times[0] < 0.5
    during = [t for t, line in rec.lines if "exporting the scene" in line and t < SLOW]
    assert len(during) >= 4 and max(b - a for a, b in zip(during, during[1:])) < 1.2  # every ~0.5 s
    first_points = next(i for i, line in enumerate(text) if "points/s" in line)
    for stage in ("exported ", "casting ", "preparing the scene", "computing "):
        assert any(line.startswith("hemisphere_local_pass: " + stage) for line in text[:first_points]), stage
    assert not heartbeat_threads()  # stopped with the job


def test_status_callback_and_stop_on_error(job, tmp_path, monkeypatch):
    seen = []
    rep = job.run_local_pass(preview=False, image=False, status=seen.append)
    assert rep.points > 0 and seen[0] == "exporting the scene" and seen[-1] is None
    assert any(s and s.startswith("preparing the scene") for s in seen)
    # an error in the export: the status is closed too, and the CLI's heartbeat stops
    bpy.data.objects["Floor"].data.attributes.remove(bpy.data.objects["Floor"].data.attributes["radiosity"])
    seen.clear()
    with pytest.raises(ValueError, match="has no attribute"):
        job.run_local_pass(preview=False, image=False, status=seen.append)
    assert seen[0] == "exporting the scene" and seen[-1] is None
    rec = Recorder()
    real = importlib.import_module(job.__name__.rsplit(".", 1)[0] + ".stderr_lines").StderrProgress
    monkeypatch.setattr(job.__name__.rsplit(".", 1)[0] + ".cli.StderrProgress", lambda: real(stream=rec, interval=0.2))
    assert job.cli_main(["render", "-o", str(tmp_path / "y.exr")]) == 1
    assert rec.lines[0][1] == "hemisphere_local_pass: exporting the scene"
    assert not heartbeat_threads()
