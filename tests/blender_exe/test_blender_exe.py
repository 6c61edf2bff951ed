"""Tier 3: the package in a real Blender executable (Debian's 3.4), headless and under Xvfb.

Blender 3.4 has no extensions and no ``--command``: the package loads as a legacy add-on
(``bl_info``) and batch jobs go through ``hemisphere_local_pass.run_local_pass`` in ``--python-expr``.
Every run must exit 0 with nothing on stderr (``--python-exit-code 1`` turns a Python error into a
non-zero exit; Blender prints the traceback on stdout, which is checked too).
"""

import json
import os
import subprocess
import sys

import pytest
from conftest import ROOT, assert_clean, python_expr, run_blender

HEADLESS = ["-b", "--factory-startup", "--python-exit-code", "1"]


def assert_no_python_error(result):
    for marker in ("Traceback", "Error: Python", "Error: script failed"):
        assert marker not in result.stdout, f"--- stdout\n{result.stdout}\n--- stderr\n{result.stderr}"


def result_json(result, tag="HLP-RESULT "):
    """The JSON object a --python-expr printed on a line starting with ``tag``."""
    lines = [line[len(tag) :] for line in result.stdout.splitlines() if line.startswith(tag)]
    assert lines, f"no {tag!r} line\n--- stdout\n{result.stdout}\n--- stderr\n{result.stderr}"
    return json.loads(lines[-1])


def test_blender_version(blender, blender_env):
    result = run_blender([blender, "--version"], blender_env)
    assert_clean(result)
    assert result.stdout.startswith("Blender "), result.stdout


def test_loads_as_legacy_addon_with_addons_flag(blender, blender_env, addon_scripts_dir):
    expr = "\n".join(
        (
            "import bpy, json, addon_utils",
            "info = {'enabled': addon_utils.check('hemisphere_local_pass'),",
            "        'settings': hasattr(bpy.types.Scene, 'hlp_settings'),",
            "        'operator': hasattr(bpy.types, 'HLP_OT_render_local_pass'),",
            "        'panel': hasattr(bpy.types, 'HLP_PT_local_pass'),",
            "        'attribute': bpy.context.scene.hlp_settings.attribute}",
            "print('HLP-RESULT ' + json.dumps(info))",
        )
    )
    result = run_blender([blender, *HEADLESS, "--addons", "hemisphere_local_pass", "--python-expr", expr], blender_env)
    assert_clean(result)
    assert_no_python_error(result)
    info = result_json(result)
    assert info == {
        "enabled": [True, True],
        "settings": True,
        "operator": True,
        "panel": True,
        "attribute": "radiosity",
    }


def test_register_unregister_twice_via_python_expr(blender, blender_env):
    expr = python_expr(
        "import bpy, json, hemisphere_local_pass as h",
        "from hemisphere_local_pass.blender import registration",
        "states = []",
        "def state():",
        "    return [hasattr(bpy.types.Scene, 'hlp_settings'), hasattr(bpy.types, 'HLP_OT_render_local_pass'),",
        "            hasattr(bpy.types, 'HLP_PT_local_pass'), all(c.is_registered for c in registration.classes)]",
        "for _ in range(2):",
        "    h.register(); states.append(state())",
        "    h.unregister(); states.append(state())",
        "h.register()",
        "info = {'states': states, 'cli': registration._cli_handle is not None,",
        "        'has_cli_api': hasattr(bpy.utils, 'register_cli_command'),",
        "        'tooltip': bpy.ops.hlp.render_local_pass.get_rna_type().description,",
        "        'doc': bpy.types.HLP_OT_render_local_pass.__doc__.strip()}",
        "h.unregister()",
        "print('HLP-RESULT ' + json.dumps(info))",
    )
    result = run_blender([blender, *HEADLESS, "--python-expr", expr], blender_env)
    assert_clean(result)
    assert_no_python_error(result)
    info = result_json(result)
    assert info["states"] == [[True] * 4, [False] * 4] * 2
    assert info["cli"] is info["has_cli_api"], "the CLI command is registered exactly where Blender has the API"
    assert info["tooltip"] == info["doc"]


def test_import_does_not_import_bpy_in_blenders_python(blender, blender_env):
    expr = python_expr(
        "import sys; sys.modules.pop('hemisphere_local_pass', None)",
        "import bpy",  # already imported by Blender; check only that the package needs no more
        "import hemisphere_local_pass, hemisphere_local_pass.core, json",
        "print('HLP-RESULT ' + json.dumps({'blender_mods': sorted(m for m in sys.modules",
        "      if m.startswith('hemisphere_local_pass.blender'))}))",
    )
    result = run_blender([blender, *HEADLESS, "--python-expr", expr], blender_env)
    assert_clean(result)
    assert_no_python_error(result)
    assert result_json(result)["blender_mods"] == []


def test_operator_reports_missing_attribute(blender, blender_env):
    """The factory scene's cube has no radiosity attribute: the operator reports one clear error."""
    expr = python_expr(
        "import bpy, json, hemisphere_local_pass as h",
        "h.register()",
        "bpy.context.scene.hlp_settings.output_path = ''",
        "try:",
        "    bpy.ops.hlp.render_local_pass()",
        "    message = None",
        "except RuntimeError as ex:",
        "    message = str(ex)",
        "h.unregister()",
        "print('HLP-RESULT ' + json.dumps({'message': message}))",
    )
    result = run_blender([blender, *HEADLESS, "--python-expr", expr], blender_env)
    assert_clean(result)
    message = result_json(result)["message"]
    assert message is not None, "the operator must fail on a scene without the attribute"
    assert "Traceback" not in message, message
    assert "radiosity" in message and "Cube" in message, message


# ------------------------------------------------------------------------------ the real job
@pytest.fixture(scope="module")
def sample_blend(blender, tmp_path_factory):
    """The bundled Cornell box sample scene, built by Blender 3.4 from sample_scenes/cornell_box.py."""
    out = tmp_path_factory.mktemp("sample") / "cornell_box.blend"
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    script = os.path.join(ROOT, "sample_scenes", "cornell_box.py")
    cmd = [blender, *HEADLESS, "--python", script, "--", str(out), "--subdivisions", "1", "--resolution", "16"]
    result = run_blender(cmd, env)
    assert result.returncode == 0 and out.exists(), result.stdout + result.stderr
    return str(out)


def test_render_sample_scene_to_exr(blender, blender_env, sample_blend, tmp_path):
    """``blender -b scene.blend --python-expr`` renders the sample scene to a multi-channel EXR.

    Blender 3.4 gets no openexr wheel (it would clash with its own OpenEXR library): the job writes
    the file without it there.
    """
    exr = tmp_path / "cornell_box.exr"
    expr = python_expr(
        "import bpy, json, hemisphere_local_pass as h",
        f"report = h.run_local_pass(output={str(exr)!r}, mode='pixels', samples=1)",
        "image = bpy.data.images.get('Local Pass')",
        "print('HLP-RESULT ' + json.dumps({'points': report.points, 'outputs': report.outputs,",
        "      'image': list(image.size) if image else None, 'ff_error': report.max_form_factor_error}))",
    )
    result = run_blender([blender, *HEADLESS, sample_blend, "--python-expr", expr], blender_env)
    assert_clean(result)
    assert_no_python_error(result)
    info = result_json(result)
    assert info["points"] > 0
    assert str(exr) in info["outputs"] and exr.exists()
    assert info["image"] and info["image"][0] > 0 and info["image"][1] > 0
    assert info["ff_error"] < 1e-6, "closed box seen from inside: the form factors sum to 1"

    # The EXR reads back with OpenEXR in plain Python (the core venv has openexr) ...
    import numpy as np
    import OpenEXR

    with OpenEXR.File(str(exr)) as f:
        channels = f.channels()
        assert channels, "no channels"
        for name, channel in channels.items():
            assert np.all(np.isfinite(np.asarray(channel.pixels, dtype=np.float64))), name

    # ... and in Blender.
    check = python_expr(
        "import bpy, json",
        f"img = bpy.data.images.load({str(exr)!r})",
        "print('HLP-RESULT ' + json.dumps({'size': list(img.size)}))",
    )
    result = run_blender([blender, *HEADLESS, "--python-expr", check], blender_env)
    assert_clean(result)
    assert_no_python_error(result)
    assert result_json(result)["size"] == info["image"]


def test_vertex_colours_written_and_saved(blender, blender_env, sample_blend, tmp_path):
    """Vertices mode on the selected meshes writes hlp_radiance/hlp_irradiance; they survive save/reload."""
    saved = tmp_path / "with_colours.blend"
    expr = python_expr(
        "import bpy, json, hemisphere_local_pass as h",
        "for ob in bpy.context.scene.objects:",
        "    ob.select_set(ob.type == 'MESH')",
        "report = h.run_local_pass(mode='vertices')",
        f"bpy.ops.wm.save_as_mainfile(filepath={str(saved)!r})",
        "print('HLP-RESULT ' + json.dumps({'points': report.points, 'outputs': report.outputs}))",
    )
    result = run_blender([blender, *HEADLESS, sample_blend, "--python-expr", expr], blender_env)
    assert_clean(result)
    assert_no_python_error(result)
    info = result_json(result)
    assert info["points"] > 0
    assert saved.exists()

    check = python_expr(
        "import bpy, json",
        "attrs = {ob.name: sorted((a.name, a.domain, a.data_type) for a in ob.data.attributes",
        "                         if a.name.startswith('hlp_')) for ob in bpy.data.objects if ob.type == 'MESH'}",
        "import numpy as np",
        "finite = all(np.all(np.isfinite([c for v in ob.data.attributes[n].data for c in v.color]))",
        "             for ob in bpy.data.objects if ob.type == 'MESH' for n in ('hlp_radiance', 'hlp_irradiance'))",
        "print('HLP-RESULT ' + json.dumps({'attrs': attrs, 'finite': bool(finite)}))",
    )
    result = run_blender([blender, *HEADLESS, str(saved), "--python-expr", check], blender_env)
    assert_clean(result)
    assert_no_python_error(result)
    back = result_json(result)
    assert back["attrs"], "no meshes"
    for name, attrs in back["attrs"].items():
        assert [a[0] for a in attrs] == ["hlp_irradiance", "hlp_radiance"], (name, attrs)
        assert all(a[2] == "FLOAT_COLOR" and a[1] in ("POINT", "CORNER") for a in attrs), (name, attrs)
    assert back["finite"]


# ------------------------------------------------------------------------------------ the UI
UI_EXPR = """
import json, os, sys, traceback
import bpy
from hemisphere_local_pass.blender import panels
import hemisphere_local_pass as h

RESULT = {result!r}
SHOT = {shot!r}
state = {{'drawn': False, 'ticks': 0, 'operator': None}}
cls = panels.HLP_PT_local_pass
cls.bl_options = set()  # open the panel so its body draws
_draw = cls.draw
def draw(self, context):
    _draw(self, context)
    state['drawn'] = True
cls.draw = draw
h.register()

def finish(ok, **extra):
    state.update(extra)
    with open(RESULT, 'w') as fh:
        json.dump({{'ok': ok, **{{k: v for k, v in state.items()}}}}, fh)
    bpy.ops.wm.quit_blender()

def tick():
    try:
        state['ticks'] += 1
        window = bpy.context.window_manager.windows[0]
        areas = [a for a in window.screen.areas if a.type == 'PROPERTIES']
        if not areas:
            finish(False, error='no Properties editor in the factory layout')
            return None
        area = areas[0]
        if area.spaces.active.context != 'RENDER':
            area.spaces.active.context = 'RENDER'
        area.tag_redraw()
        if state['drawn']:
            with bpy.context.temp_override(window=window, area=area):
                bpy.ops.screen.screenshot(filepath=SHOT)
                scene = window.scene
                scene.hlp_settings.output_path = ''
                try:
                    bpy.ops.hlp.render_local_pass()
                    state['operator'] = 'FINISHED'
                except RuntimeError as ex:
                    state['operator'] = str(ex)
            finish(True)
            return None
        if state['ticks'] > 60:
            finish(False, error='the panel never drew')
            return None
        return 0.25
    except Exception:
        finish(False, error=traceback.format_exc())
        return None

bpy.app.timers.register(tick, first_interval=0.5)
"""


def test_panel_draws_and_operator_runs_in_the_ui(blender, xvfb_run, blender_env, sample_blend, tmp_path):
    """Blender's real UI under Xvfb: the Render tab shows the panel; the operator runs with a window."""
    result_file = tmp_path / "ui.json"
    shot = tmp_path / "ui.png"
    expr = python_expr(UI_EXPR.format(result=str(result_file), shot=str(shot)))
    cmd = [
        xvfb_run, "-a", "-s", "-screen 0 1280x800x24",
        blender, "--factory-startup", "--python-exit-code", "1", sample_blend, "--python-expr", expr,
    ]  # fmt: skip
    env = dict(blender_env, LIBGL_ALWAYS_SOFTWARE="1")
    result = run_blender(cmd, env, timeout=300)
    report = f"exit {result.returncode}\n--- stdout\n{result.stdout}\n--- stderr\n{result.stderr}"
    assert result_file.exists(), report
    info = json.loads(result_file.read_text())
    assert info["ok"], f"{info}\n{report}"
    assert info["drawn"]
    assert info["operator"] == "FINISHED", info
    assert shot.exists() and shot.stat().st_size > 0
    assert_clean(result)
    assert_no_python_error(result)


def test_subprocess_python_is_not_blenders():
    """Sanity: this test process is plain Python (the core venv), not Blender's."""
    assert "bpy" not in sys.modules
    assert subprocess.run([sys.executable, "-c", "import hemisphere_local_pass"], cwd=ROOT).returncode == 0


def test_workers_under_blender_34(blender, blender_env, sample_blend, tmp_path):
    """Blender 3.4's ``sys.executable`` is whatever ``python3.11`` comes first on PATH (here possibly a
    pyenv shim without Debian's numpy): the workers run the Python of Blender's own installation
    (``sys.prefix``), import only the core, and give the same file as one process."""
    one, two = tmp_path / "one.exr", tmp_path / "two.exr"
    expr = python_expr(
        "import bpy, json, os, sys, hemisphere_local_pass as h",
        "from hemisphere_local_pass.core import parallel",
        "from hemisphere_local_pass.blender import receiver_chunks",
        "receiver_chunks.MIN_CHUNK = 32",  # several job chunks on the 16 x 16 image
        f"a = h.run_local_pass(output={str(one)!r}, preview=False, workers=1)",
        f"b = h.run_local_pass(output={str(two)!r}, preview=False, workers=2)",
        "pool = parallel.WorkerPool(1)",
        "mods = pool.submit(eval, 'sorted(__import__(\"sys\").modules)').result(60)",
        "np_version = pool.submit(eval, '__import__(\"numpy\").__version__').result(60)",
        "pool.shutdown()",
        "me = str(os.getpid())",
        "kids = [p for p in os.listdir('/proc') if p.isdigit() and open('/proc/%s/stat' % p).read()"
        ".rsplit(')', 1)[1].split()[1] == me]",
        "import numpy",
        "bad = [m for m in mods if m == 'bpy' or m.startswith('hemisphere_local_pass.blender')]",
        "print('HLP-RESULT ' + json.dumps({'workers': [a.workers, b.workers], 'python': parallel.worker_python(),",
        "      'prefix': sys.prefix, 'bpy': bad,",
        "      'numpy': [np_version, numpy.__version__], 'children': kids}))",
    )
    result = run_blender([blender, *HEADLESS, sample_blend, "--python-expr", expr], blender_env)
    assert_clean(result)
    assert_no_python_error(result)
    info = result_json(result)
    assert info["workers"] == [1, 2]
    assert info["python"].startswith(info["prefix"]) and os.path.basename(info["python"]).startswith("python3")
    assert info["bpy"] == [] and info["numpy"][0] == info["numpy"][1]
    assert info["children"] == []
    assert one.read_bytes() == two.read_bytes()
def test_first_pass_in_blender_3_4(blender, blender_env, sample_blend, tmp_path):
    """Blender 3.4 solves the first pass on the sample (replacing the attribute it made), and builds the
    furnished room with its own script: samples are built in the Blender that renders them."""
    expr = python_expr(
        "import bpy, json, hemisphere_local_pass as h",
        "report = h.solve_first_pass(tolerance=1e-2)",
        "print('HLP-RESULT ' + json.dumps({'meshes': len(report.meshes), 'replaced': len(report.replaced),",
        "      'converged': report.result.converged, 'balance': report.result.balance_error}))",
    )
    result = run_blender([blender, *HEADLESS, sample_blend, "--python-expr", expr], blender_env)
    assert_no_python_error(result)
    info = result_json(result)
    assert info["converged"] and info["meshes"] == 9 and info["replaced"] == 9 and info["balance"] < 1e-12
    out = tmp_path / "room.blend"
    script = os.path.join(ROOT, "sample_scenes", "furnished_room.py")
    cmd = [blender, *HEADLESS, "--python", script, "--", str(out), "--detail", "1", "--resolution", "8",
           "--tolerance", "0.05"]
    result = run_blender(cmd, dict(blender_env, PYTHONDONTWRITEBYTECODE="1"))
    assert result.returncode == 0 and out.exists(), result.stdout + result.stderr
    assert "first pass converged" in result.stderr


SOLVE_UI_EXPR = r"""
import json, traceback
import bpy
import hemisphere_local_pass as h

RESULT = {result!r}
h.register()
state = {{'ticks': 0, 'phase': 'start', 'invoked': None, 'cancelled_unchanged': None}}

def finish(ok, **extra):
    state.update(extra)
    with open(RESULT, 'w') as fh:
        json.dump({{'ok': ok, **state}}, fh)
    bpy.ops.wm.quit_blender()

def strip():
    for m in bpy.data.meshes:
        a = m.attributes.get('radiosity')
        if a is not None:
            m.attributes.remove(a)

def solved():
    return all('radiosity' in m.attributes for m in bpy.data.meshes)

def invoke(window, tolerance):
    window.scene.hlp_first_pass.tolerance = tolerance
    area = next(a for a in window.screen.areas if a.type == 'PROPERTIES')
    with bpy.context.temp_override(window=window, area=area):
        return sorted(bpy.ops.hlp.solve_radiosity('INVOKE_DEFAULT'))

def tick():
    try:
        state['ticks'] += 1
        window = bpy.context.window_manager.windows[0]
        if state['phase'] == 'start':        # modal run to the end
            strip()
            state['invoked'] = invoke(window, 1e-2)
            state['phase'] = 'running'
        elif state['phase'] == 'running':
            if solved():
                strip()                      # then one that Esc cancels
                invoke(window, 1e-9)
                state['phase'] = 'escape'
                state['escape_at'] = state['ticks'] + 3
        elif state['phase'] == 'escape' and state['ticks'] >= state['escape_at']:
            window.event_simulate(type='ESC', value='PRESS')
            window.event_simulate(type='ESC', value='RELEASE')
            state['phase'] = 'after'
            state['after_at'] = state['ticks'] + 8
        elif state['phase'] == 'after' and state['ticks'] >= state['after_at']:
            state['cancelled_unchanged'] = not any('radiosity' in m.attributes for m in bpy.data.meshes)
            state['tags_left'] = any('hlp_first_pass_origin' in m.attributes for m in bpy.data.meshes)
            finish(True)
            return None
        if state['ticks'] > 400:
            finish(False, error='timed out in phase ' + state['phase'])
            return None
        return 0.25
    except Exception:
        finish(False, error=traceback.format_exc())
        return None

bpy.app.timers.register(tick, first_interval=0.5)
"""


def test_solve_radiosity_modal_in_the_ui_and_escape(blender, xvfb_run, blender_env, sample_blend, tmp_path):
    """The operator runs modally in a real window (status bar progress) and Esc leaves the scene unchanged."""
    result_file = tmp_path / "solve_ui.json"
    expr = python_expr(SOLVE_UI_EXPR.format(result=str(result_file)))
    cmd = [
        xvfb_run, "-a", "-s", "-screen 0 1280x800x24",
        blender, "--factory-startup", "--enable-event-simulate", "--python-exit-code", "1", sample_blend,
        "--python-expr", expr,
    ]  # fmt: skip
    result = run_blender(cmd, dict(blender_env, LIBGL_ALWAYS_SOFTWARE="1"), timeout=300)
    report = f"exit {result.returncode}\n--- stdout\n{result.stdout}\n--- stderr\n{result.stderr}"
    assert result_file.exists(), report
    info = json.loads(result_file.read_text())
    assert info["ok"], f"{info}\n{report}"
    assert info["invoked"] == ["RUNNING_MODAL"], info
    assert info["cancelled_unchanged"] is True and info["tags_left"] is False, info
    assert_no_python_error(result)
