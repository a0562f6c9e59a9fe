"""``imustation export``: noise parameters as Kalibr / OpenVINS / VINS-Fusion / ORB-SLAM3 YAML."""

from __future__ import annotations

import click

from imustation.analysis.pipeline import choices
from imustation.cli import cli
from imustation.errors import InputError
from imustation.outputs import check_file


@cli.command()
@click.argument("runs", metavar="RUN", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--format", "fmt", type=click.Choice(choices.EXPORT_FORMATS), required=True, help="Target tool.")
@click.option("-o", "--output", default=None, help="Write the YAML here (default: print it).")
@click.option("--overwrite", is_flag=True, help="Replace an existing -o file.")
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
@click.option(
    "--inflate",
    default=None,
    metavar="F[,W]",
    help="Multiply the written noise densities by F and the random walks by W (default F), e.g. 10: the "
    "margin VIO users add for motion, vibration and temperature (docs/reports.md). The measured values "
    "stay in the file's comments. Default: no inflation.",
)
@click.option(
    "--force",
    is_flag=True,
    help="Write a quantity even when no axis's fit vouches for it (it does not fit the Allan deviation, sits "
    "at a search bound or is not identified); marked FORCED in the file. Without it such an export writes "
    "nothing and exits 2, naming the axes and why.",
)
@click.option("--warmup", default=choices.DEFAULT_WARMUP, show_default=True, help=choices.WARMUP_HELP)
def export(
    runs: tuple[str, ...],
    fmt: str,
    output: str | None,
    overwrite: bool,
    device: str | None,
    accel_device: str | None,
    gyro_only: bool,
    source: str,
    rw: str,
    model: str,
    topic: str,
    inflate: str | None,
    force: bool,
    warmup: str,
) -> None:
    """Fit every axis of RUN and write the noise parameters a VIO tool expects.

    Values are continuous-time densities (SI) — the white-noise density is
    sigma_w = N, not N*sqrt(rate); the bias random walk is K (see docs/reports.md
    for the conversion from a Gauss-Markov bias). One value per sensor and
    quantity: the largest axis among those whose fit vouches for it (the model
    fits the Allan deviation, nothing at a search bound, the value identified;
    the rule and every axis are in the file's comments); when no axis is left,
    nothing is written and the exit status is 2 (--force writes it, marked).
    A rotated capture is one RUN: its base name (week.h5) or all its parts.
    """
    from imustation.runfile import join_parts

    if output is not None:
        check_file(output, overwrite=overwrite)
    joined = join_parts(runs)
    if len(joined) != 1:
        raise InputError(f"{', '.join(joined)}: export takes one run (or the parts of one rotated capture)")
    [run] = joined
    if not run.lower().endswith((".h5", ".hdf5")):
        raise InputError(f"{run}: export needs a run file (.h5)")
    from imustation.analysis.pipeline.loaders import load_run
    from imustation.analysis.pipeline.warmup import check_warmup, cut_channels
    from imustation.analysis.reports.export import (
        export_channels,
        export_text,
        fit_axes,
        inflate_sensors,
        parse_inflation,
        sensor_noise,
    )

    factors = parse_inflation(inflate) if inflate is not None else None  # a bad value fails before the fits
    check_warmup(warmup)

    gyros, accels = export_channels(load_run(run), run, device=device, accel_device=accel_device, gyro_only=gyro_only)
    cuts = cut_channels([*gyros, *accels], warmup)  # the cut analyze/report/fleet make for this --warmup
    for cut in cuts.values():
        click.echo(f"warm-up {cut.describe()}", err=True)
    skipped: list[str] = []

    def note(line: str) -> None:
        click.echo(line, err=True)

    gyro = sensor_noise(fit_axes(gyros, "gyroscope", run, model, skipped, note), "gyro", source, rw, force=force)
    accel = (
        sensor_noise(fit_axes(accels, "accelerometer", run, model, skipped, note), "accel", source, rw, force=force)
        if accels
        else None
    )
    if factors is not None:
        gyro, accel = inflate_sensors(gyro, accel, *factors)
        for s in (gyro, accel):
            if s is not None:
                click.echo(
                    f"inflated {s.kind}: noise density {s.measured_noise_density:.4e} -> {s.noise_density:.4e}, "
                    f"random walk {s.measured_random_walk:.4e} -> {s.random_walk:.4e} (measured ones in the comments)",
                    err=True,
                )
    for s in (gyro, accel):
        for a in s.axes if s is not None else ():
            if a.noise_warning:
                click.echo(f"warning: {a.channel}: noise density doubtful: {a.noise_warning}", err=True)
            if a.warning:
                click.echo(f"warning: {a.channel}: random walk doubtful: {a.warning}", err=True)
    text = export_text(gyro, accel, fmt, topic=topic, origin=run, skipped=skipped,
                       warmup=[c.describe() for c in cuts.values()])  # fmt: skip
    if output:
        with open(output, "w", encoding="utf-8") as fh:
            fh.write(text)
        click.echo(f"wrote {output}", err=True)
    else:
        click.echo(text, nl=False)
