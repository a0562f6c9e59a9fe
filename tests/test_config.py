"""Shipped configs load; sim tables are validated up front."""

import os

import pytest

from imustation.acquisition import load_config
from imustation.drivers import DRIVERS
from imustation.errors import ConfigError

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.mark.parametrize("name", ["demo.toml", "lab-example.toml"])
def test_shipped_configs_load(name):
    cfg = load_config(os.path.join(ROOT, "configs", name))
    assert cfg.devices
    for dev in cfg.devices:
        if DRIVERS[dev.driver].bus_kind == "i2c":
            assert dev.address is not None


def test_lab_example_sim_table(tmp_path):
    cfg = load_config(os.path.join(ROOT, "configs", "lab-example.toml"))
    bmx = next(d for d in cfg.devices if d.driver == "bmx055")
    assert bmx.sim["tau_b"] == [537.0, 2440.0, 659.0]


def test_unknown_sim_key(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text('[[device]]\nname="g"\ndriver="bmx055"\nbus="i2c:1"\n[device.sim]\nsigmaw=1\n')
    with pytest.raises(ConfigError, match=r"device\[0\].sim.sigmaw: unknown key"):
        load_config(p)
