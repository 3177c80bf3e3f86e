"""The QoS profiles of train_calib: on-board sensor inputs (best effort), outputs and the links between the nodes
(reliable), /diagnostics and the replay's control topics."""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy


def sensor_qos(depth: int) -> QoSProfile:
    """Inputs from the on-board stack: best effort (hears reliable and best-effort publishers), volatile."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.VOLATILE,
    )


def reliable_qos(depth: int) -> QoSProfile:
    """Outputs and the subscriptions between train_calib nodes: reliable, volatile, keep last `depth`."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )


DIAGNOSTICS_QOS = reliable_qos(100)
CONTROL_QOS = reliable_qos(100)
