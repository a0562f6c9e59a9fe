"""Start-up stays light: the CLI and the simulators do not import what they do not use.

``imustation --help`` took ~4 s when every subcommand module imported the analysis
stack at module top; these tests check which modules get imported, never timings.
"""

import importlib
import json
import subprocess
import sys

import pytest

import imustation.analysis as analysis
from imustation.cli import cli

#: never needed to print help or to reject arguments
HEAVY = ("numpy", "scipy", "scipy.stats", "h5py", "matplotlib", "numba", "distributed", "tornado", "rosbags")
#: estimators the chip simulators (and hence ``imustation capture``) do not use
ESTIMATORS = tuple(f"imustation.analysis.estimators.{m}" for m in ("allan", "gmwm", "mli", "fitting")) + (
    "numba",
    "matplotlib",
)


def _loaded_after(code: str, names) -> list[str]:
    """Run ``code`` in a fresh interpreter and return which of ``names`` it left in sys.modules."""
    probe = f"{code}\nimport json, sys\nprint(json.dumps([n for n in {list(names)!r} if n in sys.modules]))"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_cli_import_skips_heavy_modules():
    assert _loaded_after("import imustation.cli", HEAVY) == []


def test_help_and_argument_errors_skip_heavy_modules():
    code = """
import contextlib, io
import click
from imustation.cli import cli
calls = [["--help"], ["--version"]] + [[name, "--help"] for name in cli.commands] + [
    ["analyze"], ["analyze", "--estimator", "bogus", "x.h5"], ["export", "--format", "nope", "x.h5"],
    ["import", "--time-unit", "h", "x.csv", "-o", "y.h5"], ["study", "--bogus"], ["capture"], ["nosuch"],
]
for args in calls:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        try:
            cli.main(args, prog_name="imustation")
        except SystemExit:
            pass
"""
    assert _loaded_after(code, HEAVY) == []


@pytest.mark.parametrize("module", ["imustation.analysis.estimators.models.standard", "imustation.drivers.sim"])
def test_simulators_skip_the_estimators(module):
    assert _loaded_after(f"import {module}", ESTIMATORS) == []


def test_noise_models_skip_scipy_stats():
    assert _loaded_after("import imustation.analysis.estimators.models.standard", ["scipy.stats"]) == []


def test_public_analysis_names_resolve():
    from imustation.analysis import StandardModel, fit_mli, oadev

    assert (oadev.__module__, fit_mli.__module__) == (
        "imustation.analysis.estimators.classical.allan",
        "imustation.analysis.estimators.ml.mli",
    )
    assert StandardModel.__module__ == "imustation.analysis.estimators.models.standard"
    assert sorted(analysis.__all__) == sorted(analysis._ORIGIN)
    for name in analysis.__all__:
        value = getattr(analysis, name)
        source = importlib.import_module(f"imustation.analysis.{analysis._ORIGIN[name]}")
        assert value is getattr(source, name), name
    assert set(analysis.__all__) <= set(dir(analysis))
    namespace: dict = {}
    exec("from imustation.analysis import *", namespace)
    assert set(analysis.__all__) <= set(namespace)


def test_submodules_still_import_from_the_package():
    from imustation.analysis import reports

    assert reports.__name__ == "imustation.analysis.reports"
    with pytest.raises(AttributeError, match="no_such_name"):
        analysis.no_such_name  # noqa: B018


def test_library_modules_use_the_cli_vocabularies():
    """The CLI's choices (analysis.pipeline.choices) are the ones the library modules act on."""
    from imustation.acquisition.importers import logs
    from imustation.analysis.pipeline import channel as pipeline
    from imustation.analysis.pipeline import choices, study
    from imustation.analysis.reports import export
    from imustation.units import TIME_UNITS

    assert pipeline.ESTIMATORS is choices.ESTIMATORS and pipeline.METHODS is choices.METHODS
    assert pipeline.DEFAULT_ESTIMATOR is choices.DEFAULT_ESTIMATOR
    assert export.FORMATS is choices.EXPORT_FORMATS and export.SOURCES is choices.EXPORT_SOURCES
    assert export.RW_CONVERSIONS is choices.RW_CONVERSIONS
    assert study.ESTIMATORS is choices.STUDY_ESTIMATORS and logs.TIME_UNITS is TIME_UNITS


def test_analyze_options_carry_the_library_values():
    from imustation.analysis.pipeline import channel as pipeline

    params = {p.name: p for p in cli.commands["analyze"].params}
    assert params["estimator"].type.choices == pipeline.ESTIMATORS
    assert params["estimator"].default == pipeline.DEFAULT_ESTIMATOR
    assert params["method"].type.choices == pipeline.METHODS


def test_one_option_vocabulary_across_commands():
    """-o/--output and --overwrite wherever a command writes a file; one default model and method, named in choices."""
    from imustation.analysis.pipeline import choices

    writers = ("capture", "demo", "export", "fleet", "import", "report", "study")
    for name in writers:
        opts = {o for p in cli.commands[name].params for o in p.opts}
        assert {"-o", "--output", "--overwrite"} <= opts, name  # and never replace an output without it
    assert "--out" in {o for p in cli.commands["study"].params for o in p.opts}  # the former spelling still works
    models = {name: p.default for name, c in cli.commands.items() for p in c.params if p.name == "model"}
    assert set(models) == {"analyze", "export", "fleet", "report"}
    assert set(models.values()) == {choices.DEFAULT_MODEL}
    params = {p.name: p for p in cli.commands["analyze"].params}
    assert params["method"].default == choices.DEFAULT_METHOD
    study = {p.name: p for p in cli.commands["study"].params}
    assert study["estimators"].default == ",".join(choices.DEFAULT_STUDY_ESTIMATORS)
