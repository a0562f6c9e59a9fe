"""``imustation demo``: simulated capture -> analysis -> identified vs simulated."""

from __future__ import annotations

import csv
import math
import os
import sys
import tempfile
import time

import click

from imustation.analysis.pipeline import choices
from imustation.cli import cli
from imustation.configs import config_path
from imustation.errors import InputError
from imustation.outputs import check_file
from imustation.units import display_units, format_duration, parse_duration, sensor_kind

#: virtual durations: the quick demo (byte-level capture), and the full lab (synthesised at the
#: noise-model level by default: the byte-level lab capture runs ~14x real time, its ADIS16448
#: simulator making one USB round trip per sample)
QUICK_DURATION = "6h"
LAB_DURATION = "12h"
PARAMS = ("sigma_w", "sigma_b", "tau_b")
#: the note of a paper-model row whose 90 % interval misses the simulated value
MISSED = "outside its 90 % interval (1 row in 10 is, by chance)"
#: noise profiles of the simulated devices (drivers/sim/profiles.py; not imported here: --help stays light)
PROFILES = ("paper", "datasheet")
#: the shipped lab config of each profile
LAB_CONFIGS = {"paper": "demo-lab.toml", "datasheet": "lab-realistic.toml"}
TABLE_FIELDS = ("channel", "param", "simulated", "identified", "ci90_lo", "ci90_hi", "error_pct", "unit", "note")
#: the dimension of each compared parameter (imustation.units.display_units)
PARAM_DIMENSIONS = {"sigma_w": "density", "sigma_b": "drift", "tau_b": "time"}


@cli.command()
@click.option(
    "--duration",
    default=None,
    help=f"Virtual duration of the simulated capture [default: {QUICK_DURATION}; {LAB_DURATION} with --lab].",
)
@click.option("-o", "--output", default=None, help="Keep the run file here (default: a temporary file).")
@click.option("--overwrite", is_flag=True, help="Replace an existing -o run file or --table file.")
@click.option("--config", "config_file", default=None, help="Config to simulate (default: the shipped demo.toml).")
@click.option(
    "--lab",
    is_flag=True,
    help="The full virtual lab: every device of the paper's lab (configs/demo-lab.toml), gyros and accelerometers.",
)
@click.option(
    "--profile",
    type=click.Choice(PROFILES),
    default=None,
    help="With --lab: the lab's noise profile: paper (Table IV, configs/demo-lab.toml; the default) or "
    "datasheet (configs/lab-realistic.toml: datasheet noise, output filters, warm-up, room drift).",
)
@click.option(
    "--through-drivers",
    is_flag=True,
    help="With --lab: run the byte-level simulated capture (drivers, buses, chip simulators; ~55x real "
    "time on two cores, in two processes) instead of synthesising the run file from the same noise sources (~300x).",
)
@click.option("--warmup", default=choices.DEFAULT_WARMUP, show_default=True, help=choices.WARMUP_HELP)
@click.option(
    "--table",
    "table_path",
    default=None,
    help="Write the simulated-vs-identified table as CSV here (--lab default: imustation-lab-demo.csv).",
)
def demo(
    duration: str | None,
    output: str | None,
    overwrite: bool,
    config_file: str | None,
    lab: bool,
    profile: str | None,
    through_drivers: bool,
    warmup: str,
    table_path: str | None,
) -> None:
    """Simulate a capture, analyse it, and compare identified with simulated parameters.

    The simulated chips draw their noise from the paper's Table IV parameters;
    the table shows how close the default estimator (ML_i-F) gets to them. With
    --lab every device of the paper's lab, gyroscopes and accelerometers, for 12
    virtual hours: the run file is synthesised from the chip simulators' own noise
    sources and seeds without the bus transport (a few minutes in all; see
    docs/reports.md); --through-drivers runs the byte-level capture instead.
    --profile datasheet simulates the lab as the parts behave (docs/simulation.md):
    bias instability, rate random walk, temperature, output filters; for such devices the
    analysis is analyze's own (the automatic model choice) and the table compares N, B, K
    with the simulated ones (N with the filter's folding and the counts' rounding); a row
    whose interval misses the truth, or a term not detected (its 90 % upper bound), says
    why in the table's note column (docs/noise-model.md, "The corners").
    """
    if profile is not None and (not lab or config_file):
        raise click.UsageError("--profile chooses the lab's config: use it with --lab and without --config")
    if output is not None and os.path.splitext(output)[1].lower() not in (".h5", ".hdf5"):
        # the analysis that follows opens the file by its extension: refuse before hours of simulation
        raise InputError(f"-o {output}: the run file needs an .h5 name (e.g. {output}.h5)")
    if lab and table_path is None:
        table_path = "imustation-lab-demo.csv"
    # every output before hours of simulation: a capture is never replaced silently
    if output is not None:
        check_file(output, overwrite=overwrite)
    if table_path is not None:
        check_file(table_path, overwrite=overwrite, option="--table")
    from imustation.acquisition import capture as run_capture
    from imustation.acquisition import load_config
    from imustation.acquisition.synthesize import synthesize
    from imustation.acquisition.workers import bus_groups
    from imustation.analysis.pipeline.channel import analyze_channel
    from imustation.analysis.pipeline.loaders import load_inputs
    from imustation.analysis.pipeline.truth import nbk_rows
    from imustation.analysis.pipeline.warmup import check_warmup, cut_channels
    from imustation.analysis.reports.tables import param_flag
    from imustation.drivers.sim import simulated_nbk, simulated_truth

    check_warmup(warmup)  # before hours of simulation
    default_cfg = LAB_CONFIGS[profile or "paper"] if lab else "demo.toml"
    cfg = load_config(config_file or config_path(default_cfg))
    seconds = parse_duration(duration or (LAB_DURATION if lab else QUICK_DURATION), "--duration")
    globs = ["*/gyro/*", "*/accel/*"] if lab else ["*/gyro/*"]
    with tempfile.TemporaryDirectory() as tmp:
        path = output or os.path.join(tmp, "demo.h5")
        # without -o the run file lives in a temporary folder deleted at the end: no path worth printing
        where = path if output else "a temporary run file, deleted at the end (-o RUN.h5 keeps it)"
        click.echo(f"simulating {format_duration(seconds)} of {len(cfg.devices)} device(s) -> {where}")
        if lab and not through_drivers:
            t_syn = time.perf_counter()
            with click.progressbar(length=1000, label="  synthesising (noise-model level)", file=sys.stderr) as bar:
                done = [0]

                def step(fraction: float) -> None:
                    k = int(fraction * 1000)
                    bar.update(k - done[0])
                    done[0] = k

                syn = synthesize(cfg, path, seconds, overwrite=overwrite, progress=step)
            wall = time.perf_counter() - t_syn
            click.echo(f"  {sum(syn.samples.values())} samples in {wall:.1f} s wall (synthesised, no bus transport)")
        else:
            # two processes (docs/capture.md): the same table on any machine, half the time on two cores
            workers = min(2, len(bus_groups(cfg)))
            summary = run_capture(cfg, path, seconds, simulate=True, overwrite=overwrite, workers=workers)
            click.echo(f"  {sum(summary.samples.values())} samples in {summary.wall_s:.1f} s wall")
        channels = load_inputs([path], globs)
        for cut in cut_channels(channels, warmup).values():  # the cut analyze/report/export/fleet make
            click.echo(f"  warm-up {cut.describe()}")
        paper = sorted({dev.name for dev in cfg.devices if dev.sim.get("profile") != "datasheet"})
        if paper:
            # analyze's default (--model auto) may choose another model for the same file: say which
            # command gives these numbers, so the two are not read as disagreeing
            again = (
                f"imustation analyze {output} --model {choices.PAPER_MODEL}"
                if output
                else (f"analyze --model {choices.PAPER_MODEL}")
            )
            click.echo(
                f"  fitted model {', '.join(paper)}: {choices.PAPER_MODEL}, the simulated one ({again} gives these "
                "numbers; analyze's default --model auto may choose a simpler one)"
            )
        head = (
            f"{'channel':<22} {'param':<8} {'simulated':>11} {'identified':>11} {'90% interval':>25} {'error':>8}"
            "  unit (SI)"
        )
        click.echo(head)
        click.echo("-" * len(head))
        truths = simulated_truth(cfg)
        # the datasheet profile is white noise + filter + bias instability + random walk, not the paper's
        # model: fit what analyze fits and compare N, B, K like for like (analysis/pipeline/truth.py)
        datasheet = {dev.name for dev in cfg.devices if dev.sim.get("profile") == "datasheet"}
        nbk = simulated_nbk(cfg) if datasheet else {}
        drift = _drift_note(cfg)
        rows = []
        t0 = time.perf_counter()
        for ch in channels:
            truth = truths.get(ch.id)
            if truth is None:
                continue  # replayed or unknown source: nothing to compare with
            if ch.id.split("/")[0] in datasheet:
                res = analyze_channel(ch)
                ch.release()
                for row in nbk_rows(res, nbk[ch.id], drift):
                    unit = display_units(sensor_kind(ch.units, ch.id), row["dimension"])[0]
                    sim_v, fit_v, lo, hi, err = (row[k] for k in ("simulated", "identified", "ci90_lo", "ci90_hi",
                                                                  "error_pct"))  # fmt: skip
                    rows.append(dict(zip(TABLE_FIELDS, (ch.id, row["param"], sim_v, fit_v, lo, hi, err, unit,
                                                        row["note"]), strict=True)))  # fmt: skip
                    err_s = f"{err:>7.1f}%" if err == err else f"{'':>8}"
                    click.echo(
                        f"{ch.id:<22} {row['param']:<8} {sim_v:>11.4g} {_shown(fit_v)} {f'[{lo:.3g}, {hi:.3g}]':>25} "
                        f"{err_s}  {unit}" + (f"  ({row['note']})" if row["note"] else "")
                    )
                continue
            res = analyze_channel(ch, model=choices.PAPER_MODEL)  # the simulated truth is the paper's model
            ch.release()
            for name in PARAMS:
                sim_v, fit_v = (
                    stored_truth(name, getattr(truth, name), ch.scale, ch.fs_hz),
                    getattr(res.noise_model, name),
                )
                lo, hi = res.noise_model.ci90[name]
                # no Gauss-Markov term simulated (datasheet profile): nothing to compare with
                compared = 0 < sim_v < float("inf")
                err = 100 * (fit_v / sim_v - 1) if compared else float("nan")
                unit = display_units(sensor_kind(ch.units, ch.id), PARAM_DIMENSIONS[name])[0]
                # a value at its search bound or unidentified is no estimate: say so, as analyze and report do
                note, said = paper_note(param_flag(res.noise_model, name), sim_v if compared else math.nan, lo, hi)
                rows.append(dict(zip(TABLE_FIELDS, (ch.id, name, sim_v, fit_v, lo, hi, err, unit, note), strict=True)))
                shown, err_s = (f"{sim_v:>11.4g}", f"{err:>7.1f}%") if compared else (f"{'-':>11}", f"{'':>8}")
                click.echo(
                    f"{ch.id:<22} {name:<8} {shown} {_shown(fit_v)} {f'[{lo:.3g}, {hi:.3g}]':>25} {err_s}  {unit}"
                    + (f"  ({said})" if said else "")
                )
        click.echo(f"  analysed {len(channels)} channels in {time.perf_counter() - t0:.1f} s")
    if table_path:
        with open(table_path, "w", newline="", encoding="utf-8") as fh:
            w = csv.DictWriter(fh, fieldnames=TABLE_FIELDS)
            w.writeheader()
            w.writerows(rows)
        click.echo(f"wrote {table_path}")


def stored_truth(name: str, value: float, scale: float, fs_hz: float) -> float:
    """What the stored record truly has of the simulated parameter ``name`` (SI): the white-noise density
    of a channel stored as counts (``scale`` units per count, ``fs_hz`` Hz) is the model's ``sigma_w`` and
    the rounding's in quadrature, an error uniform over one count (variance scale^2 / 12 per sample,
    Widrow & Kollar, Quantization Noise, 2008, ch. 4), as the datasheet rows count it
    (analysis/pipeline/truth.py). The slow terms are the model's."""
    from imustation.analysis.pipeline.truth import rounding_density

    if name != "sigma_w" or scale == 1.0:
        return value
    return math.hypot(value, rounding_density(scale, fs_hz))


def paper_note(flag: str, simulated: float, lo: float, hi: float) -> tuple[str, str]:
    """A paper-model row's note (CSV) and what the text says of it: a value at its bound or not identified
    is no estimate; an interval [lo, hi] missing the ``simulated`` value (NaN: nothing to compare) is named as
    the datasheet rows name it (analysis/pipeline/truth.py): the 6 h README demo printed x's sigma_b 1.65e-06
    beside [1.81e-06, 2.51e-06] and tau_b 537 beside [227, 530] without a word."""
    if flag:
        return flag, f"{flag}: no estimate from this record"
    if math.isfinite(simulated) and not lo <= simulated <= hi:
        return MISSED, MISSED
    return "", ""


def _shown(value: float) -> str:
    """The identified column: a term not detected has no estimate (NaN; its note gives the 90 % upper
    bound): a dash, not "nan"."""
    return f"{'—':>11}" if math.isnan(value) else f"{value:>11.4g}"


def _drift_note(cfg) -> str:
    """What the simulation adds beyond N, B, K: a warm-up or a room temperature drift, through the bias
    temperature coefficient, shows as slow terms (a row whose B or K misses says so)."""
    parts = []
    for dev in cfg.devices:
        if float(dev.sim.get("warmup_c", 0.0) or 0.0) > 0:
            parts.append("warm-up")
        if float(dev.sim.get("temp_drift_c", 0.0) or 0.0) > 0:
            parts.append("room temperature drift")
    if not parts:
        return ""
    what = " and ".join(sorted(set(parts)))
    return f"the simulated {what} (through the bias temperature coefficient) add to the slow terms"
