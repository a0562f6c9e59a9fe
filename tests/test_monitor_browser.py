"""The monitor page in a real browser: headless Chromium renders the plots (no network but localhost).

Skipped where no Chromium is installed; ``.ci/run`` installs Debian's ``chromium`` first.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from browser_helpers import CHROMIUM, pixels_near, screenshot_rgb
from browser_helpers import chromium as _chromium
from matplotlib import image as mpimg
from monitor_helpers import CONFIG, start_capture, start_monitor, stop, wait_for_file, wait_json

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(CHROMIUM is None, reason="no chromium installed (apt-get install chromium)"),
]


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

    # issue 23: the fitted values carry their units, the measured points their 68 % error bars
    assert "rad/s/√Hz (" in dom and "°/h/√Hz)" in dom and "rad/s²/√Hz" in dom and "°/h/√h)" in dom
    bars = [int(v) for v in re.findall(r'data-error-bars="(\d+)"', dom)]
    assert bars and bars[0] >= 3 * 10, bars  # three axes, an error bar at each of their taus

    # the screenshot is not blank: many colours, and the plot lines' colours are present
    img = mpimg.imread(shot)[:, :, :3]
    assert img.shape[0] >= 900 and img.shape[1] >= 1000
    rgb = screenshot_rgb(shot)
    colours = np.unique(rgb, axis=0)
    assert len(colours) > 200, len(colours)
    non_white = np.count_nonzero(np.any(rgb < 240, axis=1))
    assert non_white > 0.02 * len(rgb)
    # every curve its own colour: the axes x, y, z and, distinct from them, their model overlays
    for colour in ("#d62728", "#2ca02c", "#1f77b4", "#9467bd", "#ff7f0e", "#17becf"):
        assert pixels_near(rgb, colour, 25) > 100, (colour, pixels_near(rgb, colour, 25))
