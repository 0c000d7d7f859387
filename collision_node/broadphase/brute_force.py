"""Brute force: every dynamic box against every static box and every other dynamic box.

The baseline of both seed papers, O(D·S + D²/2) comparisons. The comparison is an AABB
overlap test; the ``sphere`` phase runs the same loop with the bounding-sphere test.
"""
from collision_node._jit import kernel
from collision_node.broadphase.pair_buffer import PairBuffer
from collision_node.obb import aabbs_overlap, spheres_apart


class BruteForce:
    """All pairs, filtered by their AABBs."""

    name = 'brute_force'
    uses_spheres = False

    def __init__(self, settings=None):
        self._buffer = PairBuffer()

    def set_static(self, boxes, n_static):
        pass  # nothing to build: every tick compares against all static boxes

    def find_pairs(self, boxes, n_static, n_dynamic):
        return self._buffer.fill(_all_pairs, boxes.aabbs, boxes.centers, boxes.radii,
                                 n_static, n_static + n_dynamic, self.uses_spheres)


@kernel
def _all_pairs(aabbs, centers, radii, n_static, n_total, uses_spheres, out):
    count = 0
    capacity = out.shape[0]
    for a in range(n_static, n_total):
        for b in range(n_total):
            if b >= n_static and b <= a:
                continue
            if uses_spheres:
                close = not spheres_apart(centers, radii, a, b)
            else:
                close = aabbs_overlap(aabbs, a, b)
            if close:
                if count < capacity:
                    out[count, 0] = a
                    out[count, 1] = b
                count += 1
    n_dynamic = n_total - n_static
    compared = n_dynamic * n_static + n_dynamic * (n_dynamic - 1) // 2
    return count, compared
