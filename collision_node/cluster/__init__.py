"""The World's batch checks spread over Ray actors, on one machine or a cluster (doc/cluster.md).

    from collision_node.cluster import ClusterChecker
    with ClusterChecker(world, workers=2, chunk=10_000) as checker:
        contacts = checker.check_joints(q).contacts   # == world.check_joints(q).contacts

Optional: it needs Ray, installed with ``pip install .[ray]``. Nothing else in the package
imports Ray; this layer imports the pipeline and Ray only.
"""
try:
    import ray  # noqa: F401 (the extra's presence is checked here, once)
except ImportError as error:
    raise ImportError("collision_node.cluster needs Ray: install the 'ray' extra "
                      "(pip install '.[ray]', or pip install ray)") from error

from collision_node.cluster.checker import (  # noqa: E402 (after the check for Ray)
    ClusterChecker, ClusterError, DEFAULT_CHUNK, DEFAULT_IN_FLIGHT, local_ray, transport_only)

__all__ = ['ClusterChecker', 'ClusterError', 'DEFAULT_CHUNK', 'DEFAULT_IN_FLIGHT', 'local_ray',
           'transport_only']
