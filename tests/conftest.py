import importlib.util
import os
import sys
from pathlib import Path

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def results_script():
    """Import a script under results/ by its path there (e.g. "stage2/distill/chunks.py"):
    they are files of the repository, not of the package. Its directory is on the import path
    while it loads, as when it runs: scripts import their siblings by name."""

    def load(relative: str):
        path = ROOT / "results" / relative
        spec = importlib.util.spec_from_file_location(path.stem, path)
        module = importlib.util.module_from_spec(spec)
        sys.path.insert(0, str(path.parent))
        try:
            spec.loader.exec_module(module)
        finally:
            sys.path.remove(str(path.parent))
        return module

    return load
