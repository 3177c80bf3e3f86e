"""Seeded corruption of a bundled bag, and a runner that replays the corrupted bags in one process.

Kinds of damage (``corrupt(kind, source, dest, seed)``, each reproducible from its seed):

- ``flip``: 1-24 random bytes of the MCAP file flipped (anywhere after the magic);
- ``truncate``: the file cut at a random point;
- ``length``: the length field of a random record overwritten with a huge value (2^40..2^64-1);
- ``stamps``: 1-10 input messages re-written with a header stamp before 1970 (negative seconds) or at the int32 end;
- ``logtime``: 1-5 input messages re-written with an absurd log time (after 2038, up to 2^64-1).

``python bagfuzz.py CASES.json OUT_DIR`` replays every case (``{"bag", "track", "train"}``) with
``train_calib.cli.main`` in this process and prints one JSON line per case: the exit status, or the exception that
escaped; then a last line with the process's peak RSS (MB).
"""

from __future__ import annotations

import json
import random
import resource
import struct
import sys
import traceback
from pathlib import Path

KINDS = ("flip", "truncate", "length", "stamps", "logtime")
MAGIC_LEN = 8  # b"\x89MCAP0\r\n"


def _records(data: bytes) -> list[int]:
    """Offsets of the top-level MCAP records' length fields (opcode at offset, length after it)."""
    out, pos = [], MAGIC_LEN
    while pos + 9 <= len(data) - MAGIC_LEN:
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        out.append(pos + 1)
        pos += 9 + length
    return out


def corrupt(kind: str, source: Path, dest: Path, seed: int) -> Path:
    """`dest` (a .mcap file, or a bag directory for the stamp kinds): `source` with one kind of damage."""
    rng = random.Random(seed)
    if kind in ("stamps", "logtime"):
        return _rewrite(kind, source, dest, rng)
    data = bytearray(source.read_bytes())
    if kind == "flip":
        for _ in range(rng.randint(1, 24)):
            data[rng.randrange(MAGIC_LEN, len(data))] ^= 1 << rng.randrange(8)
    elif kind == "truncate":
        del data[rng.randrange(MAGIC_LEN, len(data)) :]
    elif kind == "length":
        offset = rng.choice(_records(bytes(data)))
        struct.pack_into("<Q", data, offset, rng.randrange(2**40, 2**64))
    else:
        raise ValueError(kind)
    dest.write_bytes(bytes(data))
    return dest


def _rewrite(kind: str, source: Path, dest: Path, rng: random.Random) -> Path:
    from train_calib.bagio import INPUT_TOPICS, BagWriter, bag_topics, iter_bag, typestore

    store = typestore()
    topics = {t: ty for t, ty in bag_topics(source).items() if t in INPUT_TOPICS}
    messages = list(iter_bag(source, topics))
    chosen = set(rng.sample(range(len(messages)), rng.randint(1, 10 if kind == "stamps" else 5)))
    with BagWriter(dest, topics) as writer:
        for k, m in enumerate(messages):
            if k not in chosen:
                writer.write_raw(m.topic, m.data, m.log_time_ns)
            elif kind == "stamps":
                msg = store.deserialize_cdr(m.data, topics[m.topic])
                msg.header.stamp.sec = rng.choice([-1, -(2**31), rng.randrange(-(2**31), 0), 2**31 - 1])
                writer.write(m.topic, msg, m.log_time_ns)
            else:
                writer.write_raw(m.topic, m.data, rng.choice([2**64 - 1, 3 * 10**18, rng.randrange(2**61, 2**64)]))
    return dest


def run_cases(cases: list[dict], out_dir: Path) -> None:
    from train_calib import cli

    for k, case in enumerate(cases):
        argv = ["replay", case["bag"], "--track", case["track"], "--train", case["train"]]
        argv += ["--out", str(out_dir / f"out{k}"), "--no-report", "--quiet"]
        try:
            result = {"status": cli.main(argv)}
        except SystemExit as exc:
            result = {"status": exc.code}
        except BaseException as exc:  # what a user would see as a traceback
            result = {"status": None, "exception": "".join(traceback.format_exception_only(exc)).strip()}
        print(json.dumps({"case": k, **result}), flush=True)
    print(json.dumps({"max_rss_mb": peak_rss_mb()}), flush=True)


def peak_rss_mb() -> float:
    """This process's peak resident set size (MB): VmHWM, which starts over at exec. getrusage's ru_maxrss does
    not: a process started by fork and exec keeps the forking process's peak (a pytest-xdist worker of 400 MB made
    this runner's 157 MB read as 402 MB); it is the fallback where /proc is not there."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


if __name__ == "__main__":
    run_cases(json.loads(Path(sys.argv[1]).read_text()), Path(sys.argv[2]))
