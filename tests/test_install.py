"""The installed package imports every subpackage and keeps its layer rules."""

import importlib
import os
import shutil
import subprocess
import sys

import pytest

SUBPACKAGES = [
    "imustation",
    "imustation.cli",
    "imustation.configs",
    "imustation.acquisition",
    "imustation.drivers",
    "imustation.drivers.bus",
    "imustation.drivers.sim",
    "imustation.drivers.sim.serial_handlers",
    "imustation.analysis",
    "imustation.analysis.estimators",
    "imustation.analysis.reports",
    "imustation.analysis.pipeline",
    "imustation.monitor",
]


@pytest.mark.parametrize("name", SUBPACKAGES)
def test_subpackage_imports(name):
    importlib.import_module(name)


def test_imports_from_outside_the_source_tree(tmp_path):
    code = (
        "import " + ", ".join(SUBPACKAGES) + "; from imustation.configs import config_path; "
        "import os; assert os.path.exists(config_path('demo.toml')); "
        "from importlib import resources; from imustation.monitor.server import STATIC_FILES, INDEX; "
        "static = resources.files('imustation.monitor') / 'static'; "
        "assert all((static / n).is_file() for n in [*STATIC_FILES, INDEX])"
    )
    subprocess.run([sys.executable, "-c", code], cwd=tmp_path, check=True)


def test_console_script_runs(tmp_path):
    exe = shutil.which("imustation", path=os.path.dirname(sys.executable)) or shutil.which("imustation")
    assert exe, "console script 'imustation' not installed"
    out = subprocess.run([exe, "--help"], cwd=tmp_path, capture_output=True, text=True, check=True)
    for cmd in ("capture", "inspect", "analyze", "demo"):
        assert cmd in out.stdout


def _assemble_installed_layout(root, dest):
    """Copy the source folders into dest as the installed package tree (package-dir mapping)."""
    import tomllib

    with open(os.path.join(root, "pyproject.toml"), "rb") as fh:
        mapping = tomllib.load(fh)["tool"]["setuptools"]["package-dir"]
    for package, folder in sorted(mapping.items(), key=lambda kv: kv[0].count(".")):
        target = os.path.join(dest, *package.split("."))
        shutil.copytree(
            os.path.join(root, folder), target, dirs_exist_ok=True, ignore=shutil.ignore_patterns("__pycache__")
        )


def test_layer_contracts(tmp_path):
    """import-linter contracts of pyproject.toml, checked on the installed layout.

    grimp walks a package's own folder, which does not hold the mapped
    subpackages of an editable install; so the tree is assembled as pip would.
    """
    lint = shutil.which("lint-imports", path=os.path.dirname(sys.executable)) or shutil.which("lint-imports")
    assert lint, "import-linter not installed (pip install -e '.[test]')"
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    _assemble_installed_layout(root, tmp_path)
    env = dict(os.environ, PYTHONPATH=str(tmp_path))
    out = subprocess.run(
        [lint, "--config", os.path.join(root, "pyproject.toml")], cwd=tmp_path, capture_output=True, text=True, env=env
    )
    assert out.returncode == 0, out.stdout + out.stderr
    assert "broken" not in out.stdout.lower() or "0 broken" in out.stdout.lower()
