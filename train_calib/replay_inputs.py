"""A replay's inputs and options (no ROS): ``ReplayOptions`` and ``ReplayResult``, the bag's input messages
(``load_inputs``), the nodes to start (``graph_nodes``), the track and train (``resolve_inputs``), the params files
(``sets_parameter``) and the output directory (``prepare_out``).

window_calib_node runs when the bag has ``/train/traction_power`` (``window=None``, the default), or as
``window`` True/False forces.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from . import paths
from .bagio import INPUT_TOPICS, POWER_TOPIC, BagDamage, bag_topics, iter_bag, typestore
from .errors import BagError
from .nodes.config import GRAPH_NODES, WINDOW_NODE
from .record import METADATA_FILE, OUTPUT_FILE
from .track import load_track
from .train import load_train
from .yamlcheck import load_yaml_mapping

DEFAULT_CLOCK_HZ = 20.0
MAX_CLOCK_NS = (2**31 - 1) * 1_000_000_000 + 999_999_999  # the latest time /clock carries (int32 seconds, 2038)


def sets_parameter(params_files: Sequence[Path], name: str) -> bool:
    """Whether any of the ROS params files sets ``name`` (under any node's ``ros__parameters``)."""

    def found(node: Any) -> bool:
        if isinstance(node, dict):
            params = node.get("ros__parameters")
            if isinstance(params, dict) and name in params:
                return True
            return any(found(v) for v in node.values())
        return False

    return any(found(load_yaml_mapping(f, "params file")) for f in params_files)


@dataclass
class ReplayOptions:
    bag: Path
    track: str  # path or bundled name
    train: str  # path or bundled name
    out: Path
    rate: float = 0.0  # 0: as fast as the graph keeps up
    processes: bool = False
    params_files: tuple[Path, ...] = ()
    nodes: tuple[str, ...] = GRAPH_NODES
    window: bool | None = None  # window_calib_node: None = when the bag has /train/traction_power; True/False force
    clock_hz: float = DEFAULT_CLOCK_HZ
    executor: str = "events"  # in one process: events or single
    wait_for_subscribers: int = 0  # extra subscribers (e.g. a DAS) every output must have before starting
    max_lag: int = 200
    max_held: int = 10  # samples a node downstream of the head may hold while the graph has messages in flight
    overwrite: bool = False
    log: Callable[[str], None] | None = None
    on_input: Callable[[str, int, int], None] | None = None  # (topic, stamp... log time ns, wall ns) hook
    extra_nodes: Callable[[Any], Sequence[Any]] | None = None  # context -> nodes to spin with the graph
    until_s: float | None = None  # replay only the first `until_s` seconds of bag time
    graph_factory: Callable[..., Any] | None = None  # (context, names, overrides, params_files) -> Graph (benchmarks)
    domain_id: int | None = None  # None: a domain of its own, localhost only (isolated); N: the graph in domain N
    live: bool = False  # also publish the inputs, /clock and the outputs into the caller's environment
    quiet_nodes: bool = False  # the nodes log warnings and errors only (no [INFO] lines; --quiet)


@dataclass
class ReplayResult:
    out: Path
    output_bag: Path
    sent: dict[str, int]
    recorded: dict[str, int]
    wall_s: float
    bag_duration_s: float
    mode: str
    executor: str
    nodes: tuple[str, ...] = ()
    interrupted: bool = False
    max_behind_s: float = 0.0  # finite rate: the furthest a message was published after its due time
    stream_s: float = 0.0  # wall time from the first input published to the graph having handled the last
    stream_cpu_s: float = 0.0  # CPU time of this process over the same span (all threads)
    drops: dict[str, dict[str, dict[str, int]]] = field(default_factory=dict)
    input_error: str | None = None  # the input bag was damaged: replayed what could be read (exit status 3)
    undecodable: dict[str, int] = field(default_factory=dict)
    signal: int | None = None  # the signal that interrupted the replay (SIGINT 2, SIGTERM 15)
    domain_id: int | None = None  # the ROS domain the graph ran in
    isolated: bool = True  # the graph ran in a domain of its own, localhost only
    live: bool = False  # inputs, /clock and outputs were also published into the caller's environment


@dataclass
class BagInputs:
    topics: dict[str, str]  # input topic -> type present in the bag
    messages: list[tuple[str, int, bytes]]  # (topic, log time ns, CDR) in log-time order
    error: str | None = None  # the bag is damaged: what was wrong (messages hold what could be read)
    undecodable: dict[str, int] = field(default_factory=dict)  # topic -> messages left out (not valid CDR)

    @property
    def duration_s(self) -> float:
        return (self.messages[-1][1] - self.messages[0][1]) * 1e-9 if self.messages else 0.0


def load_inputs(bag: str | Path) -> BagInputs:
    """The bag's input messages; BagError (one line) for an unreadable bag or one without inputs."""
    topics = bag_topics(bag)
    present = {}
    for topic, expected in INPUT_TOPICS.items():
        if topic in topics:
            if topics[topic] != expected:
                raise BagError(f"{bag}: topic {topic} has type {topics[topic]}, expected {expected}")
            present[topic] = expected
    if "/train/speed" not in present or "/gnss/fix" not in present:
        missing = [t for t in ("/gnss/fix", "/train/speed") if t not in present]
        raise BagError(f"{bag}: no {' and no '.join(missing)} topic (found: {', '.join(sorted(topics)) or 'none'})")
    store = typestore()
    messages: list[tuple[str, int, bytes]] = []
    undecodable: Counter[str] = Counter()
    absurd = 0  # messages with a log time /clock cannot carry
    error = None
    try:
        for m in iter_bag(bag, present):
            if not 0 <= m.log_time_ns <= MAX_CLOCK_NS:  # /clock could not carry it (int32 seconds): a damaged bag
                undecodable[m.topic] += 1
                absurd += 1
                continue
            try:  # a message the nodes could not deserialize is left out and counted (a damaged bag)
                store.deserialize_cdr(m.data, present[m.topic])
            except Exception:
                undecodable[m.topic] += 1
                continue
            messages.append((m.topic, m.log_time_ns, m.data))
    except BagDamage as exc:
        error = str(exc)
    if not messages:
        raise BagError(error or f"{bag}: the input topics hold no messages")
    if undecodable and error is None:
        invalid = sum(undecodable.values()) - absurd
        parts = [f"{invalid} input messages are not valid CDR"] if invalid else []
        parts += [f"{absurd} input messages have a log time /clock cannot carry (after 2038)"] if absurd else []
        error = f"{bag}: {' and '.join(parts)} and were left out"
    return BagInputs(present, messages, error, dict(undecodable))


def graph_nodes(nodes: Sequence[str], window: bool | None, input_topics: Iterable[str]) -> tuple[str, ...]:
    """The nodes to start: `nodes`, plus window_calib_node when `window` is True, or None and the bag has traction
    power; without it when `window` is False."""
    wanted = (POWER_TOPIC in set(input_topics)) if window is None else window
    base = tuple(n for n in nodes if n != WINDOW_NODE)
    return (*base, WINDOW_NODE) if wanted else base


def resolve_inputs(track: str, train: str) -> tuple[Path, Path]:
    """Paths of the track and train files (a path or a bundled name); loads them to fail early in one line."""
    track_path, train_path = paths.track_file(track), paths.train_file(train)
    load_track(track_path)
    load_train(train_path)
    return track_path, train_path


def prepare_out(out: Path, overwrite: bool) -> None:
    """Create the output directory; refuse (or with overwrite, remove) the files a replay writes."""
    products = [OUTPUT_FILE, METADATA_FILE, "summary.json", "report.png"]
    existing = [out / p for p in products if (out / p).exists()]
    if existing and not overwrite:
        raise BagError(f"{existing[0]}: already exists (use --overwrite or another --out)")
    for path in existing:
        path.unlink()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BagError(f"{out}: cannot create the output directory: {exc.strerror or exc}") from None
