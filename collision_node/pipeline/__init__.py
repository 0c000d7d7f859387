"""The collision pipeline without ROS: poses → boxes → broad phase → SAT → contacts.

:mod:`~collision_node.pipeline.world` drives it; nothing in this package imports rclpy or any
other part of ``collision_node`` outside it.
"""
