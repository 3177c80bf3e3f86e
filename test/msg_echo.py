"""Subprocess subscriber for the message tests: print the first message received as JSON, exit.

usage: python msg_echo.py TYPE TOPIC   (TYPE like train_calib_msgs/msg/ResistanceEstimate)
"""

import json
import sys

import rclpy
from msgfill import message_class, to_dict
from rclpy.qos import QoSProfile, ReliabilityPolicy


def main() -> int:
    type_name, topic = sys.argv[1], sys.argv[2]
    rclpy.init()
    node = rclpy.create_node("msg_echo")
    received = []
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    node.create_subscription(message_class(type_name), topic, received.append, qos)
    print("READY", flush=True)
    while rclpy.ok() and not received:
        rclpy.spin_once(node, timeout_sec=0.1)
    print(json.dumps(to_dict(received[0])), flush=True)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
