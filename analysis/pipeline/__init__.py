"""Pipeline: running the estimators over channels, runs and fleets.

Channels from run files and plain arrays (:mod:`.loaders`), the per-channel analysis and
its ``imustation-analysis`` JSON document (:mod:`.channel`), the enough-data verdict
(:mod:`.verdict`), tasks run serially or on a dask.distributed cluster (:mod:`.parallel`),
fleet tables, repeatability and outliers (:mod:`.fleet`), the Monte Carlo study
(:mod:`.study`), and the option vocabularies and defaults every command shares
(:mod:`.choices`, dependency-free so the CLI can build its options without numpy).
"""
