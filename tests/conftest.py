"""Test configuration: make tests/ importable (naive.py, helpers.py) and locate ../shared."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
SEVEN_SCENES = SHARED / "data" / "7scenes-redkitchen"


@pytest.fixture
def seven_scenes() -> Path:
    if not SEVEN_SCENES.is_dir():
        pytest.skip("../shared/data/7scenes-redkitchen is not present")
    return SEVEN_SCENES
