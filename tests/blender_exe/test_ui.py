"""Tier 3, issue 12: the render engine from Blender's own command line, and Blender's real window
under Xvfb driven by scripts/ui_session.py with xdotool input (the panels, the modal job with its
status-bar progress, Esc, the inspector at a known point). Every run must exit 0 with nothing on stderr."""

import json
import os

import pytest
from conftest import ROOT, assert_clean, run_blender

HEADLESS = ["-b", "--factory-startup", "--python-exit-code", "1"]


@pytest.fixture(scope="module")
def box_blend(blender, tmp_path_factory):
    """The sample Cornell box (subdivisions 2: 60 polygons, 16 x 16 pixels), built by Blender 3.4."""
    out = tmp_path_factory.mktemp("box") / "cornell_box.blend"
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    script = os.path.join(ROOT, "sample_scenes", "cornell_box.py")
    cmd = [blender, *HEADLESS, "--python", script, "--", str(out), "--subdivisions", "2", "--resolution", "16"]
    result = run_blender(cmd, env)
    assert result.returncode == 0 and out.exists(), result.stdout + result.stderr
    return str(out)


def test_minus_E_renders_frames(blender, blender_env, addon_scripts_dir, box_blend, tmp_path):
    """``blender -b file.blend -E HEMISPHERE_LOCAL_PASS -f 1`` and ``-a``: what a render farm runs."""
    out = tmp_path / "frame_"
    cmd = [blender, "-b", box_blend, "--addons", "hemisphere_local_pass", "-E", "HEMISPHERE_LOCAL_PASS",
           "-o", str(out) + "####", "-F", "PNG", "-f", "1"]
    result = run_blender(cmd, blender_env, timeout=300)
    assert_clean(result)
    assert (tmp_path / "frame_0001.png").is_file(), result.stdout
    assert "points/s" in result.stdout and "max |sum F - 1|" in result.stdout, result.stdout
    cmd = [blender, "-b", box_blend, "--addons", "hemisphere_local_pass", "-E", "HEMISPHERE_LOCAL_PASS",
           "-o", str(out) + "####", "-F", "PNG", "-s", "2", "-e", "3", "-a"]
    result = run_blender(cmd, blender_env, timeout=300)
    assert_clean(result)
    assert (tmp_path / "frame_0002.png").is_file() and (tmp_path / "frame_0003.png").is_file(), result.stdout


def test_real_window_panels_modal_job_esc_and_inspector(blender, xvfb_run, blender_env, box_blend, tmp_path):
    shots = tmp_path / "shots"
    result_file = tmp_path / "ui.json"
    cmd = [xvfb_run, "-a", "-s", "-screen 0 1280x800x24", blender, "--factory-startup", box_blend,
           "--window-geometry", "0", "0", "1280", "800", "--python", os.path.join(ROOT, "scripts", "ui_session.py"),
           "--", "--out", str(shots), "--result", str(result_file), "--resolution", "16"]
    env = dict(blender_env, LIBGL_ALWAYS_SOFTWARE="1")
    result = run_blender(cmd, env, timeout=600)
    report = f"exit {result.returncode}\n--- stdout\n{result.stdout}\n--- stderr\n{result.stderr}"
    assert result_file.exists(), report
    info = json.loads(result_file.read_text())
    assert info["ok"], f"{info.get('error')}\n{report}"

    modal = info["modal"]
    assert modal["started"] == ["RUNNING_MODAL"], modal
    assert 0.0 < modal["first"]["fraction"] < 1.0, modal  # the screenshot is taken mid-run
    assert modal["second"]["status"] > modal["first"]["status"], "the status bar must keep redrawing"
    assert "points/s" in modal["second"]["text"] and "ETA" in modal["second"]["text"], modal
    assert modal["finished"] and modal["shown"] == "Local Pass", modal
    assert "max |sum F - 1|" in modal["summary"], modal

    esc = info["esc"]  # the modal bake, Esc: cancelled within a second of the key press, nothing written
    assert esc["running_before"] and esc["cancelled"] and esc["unchanged"], esc
    assert esc["done_at_esc"] < esc["total"], esc
    assert esc["latency"] <= 1.0, esc
    assert esc["workers"] >= 1 and esc["workers_left"] == [], esc  # the run's workers are gone after Esc

    f12 = info["f12_esc"]  # F12, then Esc: the render stops within a second of the key press, bands kept
    assert f12["started"] and f12["stopped"] and f12["cancelled"], f12
    assert 1 <= f12["bands"] < f12["n_bands"] and f12["done"] < f12["total"], f12
    assert f12["stop"] < 1.0, f12  # test_break()'s first True -> the render result ended (ours)
    assert f12["latency"] <= 1.0, f12  # the Esc key press -> the job had stopped for it (end to end)
    assert len(f12["worker_pids"]) == 1 and f12["workers_left"] == [], f12  # one pool, gone with the job

    ins = info["inspector"]
    assert ins["snapped_error"] < 0.02 and ins["normal"] == [0.0, 0.0, 1.0] and ins["point"][2] == 0.0, ins
    assert ins["rows_equal_core"] and ins["rows"] > 10, ins
    assert ins["form_factor_sum"] == ins["core_form_factor_sum"] and ins["irradiance"] == ins["core_irradiance"]
    assert ins["panel_draws"] > ins["panel_draws_at_click"] >= 0, "the sidebar list must draw after the click"
    assert ins["changed_pixels_near_point"] > 300, ins  # the overlay is drawn where the point projects
    drag = info["inspector_drag"]
    assert drag["moved"] > 0.01 and drag["on_floor"] and drag["towards_x"], drag  # dragging moves it live
    assert info["inspector_recoloured"] == {"same_point": True, "same_sum": True}
    assert info["inspector_left"] == {"cleared": True, "handlers": 0}
    bake = info["bake"]
    assert bake["finished"] and bake["active"] == "hlp_radiance", bake
    assert bake["shading"] == "SOLID" and bake["color_type"] == "VERTEX", bake
    assert bake["attributes"] == ["hlp_irradiance", "hlp_radiance"], bake
    for name in ("ui_engine_panels", "ui_other_engine", "ui_progress", "ui_result", "ui_inspector"):
        assert (shots / f"{name}.png").stat().st_size > 10_000, name
    assert_clean(result)
