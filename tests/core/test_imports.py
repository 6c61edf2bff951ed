"""The core and the add-on package import without Blender: no bpy, mathutils, gpu (or bmesh).

Checked in a fresh interpreter. Besides looking at sys.modules afterwards, an import hook records
every *attempt* to import one of these modules (a guarded ``try: import bpy`` would otherwise go
unnoticed here, where bpy is not installed).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
FORBIDDEN = ("bpy", "mathutils", "gpu", "bmesh")

PROBE = r"""
import importlib.abc, json, sys
FORBIDDEN = {forbidden!r}
attempts = []

class Recorder(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in FORBIDDEN:
            attempts.append(name)
        return None

sys.meta_path.insert(0, Recorder())
import {module}
loaded = sorted(m for m in sys.modules if m.split(".")[0] in FORBIDDEN)
print(json.dumps({{"attempts": attempts, "loaded": loaded}}))
"""


@pytest.mark.parametrize("module", ["hemisphere_local_pass.core", "hemisphere_local_pass"])
def test_import_without_blender(module):
    code = PROBE.format(forbidden=FORBIDDEN, module=module)
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["loaded"] == [], f"import {module} loaded {result['loaded']}"
    assert result["attempts"] == [], f"import {module} tried to import {result['attempts']}"


def test_core_public_api():
    code = ("import hemisphere_local_pass.core as c; "
            "print(all(hasattr(c, n) for n in ('Scene', 'form_factors', 'irradiance', 'radiance', 'project_point')))")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "True"


def _import_graph(package_dir):
    """``{module: modules of the same package it imports}``, function-level imports included."""
    import ast

    graph = {}
    for path in package_dir.glob("*.py"):
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 1:
                if node.module:
                    deps.add(node.module.split(".")[0])
                else:
                    deps.update(a.name for a in node.names)
        graph[path.stem] = deps - {path.stem}
    graph.pop("__init__", None)
    return graph


def _assert_no_cycle(graph):
    state = {}

    def visit(m, path):
        if state.get(m) == 1:
            raise AssertionError("import cycle: " + " -> ".join(path + [m]))
        if state.get(m) == 2 or m not in graph:
            return
        state[m] = 1
        for d in sorted(graph[m]):
            visit(d, path + [m])
        state[m] = 2

    for m in sorted(graph):
        visit(m, [])


def _reachable(graph, start):
    seen, todo = set(), [start]
    while todo:
        m = todo.pop()
        for d in graph.get(m, ()):
            if d not in seen:
                seen.add(d)
                todo.append(d)
    return seen


def test_core_modules_import_no_cycle():
    """The core's modules form a layered graph: no import cycle, function-level imports included
    (``projection`` once imported the batch drivers of ``local_pass`` inside ``project_point``)."""
    graph = _import_graph(ROOT / "hemisphere_local_pass" / "core")
    _assert_no_cycle(graph)
    assert "local_pass" not in graph["projection"] and "local_pass" not in graph["inspection"]


def test_blender_modules_import_no_cycle():
    """The Blender layer too (read from the source, without bpy): no import cycle, and the job
    function (``pipeline``) with everything it uses sits below the entry points: it never imports
    the command line (``cli``), the public facade (``job``), the operators, the modal machinery or
    the render engine (``first_pass`` once imported ``job`` for its CLI helpers while ``job``
    imported ``first_pass`` for ``solve``)."""
    graph = _import_graph(ROOT / "hemisphere_local_pass" / "blender")
    _assert_no_cycle(graph)
    entry_points = {"job", "cli", "operators", "modal", "engine", "panels", "registration", "first_pass_ui"}
    below = _reachable(graph, "pipeline") | {"pipeline"}
    assert not below & entry_points, sorted(below & entry_points)
    assert {"pipeline", "cli"} <= graph["job"]
    assert "job" not in _reachable(graph, "first_pass")
