"""Option vocabularies of the analysis layer, in a module with no dependencies.

The CLI builds its option choices and defaults from these when it starts, before
numpy or scipy are loaded; the modules that act on them import them from here.
"""

from __future__ import annotations

#: ``--model auto``: the simplest model of the family that fits (analysis/estimators/selection/model_choice.py)
MODEL_AUTO = "auto"
#: the noise model fitted unless ``--model`` says otherwise (analyze, report, export, fleet)
DEFAULT_MODEL = MODEL_AUTO
#: the paper's standard model, white rate noise + one Gauss-Markov bias (eq. 22), always reported
#: beside an automatic choice
PAPER_MODEL = "wn+gm"
#: the term codes of a model name (analysis/estimators/models/noise_models.py parse_model), spelled out
MODEL_TERMS = {
    "wn": "white rate noise (angle random walk, N = sigma_w; required)",
    "wa": "white angle noise (quantisation, Q = sigma_a)",
    "gm": "first-order Gauss-Markov bias (sigma_b, tau_b); 2gm, 3gm: two or three of them",
    "fl": "bias instability (flicker floor B, a fixed sum of Gauss-Markov terms)",
    "rw": "rate random walk (K = sigma_k)",
    "lp": "device low-pass filter (its memory, from the run file's settings or estimated)",
}
#: the ``--model`` help of every command that fits a model (analyze, report, export, fleet)
MODEL_HELP = (
    "Noise model: 'auto' (default: the simplest model of the family that fits, chosen by BIC and a check "
    "against the Allan deviation; the paper's wn+gm is reported beside it) or terms joined by '+' - "
    + "; ".join(f"{code} {text}" for code, text in MODEL_TERMS.items())
    + ". E.g. wn+gm (the paper's standard model), wn+2gm, wn+fl+rw+lp (docs/noise-model.md). --model says WHAT "
    "is fitted; analyze's --estimator says HOW the reported fit is made, --method which comparison fits are shown."
)
#: the model term of a device filter: ML_i's log pattern cannot hold it (its first intervals are
#: shorter than the filter's memory), so ML_i fits such a model on the uniform pattern
FILTER_TERM = "lp"
#: ``analyze --pattern`` choices; None (the default): log, or uniform for a model with a filter
PATTERNS = ("log", "uniform")
#: noise-model methods of ``analyze --method`` (analysis/pipeline/channel.py) and the default
METHODS = ("mli", "gmwm", "both")
DEFAULT_METHOD = "mli"
#: help of ``analyze --estimator`` and ``--method``: how they differ from ``--model``
ESTIMATOR_HELP = (
    "HOW the reported noise model is fitted (the table's row per channel, the JSON 'noise_model' block, "
    "what report/export/fleet use): mli-f (default: ML_i's integrated likelihood + the fine-scale Allan "
    "variance, docs/noise-model.md), mli (the paper's ML_i) or gmwm. Works with every --model."
)
METHOD_HELP = (
    "Comparison fits made BESIDE the reported one (shown under 'details:' with --verbose, JSON 'mli'/'gmwm'): "
    "mli (the paper's ML_i; with --model auto it fits the paper's wn+gm), gmwm (docs/gmwm.md) or both. They "
    "never change the reported numbers."
)
#: estimators that can fill the ``noise_model`` block (``analyze --estimator``)
ESTIMATORS = ("mli-f", "mli", "gmwm")
#: the default: ML_i-F won the Monte Carlo study of docs/noise-model.md
DEFAULT_ESTIMATOR = "mli-f"

#: ``--warmup``: its default in every command that analyses run files (analysis/pipeline/warmup.py)
DEFAULT_WARMUP = "auto"
WARMUP_HELP = (
    "Start of each device's record left out of the analysis: auto (default: up to the end of a warm-up its "
    "own temperature shows - a real change of many reading steps and a fitted transient; nothing otherwise), "
    "0 (nothing), or a duration such as 1h (the paper discards at least the first hour). analyze, report, "
    "export, fleet and demo cut the same for the same option and say what they cut."
)

#: estimators of the Monte Carlo study (``study --estimators``, analysis/pipeline/study.py)
STUDY_ESTIMATORS = ("mli-log", "mli-uniform", "ml-log", "ml-uniform", "gmwm", "gmwm-single", "mli-f")
#: the study's default: the paper's ML_i on its log pattern
DEFAULT_STUDY_ESTIMATORS = ("mli-log",)

#: filter-parameter formats, parameter sources and random-walk conversions of ``export``
#: (analysis/reports/export.py)
EXPORT_FORMATS = ("kalibr", "openvins", "vins", "orbslam3")
EXPORT_SOURCES = ("model", "mli", "ieee")
RW_CONVERSIONS = ("diffusion", "tau_b")
