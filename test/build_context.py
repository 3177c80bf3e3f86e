"""Which build the tests run against: the source checkout of `make setup`, or a colcon workspace's `colcon test`.

`colcon test` runs pytest in the package's source directory, so `import train_calib` finds the source tree, while
colcon built the window fit's C kernel (train_calib/window/_kernel.c) and the UKF stage's
(train_calib/estimation/_ukf_kernel.c) into build/ and install/ only. There the source tree has no kernel although the
build has one: the kernels' tests skip, and the tests that name the fit path expect the Python twin. Everywhere else
(make test, a pip install) a missing kernel is a failed build and the tests fail as before.
"""

from __future__ import annotations

import sys
from pathlib import Path

import train_calib
from train_calib.window import fast

SOURCE_PACKAGE = Path(train_calib.__file__).resolve().parent


def _built_elsewhere(subpackage: str, module: str) -> Path | None:
    """The built extension train_calib.<subpackage>.<module> of another copy of train_calib on sys.path."""
    for entry in sys.path:
        folder = Path(entry or ".").resolve() / "train_calib" / subpackage
        if folder.parent == SOURCE_PACKAGE or not folder.is_dir():
            continue
        built = sorted(folder.glob(f"{module}*.so")) + sorted(folder.glob(f"{module}*.pyd"))
        if built:
            return built[0]
    return None


def installed_kernel_elsewhere() -> Path | None:
    """A built kernel of another copy of train_calib on sys.path (colcon's install/), when the imported one has none."""
    if fast.KERNEL_AVAILABLE:
        return None
    return _built_elsewhere("window", "_kernel")


def kernel_skip_reason() -> str | None:
    """Why the kernel's tests cannot run here (colcon test of the source tree), else None."""
    installed = installed_kernel_elsewhere()
    if installed is None:
        return None
    return (f"train_calib is imported from the source tree {SOURCE_PACKAGE} (as `colcon test` does), which has no "
            f"built C kernel; it was built into {installed.parent} only")  # fmt: skip


def ukf_kernel_skip_reason() -> str | None:
    """kernel_skip_reason of the UKF stage's kernel (train_calib/estimation/_ukf_kernel.c)."""
    from train_calib.estimation import ukf_fast

    installed = None if ukf_fast.KERNEL_AVAILABLE else _built_elsewhere("estimation", "_ukf_kernel")
    if installed is None:
        return None
    return (f"train_calib is imported from the source tree {SOURCE_PACKAGE} (as `colcon test` does), which has no "
            f"built C kernel of the UKF stage; it was built into {installed.parent} only")  # fmt: skip


# "C kernel" wherever the kernel should be there (a missing one then fails the tests that expect it)
EXPECTED_FIT_PATH = "Python" if kernel_skip_reason() else "C kernel"
