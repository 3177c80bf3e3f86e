"""A ROS graph of its own for a replay: a claimed domain id and localhost-only discovery (ROS, no rclpy import).

A replay must not exchange messages with another replay or with a live graph on the host or the network. By
default its graph gets a DDS domain of its own, localhost-only: :func:`claim_domain` takes the first id in
``1..101`` (above 101 the DDS ports may collide with Linux's ephemeral ports) that

- no other replay or train_calib test run holds (an exclusive ``flock`` on ``<tmp>/train_calib_ros_domains/<id>.lock``,
  held for the replay's life: the lock goes with the process, even when it is killed),
- is not the caller's own ``ROS_DOMAIN_ID`` (its live graph), and
- has no DDS participant on this host (the first participants' unicast discovery ports, ``7410 + 250 id + 2 k``,
  can be bound: a ``ros2`` tool or a node started by hand in that domain holds one).

:func:`isolated_environment` is what the replay's contexts and node processes run with: ``ROS_DOMAIN_ID`` the
claimed id, ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, and no static peers, discovery server or
``ROS_LOCALHOST_ONLY`` of the caller's. rcl reads these variables when a context is initialised, so
:func:`environment` applies them around ``rclpy.init`` only and restores the caller's environment after.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import socket
import tempfile
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from .errors import TrainCalibError

DOMAIN_IDS = range(1, 102)
MAX_DOMAIN_ID = 232  # the largest ROS domain id (DDS port mapping)
LOCK_DIR_NAME = "train_calib_ros_domains"  # shared with test/conftest.py: tests and replays never share an id
PROBED_PARTICIPANTS = 4  # participant indices whose discovery port is probed per domain


class IsolationError(TrainCalibError):
    """No free ROS domain id for an isolated graph."""


@dataclass
class DomainClaim:
    """A claimed domain id; the lock is held until :meth:`release` (or the process ends)."""

    domain_id: int
    _lock: IO[str] | None = field(default=None, repr=False)

    def release(self) -> None:
        if self._lock is not None:
            self._lock.close()
            self._lock = None

    def __enter__(self) -> DomainClaim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def lock_dir() -> Path:
    return Path(tempfile.gettempdir()) / LOCK_DIR_NAME


def discovery_ports(domain_id: int) -> list[int]:
    """The unicast discovery (metatraffic) ports of a domain's first participants on a host (RTPS port mapping:
    PB 7400, DG 250, PG 2, d1 10)."""
    return [7400 + 250 * domain_id + 10 + 2 * k for k in range(PROBED_PARTICIPANTS)]


def domain_in_use_on_host(domain_id: int) -> bool:
    """True when a DDS participant of `domain_id` runs on this host (one of its discovery ports is bound)."""
    for port in discovery_ports(domain_id):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            try:
                probe.bind(("0.0.0.0", port))
            except OSError:
                return True
    return False


def claim_domain(environ: Mapping[str, str] | None = None) -> DomainClaim:
    """The first free domain id (see the module docstring), locked for the caller; IsolationError if none."""
    environ = os.environ if environ is None else environ
    avoid = {0}
    with contextlib.suppress(ValueError):
        avoid.add(int(environ.get("ROS_DOMAIN_ID", "0") or 0))
    directory = lock_dir()
    try:
        directory.mkdir(exist_ok=True)
    except OSError as exc:
        raise IsolationError(f"{directory}: cannot create the domain lock directory: {exc.strerror or exc}") from None
    start = os.getpid() % len(DOMAIN_IDS)
    for k in range(len(DOMAIN_IDS)):
        domain = DOMAIN_IDS[(start + k) % len(DOMAIN_IDS)]
        if domain in avoid:
            continue
        try:
            handle = open(directory / f"{domain}.lock", "a")  # noqa: SIM115 - held by the claim
        except OSError:
            continue
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        if domain_in_use_on_host(domain):
            handle.close()
            continue
        return DomainClaim(domain, handle)
    raise IsolationError(
        f"no free ROS domain id in {DOMAIN_IDS.start}..{DOMAIN_IDS.stop - 1} for an isolated replay "
        f"(locks in {directory}); pass --domain-id N or --live"
    )


def isolated_environment(domain_id: int) -> dict[str, str | None]:
    """Environment changes for a graph of its own in `domain_id` (None: the variable is removed)."""
    return {
        "ROS_DOMAIN_ID": str(domain_id),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "ROS_STATIC_PEERS": None,
        "ROS_LOCALHOST_ONLY": None,
        "ROS_DISCOVERY_SERVER": None,
    }


def applied(changes: Mapping[str, str | None], base: Mapping[str, str] | None = None) -> dict[str, str]:
    """`base` (default os.environ) with `changes` applied: the environment of a node process."""
    env = dict(os.environ if base is None else base)
    for key, value in changes.items():
        if value is None:
            env.pop(key, None)
        else:
            env[key] = value
    return env


@contextlib.contextmanager
def environment(changes: Mapping[str, str | None]) -> Iterator[None]:
    """os.environ with `changes` applied for the duration (around ``rclpy.init``), then restored."""
    saved = {key: os.environ.get(key) for key in changes}
    try:
        for key, value in changes.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


__all__ = [
    "MAX_DOMAIN_ID",
    "DomainClaim",
    "IsolationError",
    "applied",
    "claim_domain",
    "discovery_ports",
    "domain_in_use_on_host",
    "environment",
    "isolated_environment",
]
