"""Transitional alias of :mod:`imustation.analysis.pipeline.choices` (issue 20).

The field-recording importer (``analysis/field_import.py``) and ``cli/importcmd.py`` read
``TIME_UNITS`` here while they move to ``acquisition/importers``; delete this module once
they import :mod:`imustation.analysis.pipeline.choices`.
"""

from imustation.analysis.pipeline.choices import TIME_UNITS

__all__ = ["TIME_UNITS"]
