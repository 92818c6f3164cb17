"""tf2_msgs/TFMessage for an environment with the ROS 2 PyPI wheels, where tf2_msgs is not on PyPI.

The message sources ship with the package (``source/``); :mod:`.build` generates and
installs tf2_msgs with rosidl (cmake + ninja), :mod:`.first_use` does it once when a
tool first needs it, :mod:`.cli` is ``online-em-slam-tf2-msgs``.  Nothing here imports
rclpy; on a real Jazzy install tf2_msgs comes from apt and none of it runs.
"""
