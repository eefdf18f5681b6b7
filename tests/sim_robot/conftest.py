from pathlib import Path

import pytest

WORLDS = Path(__file__).resolve().parents[2] / "configs" / "worlds"


@pytest.fixture
def worlds_dir() -> Path:
    return WORLDS


def _base_world(**overrides) -> dict:
    """A small valid world-file structure that tests modify."""
    data = {
        "name": "test",
        "arena": {"shape": "circle", "radius_m": 1.0},
        "robot": {
            "sensor_angles_deg": [-90.0, -45.0, 0.0, 45.0, 90.0],
            "max_range_m": 0.5,
            "start": {"x_m": 0.0, "y_m": 0.0, "heading_deg": 0.0},
        },
        "obstacles": [],
    }
    for key, value in overrides.items():
        data[key] = value
    return data


@pytest.fixture
def base_world():
    """Factory: ``base_world(obstacles=[...], robot={...})`` -> a world-file dict."""
    return _base_world
