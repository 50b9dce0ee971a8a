"""The layering holds by construction, not by convention: app -> flows -> tasks -> library (touch2robot,
schemas), never back up. Every library module is imported in a fresh interpreter, which must then hold
neither Prefect nor any of the layers above."""

from __future__ import annotations

import json
import pkgutil
import subprocess
import sys
from pathlib import Path

import schemas
import touch2robot

ROOT = Path(__file__).resolve().parents[1]
UPPER_LAYERS = ("prefect", "tasks", "flows", "app")


def library_modules() -> list[str]:
    names = []
    for package in (touch2robot, schemas):
        names.append(package.__name__)
        names += [m.name for m in pkgutil.walk_packages(package.__path__, prefix=f"{package.__name__}.")]
    return names


def test_the_library_imports_no_prefect_and_nothing_above_it():
    modules = library_modules()
    assert len(modules) > 40, modules  # the walk found the library, not an empty package
    probe = (
        "import importlib, json, sys\n"
        f"for name in {modules!r}:\n"
        "    importlib.import_module(name)\n"
        f"print(json.dumps(sorted({{m.split('.')[0] for m in sys.modules}} & {set(UPPER_LAYERS)!r})))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, timeout=600, check=False
    )
    assert out.returncode == 0, out.stderr[-3000:]
    loaded = json.loads(out.stdout.strip().splitlines()[-1])
    assert loaded == [], f"importing the library loaded {loaded}"


def test_the_probe_sees_an_upper_layer_when_one_is_imported():
    """The probe itself can fail: importing a task module does load Prefect."""
    probe = "import sys, tasks.common; print('prefect' in sys.modules)"
    out = subprocess.run(
        [sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, timeout=600, check=False
    )
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().splitlines()[-1] == "True"
