"""Fault injection: plans fire on the clock; a simulated capture logs the faults and recovers."""

import pytest

from imustation.acquisition import capture
from imustation.acquisition.config import parse_config
from imustation.clock import VirtualClock
from imustation.drivers.sim.faults import FaultPlan, FaultSpec, parse_faults
from imustation.errors import SettingError
from imustation.runfile import open_run


def test_one_shot_and_window():
    clock = VirtualClock()
    plan = FaultPlan([FaultSpec("disconnect", at_s=10.0, duration_s=5.0), FaultSpec("reset", at_s=20.0)], clock)
    assert not plan.active("disconnect")
    clock.sleep(11.0)
    assert plan.active("disconnect")
    clock.sleep(5.0)
    assert not plan.active("disconnect")
    assert not plan.fire("reset")
    clock.sleep(5.0)
    assert plan.fire("reset") and not plan.fire("reset")
    assert [k for _, k in plan.sim_log] == ["disconnect", "reset"]


def test_slow_window_delays_each_transaction_inside_it():
    clock = VirtualClock()
    (spec,) = parse_faults([{"kind": "slow", "at_s": 10, "duration_s": 5, "delay_s": 0.004}])
    plan = FaultPlan([spec], clock)
    assert plan.delay_s() == 0.0
    clock.sleep(12.0)
    assert plan.delay_s() == 0.004 and plan.delay_s() == 0.004  # every transaction, not once
    clock.sleep(5.0)
    assert plan.delay_s() == 0.0
    assert parse_faults([{"kind": "slow", "at_s": 1, "duration_s": 1}])[0].delay_s > 0  # a default delay


def test_poisson_rate():
    clock = VirtualClock()
    plan = FaultPlan([FaultSpec("nack", every_s=10.0)], clock, seed=3)
    n = 0
    for _ in range(100_000):
        clock.sleep(0.1)
        n += plan.fire("nack")
    # 10 000 s at one per 10 s: Poisson(1000), 4 sigma = 126
    assert abs(n - 1000) < 126


@pytest.mark.parametrize(
    "entry,needle",
    [
        ({"kind": "meltdown", "at_s": 1}, "kind = 'meltdown'"),
        ({"kind": "nack"}, "give at_s"),
        ({"kind": "nack", "at_s": -1}, "at_s = -1"),
        ({"kind": "nack", "every": 3}, "every: unknown key"),
        ({"kind": "nack", "at_s": 1, "delay_s": 0.1}, "delay_s: only a 'slow' fault"),
        ({"kind": "slow", "at_s": 1}, "'slow' fault needs duration_s"),
    ],
)
def test_bad_fault_specs(entry, needle):
    with pytest.raises(SettingError, match=needle):
        parse_faults([entry])


def test_capture_survives_nacks_and_a_chip_reset(tmp_path):
    cfg = parse_config(
        {
            "station": {"seed": 3},
            "device": [
                {
                    "name": "g",
                    "driver": "bmx055",
                    "bus": "i2c:1",
                    "sim": {
                        "faults": [
                            {"kind": "nack", "every_s": 20},
                            {"kind": "reset", "at_s": 100},
                            {"kind": "disconnect", "at_s": 200, "duration_s": 3},
                        ]
                    },
                }
            ],
        }
    )
    out = tmp_path / "f.h5"
    summary = capture(cfg, out, 300.0, simulate=True)
    with open_run(out) as run:
        kinds = [e.kind for e in run.events()]
        n = run.devices["g"].n
        lost = sum(e.lost for e in run.events())
    # nacks are absorbed by the bus retries; the reset (lost configuration) and the
    # disconnect each give one fault, one reconnect and one gap with its lost samples
    assert summary.samples["g"] == n
    assert kinds == ["fault", "reconnect", "gap", "fault", "reconnect", "gap"]
    # written + logged losses = the samples of 300 s at 400 Hz, exactly (virtual clock:
    # every poll and every lost stretch falls on the sample grid)
    assert n + lost == 300 * 400 == summary.samples["g"] + summary.lost["g"]
