"""Brute force: every dynamic box against every static box and every other dynamic box.

The baseline of both seed papers, O(D·S + D²/2) comparisons. The comparison is an AABB
overlap test; the ``sphere`` phase runs the same loop with the bounding-sphere test. Nothing
is built, so ``validate`` (for tests) only checks the counts.
"""
import numpy as np

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.broadphase.pair_buffer import emit, PairBuffer
from collision_node.pipeline.broadphase.validation import check, loose_mask
from collision_node.pipeline.obb import overlap_across, spheres_apart

CHUNK = 32  # rows tested together before any pair is stored


class BruteForce:
    """All pairs, filtered by their AABBs."""

    name = 'brute_force'
    uses_spheres = False

    def __init__(self, settings=None):
        self._buffer = PairBuffer()
        self.stats = {}  # nothing to count beyond ``compared``

    def set_static(self, boxes, n_static):
        pass  # nothing to build: every tick compares against all static boxes

    def move_static(self, boxes, rows):
        return np.ones(len(rows), np.bool_)  # nothing built: every tick reads the boxes

    def validate(self, boxes, n_static, n_dynamic, loose=None):
        """Check the counts against ``boxes`` (nothing is built to check). For testing."""
        loose_mask(loose, n_static)
        check(0 <= n_static and 0 <= n_dynamic and n_static + n_dynamic <= boxes.capacity,
              '%d static and %d dynamic boxes in storage for %d', n_static, n_dynamic,
              boxes.capacity)

    def find_pairs(self, boxes, n_static, n_dynamic, moved=None):
        return self._buffer.fill(_all_pairs, boxes.aabbs, boxes.centers, boxes.radii,
                                 n_static, n_static + n_dynamic, self.uses_spheres)


@kernel
def _all_pairs(aabbs, centers, radii, n_static, n_total, uses_spheres, out):
    """Each dynamic box against the static rows, then against the later dynamic rows.

    The rows are taken ``CHUNK`` at a time: a chunk is first only counted, in a loop with no
    store and no branch that LLVM turns into SIMD code, and only a chunk with a hit is gone
    through again to store its pairs (measured 2-3x faster than storing pair by pair). The
    tests are written out here, not called through a helper: a call that LLVM does not
    inline costs more than the test itself.
    """
    count = 0
    for a in range(n_static, n_total):
        for first, stop in ((0, n_static), (a + 1, n_total)):
            for start in range(first, stop, CHUNK):
                end = min(start + CHUNK, stop)
                hits = 0
                if uses_spheres:
                    for b in range(start, end):
                        hits += not spheres_apart(centers, radii, a, b)
                else:
                    for b in range(start, end):
                        hits += overlap_across(aabbs, a, aabbs, b)
                if hits:
                    for b in range(start, end):
                        if uses_spheres:
                            close = not spheres_apart(centers, radii, a, b)
                        else:
                            close = overlap_across(aabbs, a, aabbs, b)
                        if close:
                            count = emit(out, count, a, b, n_static)
    n_dynamic = n_total - n_static
    compared = n_dynamic * n_static + n_dynamic * (n_dynamic - 1) // 2
    return count, compared
