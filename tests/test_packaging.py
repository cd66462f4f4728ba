"""The wheel carries the MIT LICENSE that pyproject.toml declares."""

import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _setuptools_version() -> tuple[int, ...]:
    try:
        from importlib.metadata import version

        return tuple(int(part) for part in version("setuptools").split(".")[:2])
    except Exception:  # not installed, or an unusual version string
        return (0,)


def test_license_file_is_mit_and_declared():
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License") and "WITHOUT WARRANTY OF ANY KIND" in text
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == "MIT" and project["license-files"] == ["LICENSE"]


def test_wheel_contains_the_license(tmp_path):
    # Build from a copy so that the build leaves nothing in the source tree.
    source = tmp_path / "src_copy"
    shutil.copytree(
        ROOT,
        source,
        ignore=shutil.ignore_patterns(
            ".*", "runs", "results", "build", "dist", "*.egg-info", "__pycache__", "tests"
        ),
    )
    out = tmp_path / "wheel"
    # The installed setuptools when it reads PEP 639 `license-files` (no download needed),
    # else pip fetches the build requirements as for any install.
    isolation = ["--no-build-isolation"] if _setuptools_version() >= (77,) else []
    pip_wheel = [sys.executable, "-m", "pip", "wheel", str(source), "--no-deps", "--quiet"]
    subprocess.run(
        [*pip_wheel, *isolation, "--wheel-dir", str(out)],
        check=True,
        capture_output=True,
    )
    (wheel,) = out.glob("clamgen-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        licenses = [name for name in archive.namelist() if name.endswith("licenses/LICENSE")]
        assert len(licenses) == 1
        assert archive.read(licenses[0]).decode() == (ROOT / "LICENSE").read_text()
        metadata = next(n for n in archive.namelist() if n.endswith(".dist-info/METADATA"))
        assert "License-Expression: MIT" in archive.read(metadata).decode()


def test_import_sets_one_blas_thread_unless_the_user_chose():
    code = "import os, clamgen; print(os.environ['OPENBLAS_NUM_THREADS'])"
    env = {key: value for key, value in os.environ.items() if key != "OPENBLAS_NUM_THREADS"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert out.stdout.strip() == "1", out.stderr
    env["OPENBLAS_NUM_THREADS"] = "2"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert out.stdout.strip() == "2", out.stderr
