"""Figures of a run (matplotlib, Agg; PNG and PDF): the paper's Fig. 6, 8, 9 styles and temperature.

* :func:`allan_figure` — measured Allan deviation with its confidence band, the
  identified model's Allan curve and each of its terms, and the earth-rate line
  (Fig. 6 style); below it the standardised residuals of the model-adequacy test
  with their band and the tau ranges where the model does not fit;
* :func:`allan_multi_figure` — several channels on one plot (Fig. 8);
* :func:`psd_figure` — two-sided Welch PSD near Nyquist with the model's exact
  sampled PSD (Fig. 9);
* :func:`temperature_figure` — temperature over time with the bias (block means of
  the rate) on a second axis.

Every figure carries its settings line (:func:`settings_line`: rate, bandwidth,
decimation/filter settings, duration, temperature span). Figures are built on
:class:`matplotlib.figure.Figure` directly (no pyplot state, no display);
:func:`save_figure` writes the files.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from imustation.analysis.estimators.classical.psd import log_average, welch_psd
from imustation.analysis.estimators.models.noise_models import NoiseModel
from imustation.analysis.estimators.selection.adequacy import MIN_EDF
from imustation.analysis.pipeline.channel import ChannelAnalysis
from imustation.analysis.reports.tables import units_of
from imustation.units import EARTH_RATE, display_units, format_duration, sensor_kind

#: device settings shown on figures besides rate and bandwidth (substrings of run-file attribute names)
_SETTING_HINTS = ("decim", "filter", "dlpf", "range", "bw_code")
_SIZE = (7.0, 4.6)
#: Welch window of the near-Nyquist PSD, s (about 0.1 Hz resolution, many windows to average)
_PSD_WINDOW_S = 8.0


def _sensor(ch) -> str | None:
    """``gyro``, ``accel`` or None (a plain array): the channel's kind, which chooses its units."""
    return sensor_kind(ch.units, ch.id)


#: noise-term parameter -> dimension of :func:`imustation.units.display_units`
_PARAM_DIM = {"sigma_w": "density", "sigma_b": "drift", "sigma_k": "drift", "tau_b": "time", "sigma_a": "angle"}
_PARAM_DIM["R"] = "ramp"


def settings_line(ch, temp_span_c: tuple[float, float] | None = None) -> str:
    """``rate 400 Hz, bandwidth 47 Hz, gyro_range_dps 125, duration 20m00s, 24.9-25.3 °C``."""
    s = dict(ch.meta.get("settings", {}))
    parts = [f"rate {ch.fs_hz:g} Hz"]
    if "bandwidth_hz" in s:
        parts.append(f"bandwidth {float(s['bandwidth_hz']):g} Hz")
    for k, v in sorted(s.items()):
        if k not in ("rate_hz", "bandwidth_hz") and any(h in k for h in _SETTING_HINTS):
            parts.append(f"{k} {v}")
    parts.append(f"duration {format_duration(ch.n / ch.fs_hz)}")
    if temp_span_c is not None and all(math.isfinite(t) for t in temp_span_c):
        parts.append(f"temperature {temp_span_c[0]:.2f}–{temp_span_c[1]:.2f} °C")
    else:
        parts.append("temperature not recorded")
    return ", ".join(parts)


def _new(title: str, settings: str, residual_panel: bool = False) -> tuple[Figure, object, object]:
    """A figure with one axes (and a residual axes below it, sharing x, or None) and its settings line."""
    fig = Figure(figsize=(_SIZE[0], _SIZE[1] * 1.3) if residual_panel else _SIZE, layout="constrained")
    FigureCanvasAgg(fig)
    if residual_panel:
        ax, low = fig.subplots(2, 1, sharex=True, height_ratios=(3, 1))
    else:
        ax, low = fig.add_subplot(), None
    ax.set_title(title, fontsize=10)
    fig.text(0.5, 0.005, settings, ha="center", va="bottom", fontsize=7, color="0.3", wrap=True)
    fig.get_layout_engine().set(h_pad=0.25)
    return fig, ax, low


def _residual_panel(ax, tau: np.ndarray, adq) -> None:
    """Standardised residuals of the measured AVAR against the model, the band, the misfit ranges."""
    z = np.asarray(adq.z, dtype=float)
    shown = np.isfinite(z)
    tested_edf = shown & (np.asarray(adq.edf) >= MIN_EDF)
    big = float(np.max(np.abs(z[tested_edf]))) if tested_edf.any() else 0.0
    lim = min(max(4.0, 1.15 * adq.band if math.isfinite(adq.band) else 0.0, 1.1 * big), 50.0)
    zc = np.clip(z, -lim, lim)
    ax.semilogx(tau[tested_edf], zc[tested_edf], "k.", ms=3)
    ax.semilogx(tau[shown & ~tested_edf], zc[shown & ~tested_edf], ".", color="0.6", ms=3)
    tested = np.asarray(adq.tested, dtype=bool)
    ax.semilogx(tau[tested], zc[tested], "o", mfc="none", mec="C0", ms=5)
    if math.isfinite(adq.band):
        for sgn in (-1, 1):
            ax.axhline(sgn * adq.band, color="C3", ls="--", lw=0.8)
    ax.axhline(0.0, color="0.4", lw=0.6)
    for m in adq.misfit:
        ax.axvspan(m.tau_lo / 1.05, m.tau_hi * 1.05, color="C3", alpha=0.12, lw=0)
    ax.set_ylim(-lim * 1.05, lim * 1.05)
    ax.set_ylabel("residual z", fontsize=8)
    ax.set_xlabel("averaging time τ [s]")
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    band = f"±{adq.band:.2f}" if math.isfinite(adq.band) else "-"
    ax.set_title(
        f"model {adq.summary()}\nz of measured vs model AVAR (○ taus of the χ² statistic, grey < {MIN_EDF:g} EDF), "
        f"dashed: band {band}",
        fontsize=7,
    )


def _term_label(t, sensor: str | None, bound: dict[str, float] | None = None) -> str:
    """``GaussMarkov (sigma_b 188 °/h/√h, tau_b 381 s)``: every value in its display unit; a value
    equal to one of the fit's parameters at their search bound (``bound``: name -> value) says so."""
    parts = []
    for k, v in t.params().items():
        _, unit, factor = display_units(sensor, _PARAM_DIM.get(k, "rate"))
        text = f"{v * factor:.3g} {unit}"
        at = any(
            name.rstrip("0123456789") == k and math.isclose(v, b, rel_tol=1e-9) for name, b in (bound or {}).items()
        )
        parts.append(f"{k} at bound ({text})" if at else f"{k} {text}")
    return f"{type(t).__name__} ({', '.join(parts)})"


def term_adev(term, tau: np.ndarray) -> np.ndarray:
    """One model term's Allan deviation at ``tau`` (s), NaN where its Allan variance is not positive: a
    device filter's term (lp) is a variance deficit, negative everywhere, and its square root leaked
    numpy's 'invalid value encountered in sqrt' at the end of a lab-realistic report."""
    avar = np.asarray(term.avar(tau), dtype=float)
    return np.sqrt(np.where(avar > 0, avar, np.nan))


def allan_figure(res: ChannelAnalysis, settings: str = "", earth_rate: bool = True) -> Figure:
    """Fig. 6: ADEV with its 68 % band, the identified model's ADEV and terms; earth rate for gyros."""
    ch, al = res.channel, res.allan
    adq = res.adequacy_of(res.noise_model)
    fig, ax, low = _new(f"Allan deviation — {ch.id}", settings, residual_panel=adq is not None)
    ax.fill_between(al.tau, al.adev_lo, al.adev_hi, color="0.8", label="68 % confidence", linewidth=0)
    ax.loglog(al.tau, al.adev, "k.", ms=3, label="measured (overlapping)")
    fit = res.noise_model
    model: NoiseModel | None = fit.noise_model
    if model is not None:
        tau = np.logspace(np.log10(al.tau[0]), np.log10(al.tau[-1]), 200)
        ax.loglog(tau, model.adev(tau, ch.fs_hz), "C3-", lw=1.5, label=f"identified {fit.model} ({fit.estimator})")
        for i, t in enumerate(model.terms):  # continuous forms: the sampled GM form cancels badly for tau_b >> tau
            bound = {k: fit.params[k] for k in fit.at_bound if k in fit.params}
            adev = term_adev(t, tau)
            if np.isfinite(adev).any():
                ax.loglog(tau, adev, "--", color=f"C{i}", lw=0.9, label=_term_label(t, _sensor(ch), bound))
    sensor = _sensor(ch)
    if earth_rate and sensor == "gyro":
        ax.axhline(EARTH_RATE, color="C2", ls=":", lw=1, label=f"earth rate {EARTH_RATE:.3g} rad/s")
    ax.set_ylabel(f"Allan deviation [{units_of(sensor, 'B')[0]}]")
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    ax.legend(fontsize=7, loc="best")
    if adq is not None:
        _residual_panel(low, np.asarray(al.tau, dtype=float), adq)
    else:
        ax.set_xlabel("averaging time τ [s]")
    return fig


def allan_multi_figure(
    results: Sequence[ChannelAnalysis], title: str = "Allan deviation", settings: str = ""
) -> Figure:
    """Fig. 8: measured ADEV (with bands) of several channels, and their identified models."""
    fig, ax, _ = _new(title, settings)
    sensors = set()
    for i, res in enumerate(results):
        al, c = res.allan, f"C{i % 10}"
        ax.fill_between(al.tau, al.adev_lo, al.adev_hi, color=c, alpha=0.15, linewidth=0)
        ax.loglog(al.tau, al.adev, ".", color=c, ms=2.5, label=res.channel.id)
        if res.noise_model.noise_model is not None:
            ax.loglog(al.tau, res.noise_model.noise_model.adev(al.tau, res.channel.fs_hz), "-", color=c, lw=0.9)
        sensors.add(_sensor(res.channel))
    if sensors == {"gyro"}:
        ax.axhline(EARTH_RATE, color="0.4", ls=":", lw=1, label="earth rate")
    unit = units_of(sensors.pop(), "B")[0] if len(sensors) == 1 else "SI: rad/s, m/s²"
    ax.set_xlabel("averaging time τ [s]")
    ax.set_ylabel(f"Allan deviation [{unit}]")
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    ax.legend(fontsize=7, loc="best", title="dots: data, lines: identified models", title_fontsize=7)
    return fig


def psd_figure(res: ChannelAnalysis, settings: str = "", f_min_hz: float = 1.0) -> Figure:
    """Fig. 9: two-sided Welch PSD from ``f_min_hz`` to Nyquist, with the model's exact sampled PSD."""
    ch = res.channel
    longest = max(b - a for a, b in ch.segments)
    nps = int(min(2 ** math.floor(math.log2(_PSD_WINDOW_S * ch.fs_hz)), 2 ** math.floor(math.log2(longest))))
    psd = log_average(welch_psd(ch.data, ch.fs_hz, scale=ch.scale, nperseg=nps, segments=ch.segments, sides="two"), 40)
    keep = psd.f >= min(f_min_hz, ch.fs_hz / 4)
    fig, ax, _ = _new(f"PSD near Nyquist — {ch.id}", settings)
    ax.loglog(psd.f[keep], psd.psd[keep], color="0.6", lw=1, label=f"Welch ({psd.windows} windows of {psd.nperseg})")
    model = res.noise_model.noise_model
    if model is not None:
        f = np.logspace(np.log10(psd.f[keep][0]), np.log10(ch.fs_hz / 2), 300)
        ax.loglog(f, model.psd(f, ch.fs_hz), "k-", lw=1.2, label=f"identified {res.noise_model.model} (exact, sampled)")
    ax.axvline(ch.fs_hz / 2, color="0.3", ls=":", lw=0.8, label=f"Nyquist {ch.fs_hz / 2:g} Hz")
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel(f"two-sided PSD [({units_of(_sensor(ch), 'B')[0]})²/Hz]")
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    ax.legend(fontsize=7, loc="best")
    return fig


def bias_track(rate: np.ndarray, fs_hz: float, block_s: float, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Block means of the rate: times (s, block centres) and bias (unit) over blocks of ``block_s`` s."""
    m = max(1, int(round(block_s * fs_hz)))
    k = len(rate) // m
    if k == 0:
        return np.zeros(0), np.zeros(0)
    means = rate[: k * m].reshape(k, m).astype(np.float64).mean(axis=1) * scale
    return (np.arange(k) + 0.5) * m / fs_hz, means


def temperature_figure(
    t_s: np.ndarray,
    temp_c: np.ndarray,
    biases: Sequence[tuple[str, np.ndarray, np.ndarray]],
    *,
    label: str,
    bias_unit: str,
    settings: str = "",
    warmup_s: float | None = None,
) -> Figure:
    """Temperature (°C) over time (s from the start), with biases ``(label, t_s, bias)`` on a second axis."""
    fig, ax, _ = _new(f"Temperature and bias — {label}", settings)
    h = 3600.0
    ax.plot(t_s / h, temp_c, "k-", lw=1.2, label="temperature")
    ax.set_xlabel("time [h]")
    ax.set_ylabel("temperature [°C]")
    ax2 = ax.twinx()
    for i, (lbl, bt, b) in enumerate(biases):
        ax2.plot(bt / h, b, "-", color=f"C{i % 10}", lw=0.8, label=f"bias {lbl}")
    ax2.set_ylabel(f"bias [{bias_unit}]")
    if warmup_s is not None and warmup_s > 0:
        ax.axvspan(0, warmup_s / h, color="0.85", label="warm-up (excluded)")
    ax.grid(True, lw=0.3, alpha=0.5)
    lines = ax.get_legend_handles_labels()
    lines2 = ax2.get_legend_handles_labels()
    ax.legend(lines[0] + lines2[0], lines[1] + lines2[1], fontsize=7, loc="best")
    return fig


def save_figure(fig: Figure, stem: str | os.PathLike) -> list[str]:
    """Write ``stem.png`` (150 dpi) and ``stem.pdf``; returns both paths."""
    out = []
    for ext, kw in ((".png", {"dpi": 150}), (".pdf", {})):
        path = os.fspath(stem) + ext
        fig.savefig(path, **kw)
        out.append(path)
    return out


def attitude_figure(res: ChannelAnalysis, settings: str = "", n_lags: int = 20, min_windows: int = 10) -> Figure:
    """Angle-error std vs integration time: the identified model's prediction against the data's spread.

    Lags from 10 samples to 1/``min_windows`` of the longest segment; independent windows. The data's
    turn-on bias is the segment mean, so the model curve uses the bias variance about that mean
    (:func:`~imustation.analysis.reports.attitude.angle_error_std` with ``record_s``).
    """
    from imustation.analysis.reports.attitude import angle_error_std, angle_spread

    ch = res.channel
    a, b = max(ch.segments, key=lambda s: s[1] - s[0])
    t_max = (b - a) / ch.fs_hz / min_windows
    lags = np.logspace(np.log10(10.0 / ch.fs_hz), np.log10(t_max), n_lags)
    sp = angle_spread(ch.data, ch.fs_hz, lags, scale=ch.scale, segment=(a, b))
    unit = display_units(_sensor(ch), "angle")[0]
    fig, ax, _ = _new(f"Attitude-error growth — {ch.id}", settings)
    yerr = np.vstack([sp.std - sp.std_lo, sp.std_hi - sp.std])
    ax.errorbar(sp.t_s, sp.std, yerr=yerr, fmt="k.", ms=4, lw=0.8, label=f"data: std over {sp.windows} windows")
    model = res.noise_model.noise_model
    if model is not None:
        t = np.logspace(np.log10(sp.t_s[0]), np.log10(sp.t_s[-1]), 200)
        rec = (b - a) / ch.fs_hz
        lbl = f"{res.noise_model.model} model, bias about the record mean"
        ax.loglog(t, angle_error_std(model, t, record_s=rec), "C3-", lw=1.4, label=lbl)
        ax.loglog(t, angle_error_std(model, t, bias_known=True), "C0--", lw=1, label="model, bias known at start")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("integration time [s]")
    ax.set_ylabel(f"angle error std [{unit}]")
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    ax.legend(fontsize=7, loc="best")
    return fig


def fleet_allan_figure(
    curves: Sequence[tuple[str, str, str, np.ndarray, np.ndarray, bool]],
    title: str = "Allan deviation — fleet",
    ncols: int = 3,
) -> Figure:
    """Every run's measured Allan deviation, one panel per axis group.

    ``curves``: ``(group, sensor, label, tau [s], adev [SI], outlier)``; panels
    in first-appearance order of ``group`` (e.g. ``"bmx055 gyro z"``). Runs in
    grey, outliers in colour with their label.
    """
    groups: dict[str, list] = {}
    for c in curves:
        groups.setdefault(c[0], []).append(c)
    n = max(1, len(groups))
    ncols = max(1, min(ncols, n))
    nrows = math.ceil(n / ncols)
    fig = Figure(figsize=(4.2 * ncols, 3.3 * nrows + 0.4), layout="constrained")
    FigureCanvasAgg(fig)
    fig.suptitle(title, fontsize=11)
    for k, (group, cs) in enumerate(groups.items()):
        ax = fig.add_subplot(nrows, ncols, k + 1)
        n_out = 0
        for _, _, label, tau, adev, outlier in cs:
            if outlier:
                ax.loglog(tau, adev, "-", color=f"C{3 + n_out % 7}", lw=1.2, label=f"outlier: {label}")
                n_out += 1
            else:
                ax.loglog(tau, adev, "-", color="0.45", lw=0.6, alpha=0.6)
        ax.plot([], [], "-", color="0.45", lw=0.6, label=f"{len(cs) - n_out} runs")
        sensor = cs[0][1]
        ax.set_title(group, fontsize=9)
        ax.set_xlabel("τ [s]", fontsize=8)
        ax.set_ylabel(f"ADEV [{units_of(sensor, 'B')[0]}]", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
        ax.legend(fontsize=6, loc="best")
    return fig
