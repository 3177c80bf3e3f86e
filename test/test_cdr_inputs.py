"""The direct CDR decoding of the input topics (cdr_inputs) equals bagio.iter_bag + rosbags + ingest converters,
event for event and bit for bit, and hands every bag that is not plain and well formed to the generic path."""

from __future__ import annotations

import random
import shutil
from pathlib import Path

import numpy as np
import pytest
from build_context import kernel_skip_reason
from repo_paths import REPO

from train_calib import bagio, cdr_inputs
from train_calib.cdr_inputs import read_input_events
from train_calib.ingest import fix_from_msg, power_from_msg, speed_from_msg
from train_calib.pipeline import bag_messages

BAGS = REPO / "bags"
CONVERT = {bagio.GNSS_TOPIC: fix_from_msg, bagio.SPEED_TOPIC: speed_from_msg, bagio.POWER_TOPIC: power_from_msg}


@pytest.fixture(autouse=True, params=["kernel", "python"])
def decoder(request, monkeypatch):
    """Every test with the chunks' messages decoded in C (the ingest's kernel) and in Python."""
    if request.param == "python":
        monkeypatch.setattr(cdr_inputs, "_kernel", None)
    elif cdr_inputs._kernel is None:
        reason = kernel_skip_reason()
        if reason:
            pytest.skip(reason)
        pytest.fail("train_calib/ingest/_kernel.c is not built (setup.py build_ext --inplace, or make setup)")
    return request.param


def _generic(bag: Path) -> list:
    return [CONVERT[topic](msg) for topic, msg in bag_messages(bag)]


def _exact(events: list) -> list:
    """Type and every field, floats by their bits (NaN equal to NaN)."""
    return [(type(e).__name__, *(x.hex() if isinstance(x, float) else x for x in vars(e).values())) for e in events]


@pytest.mark.parametrize("name", ["intercity_32km_10s_00", "tunnel_line_37km_1s_00"])
def test_bundled_bags_decode_as_the_generic_path(name):
    """A 10 s bag (fix and speed) and a 1 Hz bag with traction power and GNSS outages (no-fix messages)."""
    bag = BAGS / name
    fast = read_input_events(bag)
    assert fast is not None
    ref = _generic(bag)
    assert len(fast) == len(ref) > 200
    assert _exact(fast) == _exact(ref)


def _copy_messages(src: Path, dst: Path, *, chunk_size: int, shuffle: bool, big_endian_at: int = -1) -> Path:
    """The messages of ``src`` rewritten with the mcap writer in small chunks (their times overlapping when
    ``shuffle``: neighbours swapped), optionally one message re-serialised big-endian."""
    from mcap.writer import Writer

    store = bagio.typestore()
    messages = list(bagio.iter_bag(src))
    if shuffle:
        rng = random.Random(3)
        for i in range(0, len(messages) - 1, 2):
            if rng.random() < 0.5:
                messages[i], messages[i + 1] = messages[i + 1], messages[i]
    dst.parent.mkdir(parents=True, exist_ok=True)
    with open(dst, "wb") as f:
        writer = Writer(f, chunk_size=chunk_size)
        writer.start(profile="ros2", library="test")
        channels: dict[str, int] = {}
        for k, m in enumerate(messages):
            if m.topic not in channels:
                schema = writer.register_schema(m.msgtype, "ros2msg", b"")
                channels[m.topic] = writer.register_channel(m.topic, "cdr", schema)
            data = m.data
            if k == big_endian_at:
                data = store.serialize_cdr(m.decode(), m.msgtype, little_endian=False)
            writer.add_message(channels[m.topic], m.log_time_ns, data, m.log_time_ns)
        writer.finish()
    return dst


def test_several_chunks_with_overlapping_times_merge_as_iter_bag(tmp_path):
    bag = _copy_messages(BAGS / "tunnel_line_37km_1s_00", tmp_path / "run.mcap", chunk_size=4096, shuffle=True)
    from mcap.reader import make_reader

    with open(bag, "rb") as f:
        assert len(make_reader(f).get_summary().chunk_indexes) > 50
    fast = read_input_events(bag)
    assert fast is not None
    assert _exact(fast) == _exact(_generic(bag))


def test_a_big_endian_message_goes_to_the_generic_path(tmp_path):
    bag = _copy_messages(BAGS / "intercity_32km_10s_00", tmp_path / "be.mcap", chunk_size=1 << 20, shuffle=False,
                         big_endian_at=7)  # fmt: skip
    assert read_input_events(bag) is None
    ref = _generic(bag)  # rosbags reads big-endian CDR
    assert _exact(ref) == _exact(read_input_events(BAGS / "intercity_32km_10s_00"))


def test_damaged_bags_go_to_the_generic_path(tmp_path):
    src = BAGS / "intercity_32km_10s_00"
    truncated = tmp_path / "truncated.mcap"
    truncated.write_bytes(next(src.glob("*.mcap")).read_bytes()[:-300])  # no summary: salvaged by iter_bag
    assert read_input_events(truncated) is None
    flipped = _copy_messages(src, tmp_path / "flipped.mcap", chunk_size=1 << 20, shuffle=False)  # with chunk CRCs
    data = bytearray(flipped.read_bytes())
    data[len(data) // 3] ^= 0x01  # inside the chunk: its CRC no longer matches
    flipped.write_bytes(bytes(data))
    assert read_input_events(flipped) is None
    with pytest.raises(bagio.BagDamage):
        _generic(flipped)


def test_a_changed_value_without_crc_is_read_as_the_generic_path(tmp_path):
    """rosbags writes chunks without a CRC: a changed byte is then data, read alike by both paths."""
    bag = tmp_path / "changed"
    shutil.copytree(BAGS / "intercity_32km_10s_00", bag)
    target = next(bag.glob("*.mcap"))
    data = bytearray(target.read_bytes())
    data[len(data) // 3] ^= 0x01
    target.write_bytes(bytes(data))
    fast = read_input_events(bag)
    assert fast is not None
    assert _exact(fast) == _exact(_generic(bag))


def test_a_missing_bag_raises_as_the_generic_path(tmp_path):
    with pytest.raises(bagio.BagError, match="no such bag"):
        read_input_events(tmp_path / "nothing")


def test_unknown_covariance_and_no_fix_are_decoded(tmp_path):
    """A no-fix message (status -1, covariance type unknown: variance NaN) and a fix with its covariance."""
    bag = tmp_path / "run"
    t = np.array([1, 2, 3]) * 1_000_000_000 + 1_700_000_000_000_000_000
    bagio.write_input_bag(bag, gnss_t_ns=t, lat=[52.0, 52.001, 52.002], lon=[5.0, 5.0, 5.0], altitude=[0.0] * 3,
                          gnss_sigma_m=3.0, speed_t_ns=t, speed_ms=[1.0, 2.0, 3.0], gnss_ok=[True, False, True],
                          power=(t, [1e5, 0.0, 0.0], [0.0, 0.0, 2e4]))  # fmt: skip
    fast = read_input_events(bag)
    assert fast is not None
    assert _exact(fast) == _exact(_generic(bag))
    assert fast[0].horizontal_variance == 9.0 and fast[3].status == -1 and np.isnan(fast[3].horizontal_variance)


def _outcome(decode, records: bytes, kinds: dict) -> object:
    try:
        return _exact([event for _, event in decode(records, kinds)]), [t for t, _ in decode(records, kinds)]
    except cdr_inputs._Unusable:
        return "unusable"


def test_the_kernel_decodes_a_chunk_as_the_python_even_with_damaged_bytes(decoder):
    """cdr_inputs._record_events against the kernel's chunk_events on the records of a bundled bag's chunks, as
    they are and with random bytes changed (the same events, or both unusable)."""
    if decoder == "python":
        pytest.skip("compares the kernel with the Python")
    from train_calib.bagio import _summary, mcap_files

    def kernel(records: bytes, kinds: dict) -> list:
        items = cdr_inputs._kernel.chunk_events(
            records, kinds, cdr_inputs._CLASSES, float("nan"), cdr_inputs._check_channel, cdr_inputs._check_schema
        )
        if items is None:
            raise cdr_inputs._Unusable
        return items

    def python(records: bytes, kinds: dict) -> list:
        return cdr_inputs._record_events(records, kinds, cdr_inputs._Decoder())

    rng = random.Random(11)
    outcomes = set()
    for name in ("intercity_32km_10s_00", "tunnel_line_37km_1s_00"):
        file = mcap_files(BAGS / name)[0]
        data = file.read_bytes()
        with open(file, "rb") as stream:
            summary = _summary(stream)
        kinds = {c.id: cdr_inputs._KIND[c.topic] for c in summary.channels.values() if c.topic in cdr_inputs._KIND}
        for chunk in summary.chunk_indexes[:3]:
            records = cdr_inputs._chunk_records(data, chunk.chunk_start_offset)
            assert _outcome(kernel, records, kinds) == _outcome(python, records, kinds) != "unusable"
            for _ in range(300):
                damaged = bytearray(records)
                for _ in range(rng.choice([1, 1, 2, 8])):
                    damaged[rng.randrange(len(damaged))] = rng.randrange(256)
                got = _outcome(kernel, bytes(damaged), kinds)
                assert got == _outcome(python, bytes(damaged), kinds)
                outcomes.add(got == "unusable")
            cut = records[: rng.randrange(len(records))]
            assert _outcome(kernel, cut, kinds) == _outcome(python, cut, kinds)
    assert outcomes == {True, False}  # damage that is read as data and damage that is not
