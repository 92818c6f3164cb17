"""ROS 2 interface of online_em_slam: parameters, message conversions and the node.

Only this subpackage imports rclpy and message packages; the estimation core
(:mod:`online_em_slam.core`) stays ROS-free.
"""
