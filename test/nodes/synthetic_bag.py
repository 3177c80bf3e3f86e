"""A small synthetic input bag on test/data/small_track.yaml: two runs with a stop, bad samples, power.

Kinematic profile (not a physics simulation): stand, accelerate at 0.5 m/s^2 to 20 m/s, cruise, brake to
a stop, stand 60 s, run again. Fixes and speed at 1 Hz (GNSS stamped 0.2 s later than its epoch is
delivered, so pairing waits), power at 1 Hz, and a few bad samples of every kind.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from train_calib import bagio
from train_calib.track import load_track

NS = 1_000_000_000
T0 = 1_700_000_000 * NS
DATA = Path(__file__).resolve().parent.parent / "data"


def _profile(t, s0, wait, v_max=20.0, a=0.5, cruise=40.0):
    ta = np.clip(t - wait, 0.0, v_max / a)
    s = s0 + 0.5 * a * ta**2
    v = a * ta
    t1 = wait + v_max / a
    tc = np.clip(t - t1, 0.0, cruise)
    s = s + v_max * tc
    t2 = t1 + cruise
    tb = np.clip(t - t2, 0.0, v_max / a)
    s = s + v_max * tb - 0.5 * a * tb**2
    v = np.where(t > t1, v_max - a * tb, v)
    return s, np.maximum(v, 0.0), t2 + v_max / a


def write_bag(path: Path, *, power: bool = True, bad: bool = True) -> Path:
    track = load_track(DATA / "small_track.yaml")
    NavSatFix = bagio.msg_class("sensor_msgs/msg/NavSatFix")
    Status = bagio.msg_class("sensor_msgs/msg/NavSatStatus")
    Twist = bagio.msg_class("geometry_msgs/msg/TwistStamped")
    TwistMsg = bagio.msg_class("geometry_msgs/msg/Twist")
    Vector3 = bagio.msg_class("geometry_msgs/msg/Vector3")
    Power = bagio.msg_class("train_calib_msgs/msg/TractionPower")
    _, _, end1 = _profile(np.array(0.0), 200.0, 20.0)
    s_end1 = float(_profile(np.array(end1), 200.0, 20.0)[0])
    times = np.arange(0.0, 2 * end1 + 60.0, 1.0)
    events = []
    for t in times:
        if t <= end1 + 60.0:
            s, v, _ = _profile(np.array(t), 200.0, 20.0)
        else:
            s, v, _ = _profile(np.array(t - end1 - 60.0), s_end1, 0.0)
        s, v = float(min(s, 2950.0)), float(v)
        stamp = T0 + int(t * NS)
        lat, lon = track.latlon_at(s)
        status = 0
        if bad and t == 30:
            lat = float("nan")
        if bad and t == 31:
            status = -1
        fix = NavSatFix(
            header=bagio.make_header(stamp, "gnss"),
            status=Status(status=status, service=1),
            latitude=float(lat),
            longitude=float(lon),
            altitude=0.0,
            position_covariance=np.zeros(9),
            position_covariance_type=0,
        )
        speed_v = v
        if bad and t == 50:
            speed_v = -3.0
        if bad and t == 51:
            speed_v = float("nan")
        speed = Twist(
            header=bagio.make_header(stamp, "odom"),
            twist=TwistMsg(linear=Vector3(x=speed_v, y=0.0, z=0.0), angular=Vector3(x=0.0, y=0.0, z=0.0)),
        )
        events.append((stamp + NS // 20, bagio.SPEED_TOPIC, speed))
        events.append((stamp + NS // 5, bagio.GNSS_TOPIC, fix))  # GNSS delivered 0.2 s after its epoch
        if power:
            p = 2.0e6 * (v > 0) if t < end1 else 0.0
            events.append(
                (
                    stamp + NS // 10,
                    bagio.POWER_TOPIC,
                    Power(header=bagio.make_header(stamp), power_consumed=p, power_regenerated=0.0),
                )
            )
        if bad and t == 70:
            stale = Twist(
                header=bagio.make_header(stamp - 60 * NS, "odom"),
                twist=TwistMsg(linear=Vector3(x=1.0, y=0.0, z=0.0), angular=Vector3(x=0.0, y=0.0, z=0.0)),
            )
            events.append((stamp + NS // 2, bagio.SPEED_TOPIC, stale))
    events.sort(key=lambda e: e[0])
    topics = {t: ty for t, ty in bagio.INPUT_TOPICS.items() if power or t != bagio.POWER_TOPIC}
    with bagio.BagWriter(path, topics) as writer:
        for t, topic, msg in events:
            writer.write(topic, msg, t)
    return path
