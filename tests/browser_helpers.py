"""Headless Chromium for the page tests (the monitor's page, the report's page): skipped without it.

``.ci/run`` installs Debian's ``chromium``; no network but localhost and local files.
"""

from __future__ import annotations

import os
import shutil
import subprocess

import numpy as np
from matplotlib import image as mpimg

CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if os.path.exists("/usr/bin/chromium") else None)

FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",
    "--hide-scrollbars",
    "--window-size=1200,1400",
    "--virtual-time-budget=10000",
]


def chromium(tmp_path, url: str, *args: str) -> subprocess.CompletedProcess:
    """Run headless Chromium once; one retry (a first start in a fresh profile sometimes aborts the load)."""
    for attempt in range(2):
        profile = tmp_path / f"profile{attempt}-{len(args)}"
        cmd = [CHROMIUM, *FLAGS, f"--user-data-dir={profile}", *args, url]
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        if res.returncode == 0 and "Page load failed" not in res.stderr:
            return res
    return res


def screenshot_rgb(path) -> np.ndarray:
    """The screenshot as (pixels, 3) uint8 RGB."""
    img = mpimg.imread(path)[:, :, :3]
    return (img * 255).round().astype(np.uint8).reshape(-1, 3)


def pixels_near(rgb: np.ndarray, colour: str, tol: int = 30) -> int:
    """Pixels within ``tol`` of the ``#rrggbb`` colour in every channel."""
    target = np.array([int(colour[i : i + 2], 16) for i in (1, 3, 5)])
    return int(np.count_nonzero(np.all(np.abs(rgb.astype(int) - target) < tol, axis=1)))
