"""Acquisition layer (``imustation.acquisition``): config, station, capture."""

from imustation.acquisition.capture import capture
from imustation.acquisition.config import StationConfig, load_config
from imustation.acquisition.station import Station

__all__ = ["capture", "load_config", "StationConfig", "Station"]
