"""Real-time collision detection between oriented bounding boxes, for ROS 2.

The package is layered; each layer imports only the ones above it in this list:

- :mod:`collision_node.pipeline`: boxes, broad phases, SAT, contacts and the ``World`` (numpy
  and numba only, no ROS);
- :mod:`collision_node.ros`: the node and its edges (parameters, CDR, messages, markers,
  diagnostics);
- :mod:`collision_node.benchmarks` and :mod:`collision_node.tools`: the command-line programs.

The names below are the public API. ``cloud_to_contacts`` and ``serialize_pose_array`` are
imported on first use, so ``from collision_node import World`` never loads ROS.
"""
import importlib

from collision_node.pipeline.robot import Robot
from collision_node.pipeline.warm_up import warm_up
from collision_node.pipeline.world import CONTACT_DTYPE, DYNAMIC, Result, STATIC, World

_ROS_NAMES = {
    'cloud_to_contacts': 'collision_node.ros.messages',
    'serialize_pose_array': 'collision_node.ros.cdr',
}

__all__ = ['CONTACT_DTYPE', 'DYNAMIC', 'Result', 'Robot', 'STATIC', 'World', 'warm_up',
           *_ROS_NAMES]


def __getattr__(name):
    if name in _ROS_NAMES:
        return getattr(importlib.import_module(_ROS_NAMES[name]), name)
    raise AttributeError('module %r has no attribute %r' % (__name__, name))
