"""Small oddities a newcomer run found (issue 34, third pass); each test failed on the old code."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from imustation.cli import cli
from imustation.errors import InputError
from imustation.units import parse_duration


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


@pytest.mark.parametrize("text", ["-5m", "- 1h30m", "-0.5h"])
def test_a_negative_duration_is_refused_as_not_positive(text):
    with pytest.raises(InputError, match="must be positive"):
        parse_duration(text, "--duration")
    with pytest.raises(InputError, match="use a positive number with a unit"):
        parse_duration("-5x", "--duration")
