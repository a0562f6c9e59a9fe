"""Shipped station configurations (package data: ``imustation.configs``)."""

from importlib.resources import files


def config_path(name: str) -> str:
    """Filesystem path of a shipped config, e.g. ``config_path("demo.toml")``."""
    return str(files(__name__).joinpath(name))
