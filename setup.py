"""ament_python package train_calib: builds with colcon in a ROS 2 workspace and installs with pip."""

from glob import glob
from pathlib import Path

from setuptools import Extension, find_packages, setup

PACKAGE = "train_calib"

# Every node is its own executable so `ros2 run train_calib <node>` works in a full ROS install.
NODES = [
    "gnss_speed_node",
    "ukf_node",
    "regime_node",
    "feature_node",
    "window_calib_node",
    "prediction_node",
]


def _files(pattern: str) -> list[str]:
    return sorted(p for p in glob(pattern) if Path(p).is_file())


def _tree(top: str) -> list[tuple[str, list[str]]]:
    """data_files entries installing every file under `top` to share/<package>/<top>/..."""
    entries = []
    for folder in sorted({str(p.parent) for p in Path(top).rglob("*") if p.is_file()}):
        entries.append((f"share/{PACKAGE}/{folder}", _files(f"{folder}/*")))
    return entries


# The window fit's C kernel (train_calib/window/_kernel.c): optional, the pure-Python path runs without a compiler.
KERNEL = Extension(
    f"{PACKAGE}.window._kernel",
    [f"{PACKAGE}/window/_kernel.c"],
    # no fused multiply-add: the kernel repeats the Python path's arithmetic operation for operation (its rows equal
    # the Python's bit for bit); clang would fuse on targets with FMA (aarch64) otherwise
    extra_compile_args=["-O2", "-std=c99", "-ffp-contract=off", "-Wall", "-Wextra"],
    optional=True,
)
# The UKF stage's C kernel (train_calib/estimation/_ukf_kernel.c: the filter's common step, the coast regression's
# push and candidates, the speed slope): optional likewise, the Python paths stay beside it; the same flags
UKF_KERNEL = Extension(
    f"{PACKAGE}.estimation._ukf_kernel",
    [f"{PACKAGE}/estimation/_ukf_kernel.c"],
    extra_compile_args=["-O2", "-std=c99", "-ffp-contract=off", "-Wall", "-Wextra"],
    optional=True,
)

# The ingest's C kernel (train_calib/ingest/_kernel.c: map matching in the continuity window for offline.add_many,
# the input messages of a bag's chunk for cdr_inputs): optional as the window's; no fused multiply-add and no
# builtin sin/cos (sincos fusion): the Python's floats
INGEST_KERNEL = Extension(
    f"{PACKAGE}.ingest._kernel",
    [f"{PACKAGE}/ingest/_kernel.c"],
    extra_compile_args=["-O2", "-std=c99", "-ffp-contract=off", "-fno-builtin", "-Wall", "-Wextra"],
    optional=True,
)


setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    ext_modules=[KERNEL, UKF_KERNEL, INGEST_KERNEL],
    python_requires=">=3.10",
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", _files("launch/*.launch.py")),
        *_tree("config"),
        *_tree("bags"),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="train_calib maintainers",
    maintainer_email="train-calib@example.org",
    description="Real-time train motion model calibration (UKF, regimes, features) for ROS 2",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [f"train-calib = {PACKAGE}.cli:main"]
        + [f"{node} = {PACKAGE}.nodes.{node}:main" for node in NODES],
    },
)
