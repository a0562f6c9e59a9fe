"""``imustation devices``: list the devices and thermometers of a config and probe their identity."""

from __future__ import annotations

import click

from imustation.cli import cli
from imustation.clock import MonotonicClock, VirtualClock
from imustation.errors import ImustationError


@cli.command()
@click.argument("config", type=click.Path(dir_okay=False))
@click.option("--simulate", is_flag=True, help="Probe the simulated chips instead of the hardware.")
def devices(config: str, simulate: bool) -> None:
    """Open every device and thermometer of CONFIG and print its identity.

    Each one is identified and configured as a capture would do it (chips are
    reset to apply the settings), then closed. One line per device: name,
    driver, bus@address and the identity, or the error. Exit status 1 if any
    device failed to answer.
    """
    from imustation.acquisition import load_config
    from imustation.acquisition.buses import BusFactory
    from imustation.drivers import DRIVERS, THERMOMETER_DRIVERS

    cfg = load_config(config)
    clock = VirtualClock() if simulate else MonotonicClock()
    buses = BusFactory(simulate=simulate, clock=clock, seed=cfg.seed)
    entries = [("device", d, DRIVERS[d.driver]) for d in cfg.devices]
    entries += [("thermometer", t, THERMOMETER_DRIVERS[t.driver]) for t in cfg.thermometers]
    failed = 0
    try:
        for what, entry, driver_cls in entries:
            address = entry.address if entry.address is not None else getattr(driver_cls, "default_address", None)
            where = entry.bus + (f"@0x{address:02X}" if address is not None else "")
            head = f"{what:<11} {entry.name:<12} {entry.driver:<13} {where:<16}"
            try:
                regs = buses.register_thermometer(entry) if what == "thermometer" else buses.register_device(entry)
                driver = driver_cls(regs, entry.settings, sleep=clock.sleep)
                opened = driver.open()
                try:
                    if what == "thermometer":
                        line = f"{opened}, {driver.read_celsius():.4f} degC"
                    else:
                        line = f"{opened.identity}, {opened.model}, {opened.rate_hz:g} Hz"
                finally:
                    driver.close()
            except ImustationError as exc:
                failed += 1
                line = f"ERROR: {exc}"
            click.echo(f"{head} {line}")
    finally:
        buses.close()
    if failed:
        click.echo(f"{failed} of {len(entries)} did not answer as expected", err=True)
        raise SystemExit(1)
