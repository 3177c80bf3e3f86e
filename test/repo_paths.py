"""Paths of the repository and the test data (import this, not conftest, from tests)."""

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

REPO = Path(__file__).resolve().parent.parent
DATA = Path(__file__).resolve().parent / "data"
VALIDATION_BENCH = REPO / "bench" / "validation"


def validation_module(name: str) -> ModuleType:
    """bench/validation/<name>.py as a module (the validation scripts are not a package); loaded once."""
    key = f"validation_{name}"
    if key not in sys.modules:
        spec = importlib.util.spec_from_file_location(key, VALIDATION_BENCH / f"{name}.py")
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[key] = module
        spec.loader.exec_module(module)
    return sys.modules[key]
