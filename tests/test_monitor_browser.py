"""The monitor page in a real browser: headless Chromium renders the plots (no network but localhost).

Skipped where no Chromium is installed; ``.ci/run`` installs Debian's ``chromium`` first.
"""

from __future__ import annotations

import os
import shutil
import subprocess

import numpy as np
import pytest
from matplotlib import image as mpimg
from monitor_helpers import CONFIG, start_capture, start_monitor, stop, wait_for_file, wait_json

CHROMIUM = shutil.which("chromium") or ("/usr/bin/chromium" if os.path.exists("/usr/bin/chromium") else None)

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(CHROMIUM is None, reason="no chromium installed (apt-get install chromium)"),
]

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


def _chromium(tmp_path, url: str, *args: str) -> subprocess.CompletedProcess:
    """Run headless Chromium once; one retry (a first start in a fresh profile sometimes aborts the load)."""
    for attempt in range(2):
        profile = tmp_path / f"profile{attempt}-{len(args)}"
        cmd = [CHROMIUM, *FLAGS, f"--user-data-dir={profile}", *args, url]
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        if res.returncode == 0 and "Page load failed" not in res.stderr:
            return res
    return res


def test_page_renders_the_plots(tmp_path):
    config = tmp_path / "mon.toml"
    config.write_text(CONFIG)
    out = tmp_path / "browser.h5"
    cap = start_capture(config, out, "40m")
    mon = None
    try:
        wait_for_file(out, cap)
        mon, url = start_monitor(out)
        # data for every plot first: temperatures and Allan curves with the model overlay
        wait_json(url + "api/temperatures", lambda d: d["series"]["ambient1"]["readings"] > 30, what="temps")
        wait_json(url + "api/allan", lambda d: d["devices"]["gyro"]["model"] is not None, timeout=120, what="model")
        shot = tmp_path / "shot.png"
        res = _chromium(tmp_path, url, f"--screenshot={shot}")
        assert shot.exists(), res.stderr[-2000:]
        dom = _chromium(tmp_path, url, "--dump-dom").stdout
    finally:
        if mon is not None:
            stop(mon)
        stop(cap)

    # the DOM: uPlot built one canvas for the temperatures and one per gyro, with the model series
    assert dom.count("<canvas") >= 2, dom[:2000]
    assert 'id="allan-gyro"' in dom and "x model" in dom and "ambient1 (thermometer)" in dom
    assert "connecting" not in dom  # the status arrived and was rendered
    assert ">gyro<" in dom and "400" in dom

    # the screenshot is not blank: many colours, and the plot lines' colours are present
    img = mpimg.imread(shot)[:, :, :3]
    assert img.shape[0] >= 900 and img.shape[1] >= 1000
    rgb = (img * 255).round().astype(np.uint8).reshape(-1, 3)
    colours = np.unique(rgb, axis=0)
    assert len(colours) > 200, len(colours)
    non_white = np.count_nonzero(np.any(rgb < 240, axis=1))
    assert non_white > 0.02 * len(rgb)
    for r, g, b in ((0xD6, 0x27, 0x28), (0x2C, 0xA0, 0x2C), (0x1F, 0x77, 0xB4)):  # axis colours x, y, z
        near = np.all(np.abs(rgb.astype(int) - (r, g, b)) < 30, axis=1)
        assert np.count_nonzero(near) > 200, (r, g, b, np.count_nonzero(near))
