"""Reports: what the estimators' results become for people and other tools.

The summary a report opens with (:mod:`.summary`), noise tables in CSV, Markdown and
LaTeX (:mod:`.tables`), figures (:mod:`.plots`),
filter-parameter files for Kalibr, OpenVINS, VINS-Fusion and ORB-SLAM3 (:mod:`.export`),
attitude-error growth (:mod:`.attitude`), temperature, warm-up and temperature
coefficients (:mod:`.temperature`), and the report of one run or several: tables, figures
and an HTML page per run (:mod:`.runreport`).
"""
