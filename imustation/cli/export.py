"""``imustation export``: noise parameters as Kalibr / OpenVINS / VINS-Fusion / ORB-SLAM3 YAML."""

from __future__ import annotations

import click

from imustation.analysis.pipeline import choices
from imustation.cli import cli
from imustation.errors import InputError


def _device_channels(channels, device: str | None, kind: str, path: str):
    """Channels of ``kind`` ('gyro'/'accel') of ``device``; the only device with them when not named."""
    by_dev: dict[str, list] = {}
    for ch in channels:
        if ch.id.split("/")[1] == kind:
            by_dev.setdefault(ch.meta["device"], []).append(ch)
    if device is not None:
        return by_dev.get(device, [])
    if len(by_dev) > 1:
        opt = "--device" if kind == "gyro" else "--accel-device"
        raise InputError(f"{path}: {kind} channels on {', '.join(sorted(by_dev))}; choose one with {opt}")
    return next(iter(by_dev.values()), [])


@cli.command()
@click.argument("run", type=click.Path(dir_okay=False))
@click.option("--format", "fmt", type=click.Choice(choices.EXPORT_FORMATS), required=True, help="Target tool.")
@click.option("-o", "--output", default=None, help="Write the YAML here (default: print it).")
@click.option("--device", default=None, help="Device whose gyroscope is exported (default: the only one).")
@click.option("--accel-device", default=None, help="Device whose accelerometer is exported (default: --device).")
@click.option("--gyro-only", is_flag=True, help="Leave the accelerometer keys out (e.g. a gyro-only device).")
@click.option(
    "--source",
    type=click.Choice(choices.EXPORT_SOURCES),
    default="model",
    show_default=True,
    help="model: sigma_w and the bias model of the default estimator (ML_i-F); mli: the same from ML_i; "
    "ieee: N and K of the Allan fit.",
)
@click.option(
    "--random-walk",
    "rw",
    type=click.Choice(choices.RW_CONVERSIONS),
    default="diffusion",
    show_default=True,
    help="Gauss-Markov bias -> random walk: sigma_b (conservative) or ADEV match at tau_b (docs/reports.md).",
)
@click.option("--model", default=choices.DEFAULT_MODEL, show_default=True, help=choices.MODEL_HELP)
@click.option("--topic", default="/imu0", show_default=True, help="IMU topic written for ROS-based tools.")
def export(
    run: str,
    fmt: str,
    output: str | None,
    device: str | None,
    accel_device: str | None,
    gyro_only: bool,
    source: str,
    rw: str,
    model: str,
    topic: str,
) -> None:
    """Fit every axis of RUN and write the noise parameters a VIO tool expects.

    Values are continuous-time densities (SI) — the white-noise density is
    sigma_w = N, not N*sqrt(rate); the bias random walk is K (see docs/reports.md
    for the conversion from a Gauss-Markov bias). One value per sensor: the
    largest axis.
    """
    if not run.lower().endswith((".h5", ".hdf5")):
        raise InputError(f"{run}: export needs a run file (.h5)")
    from imustation.analysis.pipeline.channel import analyze_channel
    from imustation.analysis.pipeline.loaders import load_run
    from imustation.analysis.reports.export import export_text, sensor_noise

    channels = load_run(run)
    gyros = _device_channels(channels, device, "gyro", run)
    if not gyros:
        raise InputError(f"{run}: no gyroscope channels" + (f" on device {device}" if device else ""))
    accels = [] if gyro_only else _device_channels(channels, accel_device or gyros[0].meta["device"], "accel", run)
    if accel_device is None and not accels and not gyro_only:
        accels = _device_channels(channels, None, "accel", run)  # e.g. the BMX055's separate accelerometer die
    if not accels and not gyro_only:
        raise InputError(
            f"{run}: no accelerometer channels"
            + (f" on device {accel_device}" if accel_device else "")
            + "; name one with --accel-device or pass --gyro-only"
        )

    def fit(chs):
        out = []
        for ch in chs:
            click.echo(f"fitting {ch.id} ({ch.n} samples) ...", err=True)
            out.append(analyze_channel(ch, model=model))
            ch.release()
        return out

    gyro = sensor_noise(fit(gyros), "gyro", source, rw)
    accel = sensor_noise(fit(accels), "accel", source, rw) if accels else None
    for s in (gyro, accel):
        for a in s.axes if s is not None else ():
            if a.warning:
                click.echo(f"warning: {a.channel}: random walk doubtful: {a.warning}", err=True)
    text = export_text(gyro, accel, fmt, topic=topic, origin=run)
    if output:
        with open(output, "w", encoding="utf-8") as fh:
            fh.write(text)
        click.echo(f"wrote {output}", err=True)
    else:
        click.echo(text, nl=False)
