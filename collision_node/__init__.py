"""Real-time collision detection between oriented bounding boxes, for ROS 2.

The package is layered; each layer imports only the ones above it in this list:

- :mod:`collision_node.pipeline`: boxes, broad phases, SAT, contacts and the ``World`` (numpy
  and numba only, no ROS);
- :mod:`collision_node.ros`: the node and its edges (parameters, CDR, messages, markers,
  diagnostics);
- :mod:`collision_node.benchmarks` and :mod:`collision_node.tools`: the command-line programs.

The names below are the public API, each imported on first use: ``from collision_node import
World`` never loads ROS, and importing a submodule (a console script's entry) loads nothing.
"""
import importlib

_NAMES = {  # imported on first use: importing a submodule never loads numba or ROS
    'CONTACT_DTYPE': 'collision_node.pipeline.world',
    'DYNAMIC': 'collision_node.pipeline.world',
    'Result': 'collision_node.pipeline.world',
    'Robot': 'collision_node.pipeline.robot',
    'STATIC': 'collision_node.pipeline.world',
    'World': 'collision_node.pipeline.world',
    'warm_up': 'collision_node.pipeline.warm_up',
    'cloud_to_contacts': 'collision_node.ros.messages',
    'serialize_pose_array': 'collision_node.ros.cdr',
}

__all__ = sorted(_NAMES)


def __getattr__(name):
    if name in _NAMES:
        return getattr(importlib.import_module(_NAMES[name]), name)
    raise AttributeError('module %r has no attribute %r' % (__name__, name))
