"""The ROS 2 side: the ``mos_node`` node and the pieces it is built from.

Only :mod:`ros2_mos.ros.node` imports rclpy; :mod:`params`, :mod:`messages`,
:mod:`processor`, :mod:`latest_queue` and :mod:`stats` are plain Python so that
the offline ``process`` command and the tests share them without a ROS graph.
"""
