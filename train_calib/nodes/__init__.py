"""The ROS 2 nodes (rclpy): thin adapters from messages to the core and back (docs/nodes.md).

``config`` (no ROS) says which parameters each node declares; ``common`` holds the conventions every
node follows (parameters, QoS, diagnostics, end of input, ``main``) and the base class ``TrainCalibNode``, with
its parts in ``ros_params``, ``qos``, ``diagnostics`` and ``runner``; ``convert`` maps core records to
messages; one module per node, each with ``main()``.
"""
