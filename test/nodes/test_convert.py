"""The message writers of nodes/convert.py and common.key_value (filled slot by slot, without the generated
constructors) give the same messages as the generated constructors and setters: same fields, same types, same
serialized content."""

from __future__ import annotations

import math

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import KeyValue
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Header
from train_calib_msgs.msg import DrivingRegime, ResistanceEstimate, TrackMeasurement

from train_calib import bagio
from train_calib.estimation.records import (
    EFFORT_COASTING,
    EFFORT_COMPUTED,
    EFFORT_POWER,
    EFFORT_POWER_COASTING,
    EstimateSample,
)
from train_calib.measurement import Measurement
from train_calib.nodes.common import key_value
from train_calib.nodes.convert import (
    RegimeInput,
    estimate_to_cdr,
    estimate_to_msg,
    measurement_from_msg,
    measurement_to_cdr,
    measurement_to_msg,
    phase_from_msg,
    regime_input_from_msg,
    regime_to_cdr,
    regime_to_msg,
    time_msg,
)

NS = 1_000_000_000


def _fields(msg):
    """Field name -> (type name, value) recursively; floats by their bits (NaN equal to NaN)."""
    if hasattr(msg, "get_fields_and_field_types"):
        return {f: _fields(getattr(msg, f)) for f in msg.get_fields_and_field_types()}
    if isinstance(msg, np.ndarray):
        return (msg.dtype.str, msg.shape, msg.tobytes())
    if isinstance(msg, float):
        return ("float", float(msg).hex())
    return (type(msg).__name__, msg)


def _same(fast, reference):
    assert type(fast) is type(reference)
    assert _fields(fast) == _fields(reference)
    assert fast == reference or any(isinstance(v, float) and math.isnan(v) for v in _values(reference))
    # the middleware sees the same content (compared after a round trip: CDR padding bytes are not initialised)
    back = deserialize_message(serialize_message(fast), type(fast))
    assert _fields(back) == _fields(deserialize_message(serialize_message(reference), type(reference)))
    # a message built fast behaves as any other (its field setters work)
    assert fast._check_fields == reference._check_fields


def _plain(x):
    """Field name -> value of an rclpy or a rosbags message (floats by their bits, arrays as lists)."""
    if hasattr(x, "__dataclass_fields__") or hasattr(x, "get_fields_and_field_types"):
        names = x.get_fields_and_field_types() if hasattr(x, "get_fields_and_field_types") else x.__dataclass_fields__
        return {f: _plain(getattr(x, f)) for f in names if f != "__msgtype__" and not f.isupper()}  # no constants
    if isinstance(x, np.ndarray):
        return [_plain(v) for v in x.tolist()]
    if isinstance(x, float):
        return float(x).hex()
    return int(x) if isinstance(x, (bool, np.bool_, int, np.integer)) else x


def _same_cdr(data, msg):
    """Bytes packed by a *_to_cdr writer are the message: same length as rclpy's serialization, read back equal by
    rclpy and by rosbags (an independent CDR reader)."""
    assert isinstance(data, bytes) and len(data) == len(serialize_message(msg))
    assert _fields(deserialize_message(data, type(msg))) == _fields(msg)
    typename = f"train_calib_msgs/msg/{type(msg).__name__}"
    assert _plain(bagio.typestore().deserialize_cdr(data, typename)) == _plain(msg)


def _values(msg):
    return [getattr(msg, f) for f in msg.get_fields_and_field_types()]


def _header(t_ns, frame_id):
    return Header(stamp=Time(sec=int(t_ns // NS), nanosec=int(t_ns % NS)), frame_id=frame_id)


MEASUREMENTS = [
    Measurement(1_583_132_400_757_735_773, 294.28, 0.0, 0.0),
    Measurement(
        12 * NS + 5,
        np.float64(1.5),
        np.float64(2.5),
        -0.01,
        1.0,
        np.int64(3),
        np.bool_(False),
        16.0,
        0.07,
        0.2,
        math.inf,
        0.5,
        True,
        1.0e6,
        0.0,
    ),
    Measurement(0, math.nan, 1.0, 0.0, power_valid=False),
]


@pytest.mark.parametrize("m", MEASUREMENTS)
def test_measurement_to_msg_is_the_constructed_message(m):
    reference = TrackMeasurement(
        header=_header(m.stamp_ns, "line"), run_id=int(m.run_id), s=float(m.s), v=float(m.v),
        track_force=float(m.track_force), dt=float(m.dt), s_measured=bool(m.s_measured),
        s_variance=float(m.s_variance), v_variance=float(m.v_variance), cross_track=float(m.cross_track),
        speed_limit=float(m.speed_limit), tunnel_fraction=float(m.tunnel_fraction), power_valid=bool(m.power_valid),
        power_consumed=float(m.power_consumed), power_regenerated=float(m.power_regenerated),
        track_force_integral=float(m.track_force_integral),
    )  # fmt: skip
    msg = measurement_to_msg(m, "line")
    _same(msg, reference)
    _same_cdr(measurement_to_cdr(m, "line"), reference)
    _same_cdr(measurement_to_cdr(m, "intercity_32km"), measurement_to_msg(m, "intercity_32km"))
    back = measurement_from_msg(msg)
    assert _fields(measurement_to_msg(back, "line")) == _fields(msg)


def test_track_force_integral_left_at_the_message_default_reads_as_unknown():
    """A publisher that does not fill track_force_integral leaves 0.0: NaN (unknown) unless s is 0, where Gamma is
    0; the value is kept otherwise (the estimators then take the energy form at 10 s, docs/estimator.md)."""
    msg = measurement_to_msg(Measurement(0, 1200.0, 20.0, 0.05, track_force_integral=0.0), "line")
    assert math.isnan(measurement_from_msg(msg).track_force_integral)
    msg = measurement_to_msg(Measurement(0, 0.0, 20.0, 0.05, track_force_integral=0.0), "line")
    assert measurement_from_msg(msg).track_force_integral == 0.0
    msg = measurement_to_msg(Measurement(0, 1200.0, 20.0, 0.05, track_force_integral=-61.25), "line")
    assert measurement_from_msg(msg).track_force_integral == -61.25


def test_estimate_to_msg_is_the_constructed_message():
    cov = np.arange(25, dtype=float).reshape(5, 5) * 1e-3
    e = EstimateSample(7 * NS + 1, 2, 10.0, np.float64(20.0), 0.02, 3e-4, 4e-5, np.asfortranarray(cov), 0.1, -0.2,
                       0.03, 0.001, 1.2, np.bool_(True), np.int64(1), v_measured=np.float64(20.1),
                       effort_source=np.uint8(EFFORT_POWER))  # fmt: skip
    reference = ResistanceEstimate(
        header=_header(e.stamp_ns, "line"), run_id=2, s=10.0, v=20.0, r0=0.02, r1=3e-4, r2=4e-5,
        covariance=cov.reshape(25), effort=0.1, acceleration=-0.2, resistance=0.03, track_force=0.001, nis=1.2,
        effort_known=True, health=1, v_measured=20.1, effort_source=ResistanceEstimate.EFFORT_POWER,
    )  # fmt: skip
    msg = estimate_to_msg(e, "line")
    _same(msg, reference)
    for frame in ("", "a", "ab", "abc", "line", "tunnel_line_37km"):
        _same_cdr(estimate_to_cdr(e, frame), estimate_to_msg(e, frame))
    cov[0, 0] = 99.0
    assert msg.covariance[0] == 0.0


def test_regime_to_msg_and_back():
    sample = RegimeInput(3 * NS + 9, 1, 5.0, 6.0, 0.2, -0.1, True, 0.03, 0.0, 6.1, EFFORT_POWER_COASTING)
    reference = DrivingRegime(header=_header(sample.stamp_ns, "x"), run_id=1, regime=2, s=5.0, v=6.0, effort=0.2,
                              acceleration=-0.1, v_measured=6.1, effort_source=3, phase=2)  # fmt: skip
    msg = regime_to_msg(sample, np.int64(2), "x")  # no phase given: the regime
    _same(msg, reference)
    _same_cdr(regime_to_cdr(sample, np.int64(2), "x"), reference)
    reference.regime = 3  # a coasting sample of a cycle the paper calls cruising
    _same(regime_to_msg(sample, 3, "x", phase=np.int64(2)), reference)
    _same_cdr(regime_to_cdr(sample, 3, "x", phase=2), reference)
    assert phase_from_msg(reference) == 2
    back = regime_input_from_msg(msg)
    assert back == RegimeInput(
        sample.stamp_ns, 1, 5.0, 6.0, 0.2, -0.1, v_measured=6.1, effort_source=EFFORT_POWER_COASTING, frame_id="x"
    )  # no resistance


def test_a_message_recorded_without_the_measured_speed_and_effort_source_reads_as_nan_and_computed():
    class OldRegime:  # a DrivingRegime decoded from a bag recorded before v_measured and effort_source existed
        header = _header(5 * NS, "x")
        run_id, regime, s, v, effort, acceleration = 0, 1, 1.0, 2.0, 0.1, 0.0

    old = regime_input_from_msg(OldRegime())
    assert math.isnan(old.v_measured)
    assert old.effort_source == EFFORT_COMPUTED
    assert phase_from_msg(OldRegime()) == 1  # recorded before the phase field: its regime was the phase


def test_regime_input_from_an_estimate():
    e = EstimateSample(4 * NS, 0, 1.0, 2.0, 0.02, 3e-4, 4e-5, np.eye(5), 0.1, -0.2, 0.03, 0.001, 1.2, True, 0,
                       v_measured=2.1, effort_source=EFFORT_COASTING)  # fmt: skip
    got = regime_input_from_msg(estimate_to_msg(e))
    assert got == RegimeInput(4 * NS, 0, 1.0, 2.0, 0.1, -0.2, True, 0.03, 0.001, 2.1, EFFORT_COASTING)


def test_time_and_key_value():
    _same(time_msg(1_583_132_400_757_735_773), Time(sec=1_583_132_400, nanosec=757_735_773))
    _same(key_value("a key", "a value"), KeyValue(key="a key", value="a value"))


def test_a_message_class_of_another_layout_is_refused_in_one_line():
    from train_calib.nodes.slots import check_layout

    class Other:  # a generator that keeps the fields elsewhere
        __slots__ = ("_check_fields", "_extra", "_key")
        __module__ = "other_msgs.msg"

        @staticmethod
        def get_fields_and_field_types():
            return {"key": "string"}

    check_layout(KeyValue)
    with pytest.raises(ImportError, match=r"^other_msgs.msg.Other: unexpected generated message layout"):
        check_layout(Other)


@pytest.mark.parametrize("frame", ["", "abc", "tunnel_line_37km"])
def test_window_to_cdr_is_the_message(frame):
    from train_calib_msgs.msg import WindowResistance

    from train_calib.nodes.window_calib_node import window_to_cdr, window_to_msg
    from train_calib.window import WindowFit

    fit = WindowFit(9 * NS + 7, np.int64(2), 30.0, 29, 1, 812.5, math.nan, 1.5e3, 4.2, 0.018, 2.9e-4, 3.1e-5,
                    np.int64(3), np.bool_(True), 4.25)  # fmt: skip
    reference = WindowResistance(
        header=_header(fit.stamp_ns, frame), run_id=2, window_length=30.0, sample_count=29, gof_kind=1,
        gof_value=812.5, a=math.nan, b=1.5e3, c=4.2, r0=0.018, r1=2.9e-4, r2=3.1e-5, regime=3, ill_posed=True,
        speed_span=4.25, resistance_speed=math.nan, resistance_at_speed=math.nan,
        resistance_at_speed_std=math.nan, pooled_r0=math.nan, pooled_r1=math.nan, pooled_r2=math.nan,
        pooled_covariance=np.full(9, math.nan), pooled_windows=0,
    )  # fmt: skip
    assert _fields(window_to_msg(fit, frame)) == _fields(reference)
    _same_cdr(window_to_cdr(fit, frame), reference)
