"""Shared fixtures: a simulated capture made once per session, small configs."""

from __future__ import annotations

import pytest

from imustation.acquisition import capture, load_config
from imustation.configs import config_path


@pytest.fixture(scope="session")
def demo_config():
    return load_config(config_path("demo.toml"))


@pytest.fixture(scope="session")
def sim_run(tmp_path_factory, demo_config):
    """A 20-minute simulated capture of the demo config (path, summary)."""
    path = tmp_path_factory.mktemp("runs") / "demo20m.h5"
    summary = capture(demo_config, path, 1200.0, simulate=True)
    return path, summary


def write_config(tmp_path, text: str, name: str = "station.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p
