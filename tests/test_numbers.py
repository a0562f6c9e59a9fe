"""Numbers a person reads: unbounded and unidentified values are printed as such (analysis/reports/numbers.py)."""

from __future__ import annotations

import math

import numpy as np

from imustation.analysis.estimators.selection.adequacy import Adequacy
from imustation.analysis.pipeline.verdict import Interval, data_verdict
from imustation.analysis.reports.numbers import factor, interval, number, p_value


def test_an_interval_reaching_its_search_range_is_not_printed_as_numbers():
    # analyze printed 'B 1.509e-05 [8.326e-32, 6.997e+17]' for a bias instability the record does not pin down
    assert interval(1.509e-05, 8.326e-32, 6.997e17) == "[~0, unbounded]"
    assert interval(1.509e-05, 1.2e-06, 2.2e-04) == "[1.2e-06, 0.00022]"
    assert interval(300.0, 120.0, math.inf) == "[120, unbounded]"
    assert interval(3.0, 0.0, 5.0) == "[~0, 5]"
    assert interval(3.0, math.nan, 5.0) == "no interval"


def test_factors_numbers_and_p_values():
    assert factor(6.18e63) == ">1e6" and factor(math.inf) == "unbounded" and factor(math.nan) == "unbounded"
    assert factor(3.84) == "3.8"
    assert number(math.nan, missing="not identified") == "not identified"
    assert number(math.inf, infinite="unbounded") == "unbounded" and number(2.5e-3) == "0.0025"
    assert p_value(0.0) == "<1e-4" and p_value(0.51) == "0.51" and p_value(math.nan) == "-"


def test_verdict_and_adequacy_text_never_print_absurd_numbers():
    # 'its 90 % interval spans a factor 9283470844165404317743082975205735977869473454773640811648122880.0'
    v = data_verdict(10800.0, math.inf, 100.0, intervals={"sigma_b": Interval(2.39e-9, 1e-40, 1e24)})
    text = "; ".join(v.reasons)
    assert v.verdict == "not enough" and "more than a factor 25" in text
    assert "e+" not in text.split("sigma_b = 2.39e-09")[1]
    e = np.zeros(0)
    adq = Adequacy("does not fit", 0.0, 1e4, 30, 0.0, 0.0, 0.05, 2.0, e, e, e, e)
    assert adq.summary() == "does not fit (p<1e-4)"


def test_analyze_and_fleet_of_a_short_lab_record_leak_no_warnings(tmp_path):
    """numpy RuntimeWarnings leaked from fleet and analyze (e.g. the std of [inf, inf]); a 12 s capture of
    the realistic lab, every gyro x axis, through the analysis, the table and the fleet statistics."""
    import warnings

    from imustation.acquisition import capture, load_config
    from imustation.analysis.pipeline.fleet import flag_outliers, repeatability
    from imustation.analysis.pipeline.parallel import AnalysisOptions, plan_tasks, run_tasks
    from imustation.analysis.reports.analyzetable import results_table
    from imustation.analysis.reports.fleettable import fleet_markdown, fleet_rows
    from imustation.configs import config_path

    path = tmp_path / "lab.h5"
    capture(load_config(config_path("lab-realistic.toml")), path, 12.0, simulate=True, sim_level="model")
    tasks, _ = plan_tasks([str(path)], ["*/gyro/x"])
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        res, _ = run_tasks(tasks, AnalysisOptions())
        done = [r for r in res if r is not None]
        text = results_table(done, verbose=True)
        rows = flag_outliers(fleet_rows(done))
        fleet_markdown(rows, repeatability(rows))
    assert done and "e+17" not in text and "e-3" not in text.split("details:")[0]


def test_an_interval_end_equal_to_its_value_is_not_printed_to_six_digits():
    # analyze printed mti/accel/z's B as '0.582311 [0.582311, 8.61742]': the loop that adds digits until
    # value and ends differ could never separate an end equal to the value (second newcomer run)
    from imustation.analysis.reports.analyzetable import cell
    from imustation.analysis.reports.tables import Estimate

    assert cell(Estimate(0.5823114, 0.5823114, 8.617421)) == "0.582 [0.582, 8.62]"
    assert cell(Estimate(41.04, 41.0, 41.08)) == "41.04 [41, 41.08]"  # a narrow interval still gets its digits


def test_channels_with_the_same_attention_text_share_one_line():
    # a 12 s record of the whole lab printed 31 'needs attention' lines of the same reason (second newcomer run)
    from imustation.analysis.reports.analyzetable import attention_lines

    short = ["not enough data: record of 12 s is shorter than 60 s: too short for any bias term"]
    todo = [(f"dev{i}/gyro/x", short) for i in range(31)] + [("fog/gyro/z", ["tau_b at the search bound"])]
    lines = attention_lines(todo)
    assert lines == [
        f"  31 channels (dev0/gyro/x, dev1/gyro/x and 29 more): {short[0]}",
        "  fog/gyro/z: tau_b at the search bound",
    ]
    two = [("a/gyro/x", short), ("b/gyro/x", short)]  # a pair keeps its own lines
    assert attention_lines(two) == [f"  a/gyro/x: {short[0]}", f"  b/gyro/x: {short[0]}"]


def test_the_report_tables_print_an_interval_reaching_its_search_range_as_analyze_does():
    # report's summary.md and noise.md printed an imported white-noise log's B as '0.797 [5.25e-26, 1.12e+25]'
    # (analyze: '0.797 [~0, unbounded]'), and an end equal to the value at six digits (second newcomer run)
    from imustation.analysis.reports.analyzetable import cell
    from imustation.analysis.reports.tables import Estimate, fmt_estimate

    wide = Estimate(0.797, 5.25e-26, 1.12e25)
    assert fmt_estimate(wide) == cell(wide) == "0.797 [~0, unbounded]"
    assert fmt_estimate(Estimate(0.5823114, 0.5823114, 8.617421)) == "0.582 [0.582, 8.62]"
    assert fmt_estimate(Estimate(41.04, 41.0, 41.08)) == "41.04 [41, 41.08]"
    assert fmt_estimate(Estimate(3.0, float("nan"), float("nan"))) == "3"
