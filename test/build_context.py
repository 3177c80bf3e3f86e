"""Which build the tests run against: the source checkout of `make setup`, or a colcon workspace's `colcon test`.

`colcon test` runs pytest in the package's source directory, so `import train_calib` finds the source tree, while
colcon built the window fit's C kernel (train_calib/window/_kernel.c) into build/ and install/ only. There the
source tree has no kernel although the build has one: the kernel's tests skip, and the tests that name the fit path
expect the Python twin. Everywhere else (make test, a pip install) a missing kernel is a failed build and the tests
fail as before.
"""

from __future__ import annotations

import sys
from pathlib import Path

import train_calib
from train_calib.window import fast

SOURCE_PACKAGE = Path(train_calib.__file__).resolve().parent


def installed_kernel_elsewhere() -> Path | None:
    """A built kernel of another copy of train_calib on sys.path (colcon's install/), when the imported one has none."""
    if fast.KERNEL_AVAILABLE:
        return None
    for entry in sys.path:
        folder = Path(entry or ".").resolve() / "train_calib" / "window"
        if folder.parent == SOURCE_PACKAGE or not folder.is_dir():
            continue
        built = sorted(folder.glob("_kernel*.so")) + sorted(folder.glob("_kernel*.pyd"))
        if built:
            return built[0]
    return None


def kernel_skip_reason() -> str | None:
    """Why the kernel's tests cannot run here (colcon test of the source tree), else None."""
    installed = installed_kernel_elsewhere()
    if installed is None:
        return None
    return (f"train_calib is imported from the source tree {SOURCE_PACKAGE} (as `colcon test` does), which has no "
            f"built C kernel; it was built into {installed.parent} only")  # fmt: skip


# "C kernel" wherever the kernel should be there (a missing one then fails the tests that expect it)
EXPECTED_FIT_PATH = "Python" if kernel_skip_reason() else "C kernel"
