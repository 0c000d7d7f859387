"""Real-time collision detection between oriented bounding boxes, for ROS 2.

The geometry, broad phases and SAT are plain numpy/numba modules; :mod:`collision_node.node`
is the only one that imports rclpy.
"""
from collision_node.world import CONTACT_DTYPE, DYNAMIC, Result, STATIC, World

__all__ = ['CONTACT_DTYPE', 'DYNAMIC', 'Result', 'STATIC', 'World']
