"""train_calib: real-time calibration of the train motion model.

The numerical core (track, train, physics, simulator, estimators, calibrators) imports no ROS;
``train_calib.nodes`` holds the rclpy adapters and ``train_calib.cli`` the ``train-calib`` command.
"""

__version__ = "0.1.0"
