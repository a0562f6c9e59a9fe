"""``imustation setup udev|service``: write the lab computer's set-up files (docs/hardware.md)."""

from __future__ import annotations

import os

import click

from imustation.cli import cli


@cli.group()
def setup() -> None:
    """Print the set-up files a lab computer needs: udev rules, a systemd service.

    \b
      imustation setup udev | sudo tee /etc/udev/rules.d/70-imustation.rules
      imustation setup service lab.toml -o /data/night.h5 | sudo tee /etc/systemd/system/imustation-lab-a.service
    """


@setup.command()
def udev() -> None:
    """Print udev rules: I2C nodes to group i2c, the CP2130/MCP2210 bridges to plugdev, Xsens USB serial to dialout.

    Install with: imustation setup udev | sudo tee /etc/udev/rules.d/70-imustation.rules;
    sudo udevadm control --reload; sudo udevadm trigger; replug the USB devices.
    """
    from imustation.acquisition.setupfiles import udev_rules

    click.echo(udev_rules(), nl=False)


@setup.command()
@click.argument("config", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, help="Run file of the capture (its parts: NAME.001.h5, ...).")
@click.option("--duration", default="12h", show_default=True, help="How long the run lasts, across restarts.")
@click.option(
    "--rotate", default="1h", show_default=True, help="Part length: a crash loses at most the open part's tail."
)
@click.option("--user", default=None, help="User the capture runs as [default: you].")
@click.option("--executable", default=None, help="Command that runs imustation [default: this Python -m imustation].")
def service(config: str, output: str, duration: str, rotate: str, user: str | None, executable: str | None) -> None:
    """Print a systemd unit that captures CONFIG unattended into OUTPUT.

    The capture stops cleanly on SIGTERM (systemctl stop, shutdown), restarts after a
    failure, and every start resumes the run (capture --resume): after a power cut or a
    reboot the night continues as the next part of the same run, the outage a logged gap.
    The unit grants what the readers may ask for (LimitRTPRIO, LimitMEMLOCK, Nice).
    """
    from imustation.acquisition import load_config
    from imustation.acquisition.hostview import HostView
    from imustation.acquisition.setupfiles import ServiceSpec, service_unit
    from imustation.units import parse_duration

    cfg = load_config(config)
    from imustation.cli.capture import check_rotate

    # refused now, not by the service at 3 a.m.; the default part length (1h) may exceed a short run
    seconds = parse_duration(duration, "--duration")
    rotate_s = parse_duration(rotate, "--rotate")
    if click.get_current_context().get_parameter_source("rotate") != click.core.ParameterSource.DEFAULT:
        check_rotate(rotate, rotate_s, duration, seconds)
    elif rotate_s > seconds:
        rotate = duration  # a run shorter than the default part: one part (capture refuses a longer one)
    spec = ServiceSpec(
        config=os.path.abspath(config),
        output=os.path.abspath(output),
        duration=duration,
        rotate=rotate,
        user=user or HostView().user,
        station=cfg.name,
        executable=executable or "",
    )
    click.echo(service_unit(spec), nl=False)
