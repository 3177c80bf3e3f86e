"""Compare messages read back from a bag with the core records the offline pipeline produced."""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

import numpy as np

from train_calib import bagio
from train_calib.pipeline import PipelineOutput

DATA_TOPICS = {
    "/train_calib/measurement": "measurements",
    "/train_calib/resistance": "estimates",
    "/train_calib/regime": "regimes",
    "/train_calib/features": "features",
    "/train_calib/window_resistance": "windows",
}


def read_outputs(bag: Path) -> dict[str, list]:
    """Decoded messages per output topic, in file (publication) order."""
    out = defaultdict(list)
    for m in bagio.iter_bag(bag):
        out[m.topic].append(m.decode())
    return out


def _same(a, b) -> bool:
    a = np.asarray(a, dtype=float) if not isinstance(a, (bool, np.bool_)) else a
    b = np.asarray(b, dtype=float) if not isinstance(b, (bool, np.bool_)) else b
    if isinstance(a, (bool, np.bool_)) or isinstance(b, (bool, np.bool_)):
        return bool(a) == bool(b)
    return a.shape == b.shape and bool(np.all((a == b) | (np.isnan(a) & np.isnan(b))))


def message_differences(msg, record) -> list[str]:
    """Fields of a decoded message that differ from the record (exact, NaN equal to NaN)."""
    diffs = []
    stamp = bagio.stamp_ns(msg.header)
    if stamp != record.stamp_ns:
        diffs.append(f"stamp {stamp} != {record.stamp_ns}")
    for name in msg.__dataclass_fields__:
        if name in ("header", "__msgtype__") or name.isupper():
            continue
        value = getattr(msg, name)
        expected = getattr(record, name)
        if name == "covariance":
            expected = np.asarray(expected).reshape(-1)
        if not _same(value, expected):
            diffs.append(f"{name}: {value!r} != {expected!r}")
    return diffs


def compare(outputs: dict[str, list], reference: PipelineOutput) -> list[str]:
    """Every difference between the graph's messages and the pipeline's records, topic by topic."""
    problems = []
    for topic, attr in DATA_TOPICS.items():
        got, want = outputs.get(topic, []), getattr(reference, attr)
        if len(got) != len(want):
            problems.append(f"{topic}: {len(got)} messages, the pipeline made {len(want)}")
        for i, (msg, rec) in enumerate(zip(got, want)):
            diffs = message_differences(msg, rec)
            if diffs:
                problems.append(f"{topic}[{i}]: " + "; ".join(diffs[:4]))
                break
    return problems


def finite(x) -> bool:
    return isinstance(x, float) and math.isfinite(x)
