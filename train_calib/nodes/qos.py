"""The QoS profiles of train_calib: on-board sensor inputs (best effort), outputs and the links between the nodes
(reliable), /diagnostics and the replay's control topics."""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy


def _keep_last(depth: int, reliability: ReliabilityPolicy, durability: DurabilityPolicy) -> QoSProfile:
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=reliability, durability=durability)


def sensor_qos(depth: int) -> QoSProfile:
    """Inputs from the on-board stack: best effort (hears reliable and best-effort publishers), volatile."""
    return _keep_last(depth, ReliabilityPolicy.BEST_EFFORT, DurabilityPolicy.VOLATILE)


def reliable_qos(depth: int, durability: DurabilityPolicy = DurabilityPolicy.VOLATILE) -> QoSProfile:
    """Outputs and the subscriptions between train_calib nodes: reliable, keep last `depth`, volatile unless said
    (``replay --live`` publishes its outputs transient local)."""
    return _keep_last(depth, ReliabilityPolicy.RELIABLE, durability)


DIAGNOSTICS_QOS = reliable_qos(100)
CONTROL_QOS = reliable_qos(100)
