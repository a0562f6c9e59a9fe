"""The tree stays ruff-clean (lint rules in pyproject.toml)."""

import os
import shutil
import subprocess
import sys


def test_ruff_clean():
    ruff = shutil.which("ruff", path=os.path.dirname(sys.executable)) or shutil.which("ruff")
    assert ruff, "ruff not installed (pip install -e '.[test]')"
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    out = subprocess.run([ruff, "check", "--no-cache", root], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr
