"""Option combinations of analyze: --model with a device filter, --pattern, --estimator and --method (issue 34)."""

from __future__ import annotations

import numpy as np
from click.testing import CliRunner

from imustation.cli import cli
from tests.realistic_records import record

SIGMA_W = 2.44e-4


def test_a_model_with_a_device_filter_works_without_naming_the_pattern(tmp_path):
    """The --help example --model wn+fl+rw+lp was refused unless --pattern uniform was added, and neither the
    error nor the help said so: ML_i now fits such a model on the uniform pattern by default."""
    x, fs = record("mpu9150", 0.25, SIGMA_W, seed=5)
    p = tmp_path / "mpu.npy"
    np.save(p, x)
    r = CliRunner().invoke(cli, ["analyze", str(p), "--rate", str(fs), "--model", "wn+rw+lp", "--verbose"])
    assert r.exit_code == 0, r.output
    assert "  noise_model: ML_i-F wn+rw+lp" in r.output and "  mli: ML_i wn+rw+lp" in r.output
    r = CliRunner().invoke(cli, ["analyze", str(p), "--rate", str(fs), "--model", "wn+rw+lp", "--pattern", "log"])
    assert r.exit_code == 2
    (line,) = [ln for ln in r.output.splitlines() if ln.strip()]
    assert "--pattern log cannot fit --model wn+rw+lp" in line and "--pattern uniform" in line


def test_help_tells_model_estimator_and_method_apart():
    out = CliRunner().invoke(cli, ["analyze", "--help"]).output
    for needle in ("WHAT is fitted", "HOW the reported", "BESIDE the reported", "uniform (the default for a model"):
        assert needle in " ".join(out.split()), needle
