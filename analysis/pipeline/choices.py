"""Option vocabularies of the analysis layer, in a module with no dependencies.

The CLI builds its option choices and defaults from these when it starts, before
numpy or scipy are loaded; the modules that act on them import them from here.
"""

from __future__ import annotations

#: the noise model fitted unless ``--model`` says otherwise (analyze, report, export, fleet):
#: the paper's standard model, white rate noise + one Gauss-Markov bias (eq. 22)
DEFAULT_MODEL = "wn+gm"
#: the term codes of a model name (analysis/estimators/noise_models.py parse_model), spelled out
MODEL_TERMS = {
    "wn": "white rate noise (angle random walk, N = sigma_w)",
    "gm": "first-order Gauss-Markov bias (sigma_b, tau_b); 2gm, 3gm: two or three of them",
    "rw": "rate random walk (K = sigma_k)",
    "wa": "white angle noise (sigma_a, e.g. ring-laser gyros)",
}
#: the ``--model`` help of every command that fits a model (analyze, report, export, fleet)
MODEL_HELP = (
    "Noise model fitted: terms joined by '+', exactly one wn - "
    + "; ".join(f"{code} {text}" for code, text in MODEL_TERMS.items())
    + ". E.g. wn+gm (the paper's standard model), wn+2gm, wn+gm+rw, wa+wn+gm (docs/mli.md)."
)
#: noise-model methods of ``analyze --method`` (analysis/pipeline/channel.py) and the default
METHODS = ("mli", "gmwm", "both")
DEFAULT_METHOD = "mli"
#: estimators that can fill the ``noise_model`` block (``analyze --estimator``)
ESTIMATORS = ("mli-f", "mli", "gmwm")
#: the default: ML_i-F won the Monte Carlo study of docs/noise-model.md
DEFAULT_ESTIMATOR = "mli-f"

#: estimators of the Monte Carlo study (``study --estimators``, analysis/pipeline/study.py)
STUDY_ESTIMATORS = ("mli-log", "mli-uniform", "ml-log", "ml-uniform", "gmwm", "gmwm-single", "mli-f")
#: the study's default: the paper's ML_i on its log pattern
DEFAULT_STUDY_ESTIMATORS = ("mli-log",)

#: filter-parameter formats, parameter sources and random-walk conversions of ``export``
#: (analysis/reports/export.py)
EXPORT_FORMATS = ("kalibr", "openvins", "vins", "orbslam3")
EXPORT_SOURCES = ("model", "mli", "ieee")
RW_CONVERSIONS = ("diffusion", "tau_b")

#: time units of text logs -> nanoseconds (``import --time-unit``, acquisition/importers/logs.py)
TIME_UNITS = {"s": 1e9, "ms": 1e6, "us": 1e3, "ns": 1.0}
