"""Paths of the repository and the test data (import this, not conftest, from tests)."""

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

REPO = Path(__file__).resolve().parent.parent
DATA = Path(__file__).resolve().parent / "data"
VALIDATION_BENCH = REPO / "bench" / "validation"


def bench_module(relative: str, key: str) -> ModuleType:
    """A script under bench/ (``relative``, e.g. "prediction/siblings.py") as a module, registered as ``key`` in
    sys.modules and loaded once (the bench scripts are not a package)."""
    if key not in sys.modules:
        spec = importlib.util.spec_from_file_location(key, REPO / "bench" / relative)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[key] = module
        spec.loader.exec_module(module)
    return sys.modules[key]


def validation_module(name: str) -> ModuleType:
    """bench/validation/<name>.py as a module (the key bench/prediction/siblings.py uses for the family too)."""
    return bench_module(f"validation/{name}.py", f"validation_{name}")
