"""Test session set-up: DDS isolation and shared fixtures.

Every pytest run takes a ROS domain id of its own (a lock file per id, held for the session, so
concurrent runs on one machine never share one), keeps discovery on localhost and logs to a
temporary directory. Subprocesses inherit the environment.
"""

from __future__ import annotations

import fcntl
import os
import tempfile
from pathlib import Path

import pytest
from repo_paths import DATA

_DOMAIN_LOCK = None


def _claim_domain_id() -> int:
    """The first free id in 1..101 (ids above 101 may collide with ephemeral ports on Linux)."""
    global _DOMAIN_LOCK
    lock_dir = Path(tempfile.gettempdir()) / "train_calib_ros_domains"
    lock_dir.mkdir(exist_ok=True)
    start = os.getpid() % 101
    for k in range(101):
        domain = 1 + (start + k) % 101
        handle = open(lock_dir / f"{domain}.lock", "w")  # noqa: SIM115 - held for the session
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        _DOMAIN_LOCK = handle
        return domain
    raise RuntimeError("no free ROS domain id in 1..101")


def pytest_configure(config: pytest.Config) -> None:
    os.environ["ROS_DOMAIN_ID"] = str(_claim_domain_id())
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    os.environ["ROS_LOG_DIR"] = tempfile.mkdtemp(prefix="train_calib_roslog_")
    os.environ.setdefault("RCUTILS_LOGGING_BUFFERED_STREAM", "0")


@pytest.fixture
def rclpy_context():
    """An initialised rclpy context of its own, shut down after the test."""
    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


@pytest.fixture
def data_dir() -> Path:
    return DATA
