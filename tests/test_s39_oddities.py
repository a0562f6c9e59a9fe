"""Small oddities a newcomer run found (issue 34, third pass); each test failed on the old code."""

from __future__ import annotations

import numpy as np
from click.testing import CliRunner

from imustation.cli import cli


def test_analyze_of_a_text_log_prints_its_column_mapping_once(tmp_path):
    log = tmp_path / "log.csv"
    rng = np.random.default_rng(4)
    n, fs = 6000, 100.0
    data = np.column_stack([np.arange(n) / fs, rng.normal(0, 0.01, (n, 3))])
    np.savetxt(log, data, delimiter=",", header="time,gx [rad/s],gy [rad/s],gz [rad/s]", comments="", fmt="%.6f")
    r = CliRunner().invoke(cli, ["analyze", str(log), "--channel", "*/gyro/x"])
    assert r.exit_code == 0, r.output
    assert r.stderr.count("gyro x <- 'gx [rad/s]'") == 1
    assert f"{log}: imu: 6000 samples" in r.stderr
