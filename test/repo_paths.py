"""Paths of the repository and the test data (import this, not conftest, from tests)."""

from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
DATA = Path(__file__).resolve().parent / "data"
