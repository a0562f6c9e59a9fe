"""The installed package imports every subpackage and keeps its layer rules."""

import importlib
import os
import shutil
import subprocess
import sys

import pytest

SUBPACKAGES = [
    "imustation",
    "imustation.runfile",
    "imustation.cli",
    "imustation.configs",
    "imustation.acquisition",
    "imustation.acquisition.importers",
    "imustation.drivers",
    "imustation.drivers.bus",
    "imustation.drivers.sim",
    "imustation.drivers.sim.serial_handlers",
    "imustation.analysis",
    "imustation.analysis.estimators",
    "imustation.analysis.estimators.models",
    "imustation.analysis.estimators.engine",
    "imustation.analysis.estimators.classical",
    "imustation.analysis.estimators.ml",
    "imustation.analysis.estimators.selection",
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


def test_layer_contracts():
    """import-linter contracts of pyproject.toml, checked on the source tree itself.

    grimp finds a package by walking its folder; the links imustation/analysis,
    acquisition, drivers and configs (docs/architecture.md, "Source tree and
    installed package") give the source tree the installed shape, so no copy is needed.
    """
    lint = shutil.which("lint-imports", path=os.path.dirname(sys.executable)) or shutil.which("lint-imports")
    assert lint, "import-linter not installed (pip install -e '.[test]')"
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    out = subprocess.run([lint, "--no-cache"], cwd=root, capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "0 broken" in out.stdout.lower(), out.stdout


ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ROOT_LINKS = ["acquisition", "analysis", "configs", "drivers"]


def _package_dirs():
    """pyproject's package-dir mapping: import package -> source folder."""
    import tomllib

    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as fh:
        return tomllib.load(fh)["tool"]["setuptools"]["package-dir"]


def _source_modules(mapping):
    """Installed path of every .py file under the mapped folders, and every package.

    os.walk does not follow links, so the links inside imustation/ are not
    counted twice; each mapped folder is walked under its own package name.
    """
    files, packages = set(), set()
    for package, folder in mapping.items():
        base = os.path.join(ROOT, folder)
        for dirpath, dirnames, filenames in os.walk(base):
            dirnames[:] = [d for d in dirnames if d != "__pycache__"]
            rel = os.path.relpath(dirpath, base)
            parts = package.split(".") + ([] if rel == "." else rel.split(os.sep))
            if "__init__.py" in filenames:
                packages.add(".".join(parts))
            files.update("/".join([*parts, f]) for f in filenames if f.endswith(".py"))
    return files, packages


def test_root_links_give_the_source_tree_the_installed_shape():
    for name in ROOT_LINKS:
        link = os.path.join(ROOT, "imustation", name)
        assert os.path.islink(link), f"imustation/{name} must be a link to ../{name}"
        assert os.readlink(link) == os.path.join("..", name)
        assert _package_dirs()[f"imustation.{name}"] == name


def test_non_editable_install_imports_from_the_repository_root(tmp_path):
    """`pip install .` (not editable) into a fresh venv, then import from the repository root.

    The root folder imustation/ comes first on sys.path when Python runs there; it
    must hold the layers too (the links), or `import imustation.analysis` fails.
    No network: the build uses this interpreter's setuptools (--no-build-isolation)
    and the venv borrows this interpreter's dependencies through a .pth file.
    """
    import sysconfig
    import zipfile

    mapping = _package_dirs()
    src = tmp_path / "src"  # the build writes build/ and *.egg-info beside its input: build a copy
    src.mkdir()
    for name in ("pyproject.toml", "README.md", *sorted(set(mapping.values()))):
        from_path = os.path.join(ROOT, name)
        if os.path.isdir(from_path):
            shutil.copytree(from_path, src / name, symlinks=True, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(from_path, src / name)
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    build = subprocess.run(
        [*pip, "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-w", str(tmp_path / "dist"), str(src)],
        capture_output=True,
        text=True,
    )
    assert build.returncode == 0, "wheel build failed (needs setuptools>=70.1: pip install -e '.[test]')\n" + (
        build.stdout + build.stderr
    )
    (wheel,) = (tmp_path / "dist").glob("imustation-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert len(names) == len(set(names)), "duplicate entries in the wheel"
    expected_files, packages = _source_modules(mapping)
    assert {n for n in names if n.endswith(".py")} == expected_files

    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = str(venv / "bin" / "python")
    site = subprocess.run(
        [python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    outer = sorted({sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]})
    with open(os.path.join(site, "_outer_dependencies.pth"), "w") as fh:
        fh.write("\n".join(outer) + "\n")  # plain path lines: that folder's own .pth files stay unread
    subprocess.run([*pip, "install", "--no-deps", "--no-index", "--target", site, str(wheel)], check=True)

    every = ", ".join(sorted(packages))
    show = "import imustation.analysis as a; print(a.__file__)"
    elsewhere = subprocess.run([python, "-c", f"import {every}; {show}"], cwd=tmp_path, capture_output=True, text=True)
    assert elsewhere.returncode == 0, elsewhere.stderr
    assert elsewhere.stdout.strip().startswith(site), elsewhere.stdout  # the installed copy, not the source tree

    at_root = subprocess.run(
        [python, "-c", f"import imustation.analysis, imustation.acquisition, imustation.drivers, {every}; {show}"],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert at_root.returncode == 0, at_root.stderr
    # Python puts the working folder first: from the root the source tree answers, whole
    assert os.path.realpath(at_root.stdout.strip()) == os.path.join(os.path.realpath(ROOT), "analysis", "__init__.py")
