"""The report's page in a real browser: headless Chromium opens index.html from the report folder (no
network) and renders the summary first, then the figures (issue 23). Skipped where no Chromium is installed."""

from __future__ import annotations

import re

import numpy as np
import pytest
from browser_helpers import CHROMIUM, chromium, pixels_near, screenshot_rgb
from click.testing import CliRunner

from imustation.cli import cli

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(CHROMIUM is None, reason="no chromium installed (apt-get install chromium)"),
]


def test_report_page_renders_summary_then_figures(sim_run, tmp_path):
    path, _ = sim_run
    out = tmp_path / "rep"
    r = CliRunner().invoke(cli, ["report", str(path), "-o", str(out), "--warmup", "0", "--channel", "*/z"])
    assert r.exit_code == 0, r.output
    page = (out / path.stem / "index.html").resolve()
    url = page.as_uri()
    shot = tmp_path / "report.png"
    res = chromium(tmp_path, url, f"--screenshot={shot}")
    assert shot.exists(), res.stderr[-2000:]
    dom = chromium(tmp_path, url, "--dump-dom").stdout

    # the rendered DOM: the summary table (display units, interval, verdict) before the figures and details
    assert re.findall(r"<h2>([^<]+)</h2>", dom) == ["Summary", "Figures", "Details"]
    first_table = dom.index("<table>")
    assert dom.index("<h2>Summary</h2>") < first_table < dom.index("<h2>Figures</h2>") < dom.index("<img")
    summary = dom[first_table : dom.index("</table>")]
    assert "N [°/h/√Hz]" in summary and "bmx055" in summary and re.search(r"\[\d[\d.]*, \d[\d.]*\]", summary)

    # the screenshot: a page with text, the summary table's rules and the first Allan figure drawn
    rgb = screenshot_rgb(shot)
    assert len(np.unique(rgb, axis=0)) > 200
    assert np.count_nonzero(np.any(rgb < 240, axis=1)) > 0.02 * len(rgb)
    assert pixels_near(rgb, "#bbbbbb", 12) > 500  # table borders (the page's style: 1px solid #bbb)
    assert pixels_near(rgb, "#d62728", 30) > 200  # the identified model's curve (matplotlib C3) in the figure
