"""Sweep and prune ("Discrete Collision Algorithms"): boxes sorted by their lower bound, swept.

Algorithm. The dynamic boxes are kept sorted by the lower bound of their AABB on the sweep
axis, with a copy of their AABBs in that order so the sweep reads memory sequentially. Each
box is compared with the boxes after it until one starts beyond its upper bound; a pair is
reported when the AABBs overlap on all three axes. Static boxes are sorted once per axis
(at :meth:`SweepAndPrune.set_static`) and swept against the dynamic list by a merge: whichever
box starts first scans the other list, so each dynamic-static pair is met exactly once and
static boxes never meet each other.

Axis: the one along which the box centres (dynamic and static) spread most (variance), the
choice of Liu et al. 2010 cited by "Discrete Collision Algorithms"; the axis changes only when
another one spreads ``AXIS_SWITCH_RATIO`` times more, so a scene near a tie does not re-sort
every tick.

Coherence: between ticks boxes move little, so last tick's order is nearly sorted and an
insertion sort repairs it in about O(n + moves). When it needs more than
``MAX_SWAPS_PER_BODY`` swaps per box (the order changed too much, e.g. bodies came or went, or
the axis changed) it gives up and a full sort (O(n log n)) runs instead.
:meth:`SweepAndPrune.validate` (for tests) checks that every list is sorted and complete.

When to use: bodies spread along one axis (a corridor, a conveyor), few bodies, or as a
robust fallback: it needs no cell size and no domain. It degrades in dense 3-D scenes where
many boxes overlap on any single axis.
"""
import numpy as np

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.broadphase.pair_buffer import emit_if, PairBuffer
from collision_node.pipeline.broadphase.validation import check, check_permutation, loose_mask
from collision_node.pipeline.flat_views import copy_into
from collision_node.pipeline.obb import overlap_across

AXIS_SWITCH_RATIO = 1.25   # another axis must spread this many times more to take over
MAX_SWAPS_PER_BODY = 8     # insertion sort budget before falling back to a full sort


class SweepAndPrune:
    """Sorted dynamic list repaired every tick; static lists sorted once per axis."""

    name = 'sweep_and_prune'

    def __init__(self, settings=None):
        self._buffer = PairBuffer()
        self._axis = -1
        self._order = np.zeros(0, np.int64)     # dynamic rows by lower bound on the axis
        self._order_of = None  # (n_static, n_dynamic) the order was made for
        self._keys = np.zeros(0)
        self._sorted = np.zeros((0, 2, 3))      # dynamic AABBs in that order
        self._static_orders = np.zeros((3, 0), np.int64)
        self._static_sorted = np.zeros((3, 0, 2, 3))
        self._static_moments = np.zeros((2, 3))  # sum and sum of squares of static centres
        self.stats = {'axis': -1, 'full_sorts': 0, 'incremental_sorts': 0}

    def set_static(self, boxes, n_static):
        aabbs = boxes.aabbs[:n_static]
        self._static_orders = np.stack([np.argsort(aabbs[:, 0, k], kind='stable')
                                        for k in range(3)])
        self._copy_static(aabbs)

    def move_static(self, boxes, rows):
        """Sort the static lists again from their last order (nearly sorted) and copy them."""
        aabbs = boxes.aabbs
        count = self._static_orders.shape[1]
        keys = np.empty(count)
        for k in range(3):
            if not _insertion_sort(aabbs, k, self._static_orders[k], keys,
                                   MAX_SWAPS_PER_BODY * count):
                _full_sort(aabbs, k, self._static_orders[k], keys)
        self._copy_static(aabbs[:count])
        return np.ones(len(rows), np.bool_)

    def _copy_static(self, aabbs):
        """Copy the static AABBs in the order of each axis; their centres' moments."""
        centers = aabbs[:, 0] + aabbs[:, 1]  # twice the centre: only ratios matter
        self._static_moments = np.stack([centers.sum(axis=0), (centers ** 2).sum(axis=0)])
        self._static_sorted = np.ascontiguousarray(aabbs[self._static_orders])

    def find_pairs(self, boxes, n_static, n_dynamic, moved=None):
        aabbs = boxes.aabbs
        n_total = n_static + n_dynamic
        spread = _spread(aabbs, n_static, n_total, self._static_moments)
        axis = self._axis
        if axis < 0 or spread.max() > AXIS_SWITCH_RATIO * spread[axis]:
            axis = int(np.argmax(spread))
        if axis != self._axis or self._order_of != (n_static, n_dynamic):
            self._axis = axis
            self._order_of = (n_static, n_dynamic)
            self._order = np.arange(n_static, n_total)
            self._keys = np.empty(n_dynamic)
            self._sorted = np.empty((n_dynamic, 2, 3))
            _full_sort(aabbs, axis, self._order, self._keys)
            self.stats['full_sorts'] += 1
        elif _insertion_sort(aabbs, axis, self._order, self._keys,
                             MAX_SWAPS_PER_BODY * n_dynamic):
            self.stats['incremental_sorts'] += 1
        else:
            _full_sort(aabbs, axis, self._order, self._keys)
            self.stats['full_sorts'] += 1
        self.stats['axis'] = axis
        _gather(aabbs, self._order, self._sorted)
        return self._buffer.fill(_sweep, self._sorted, self._order, self._static_sorted[axis],
                                 self._static_orders[axis], n_static, axis)

    def validate(self, boxes, n_static, n_dynamic, loose=None):
        """Check the sorted lists against ``boxes``; raise InvalidStructure if wrong. For testing.

        Each static list (one per axis) holds every static row once, its AABB copies are the
        rows' boxes (loose rows excepted: the copies keep where they were) and are sorted by
        the lower bound on that axis; the dynamic list holds every dynamic row once, sorted on
        the sweep axis, its copies the boxes of the last tick. A dynamic list made for other
        counts than ``n_static`` and ``n_dynamic`` is checked on its own only: the next tick
        sorts a new one.
        """
        loose = loose_mask(loose, n_static)
        aabbs = boxes.aabbs
        orders, copies = self._static_orders, self._static_sorted
        check(orders.shape == (3, n_static) and copies.shape == (3, n_static, 2, 3),
              'static lists of shape %s (copies %s) for %d static boxes', orders.shape,
              copies.shape, n_static)
        for k in range(3):
            what = 'static list of axis %d' % k
            check_permutation(orders[k], np.arange(n_static), what)
            _check_sorted(copies[k], k, what)
            held = ~loose[orders[k]]
            stale = np.flatnonzero(np.any(copies[k][held] != aabbs[orders[k][held]],
                                          axis=(1, 2)))
            check(not len(stale), '%s: the copy of static box %d is not its box', what,
                  orders[k][held][stale[0]] if len(stale) else -1)
        in_rows = np.empty_like(copies[0])
        in_rows[orders[0]] = copies[0]  # the copies in row order, as _copy_static read them
        centers = in_rows[:, 0] + in_rows[:, 1]
        moments = np.stack([centers.sum(axis=0), (centers ** 2).sum(axis=0)])
        check(np.allclose(self._static_moments, moments, rtol=1e-12, atol=0.0),
              'static moments %s, the copies give %s', self._static_moments.tolist(),
              moments.tolist())
        if self._order_of is None:
            return  # no tick yet
        first, count = self._order_of
        axis = self._axis
        check(0 <= axis < 3 and self.stats['axis'] == axis, 'sweep axis %d (stats: %s)', axis,
              self.stats['axis'])
        check(len(self._keys) == len(self._sorted) == count, 'dynamic list of %d rows with %d '
              'keys and %d copies', count, len(self._keys), len(self._sorted))
        check_permutation(self._order, np.arange(first, first + count), 'dynamic list')
        _check_sorted(self._sorted, axis, 'dynamic list')
        check(np.array_equal(self._keys, self._sorted[:, 0, axis]),
              'dynamic list: keys are not the lower bounds of its copies')
        if self._order_of == (n_static, n_dynamic):
            stale = np.flatnonzero(np.any(self._sorted != aabbs[self._order], axis=(1, 2)))
            check(not len(stale), 'dynamic list: the copy of box %d is not its box',
                  self._order[stale[0]] if len(stale) else -1)


def _check_sorted(copies, axis, what):
    """Check that AABB ``copies`` are in order of their lower bound on ``axis``."""
    low = copies[:, 0, axis]
    unsorted = np.flatnonzero(low[1:] < low[:-1])
    check(not len(unsorted), '%s: not sorted by the lower bound on axis %d at position %d '
          '(%r after %r)', what, axis, unsorted[0] + 1 if len(unsorted) else -1,
          float(low[unsorted[0] + 1]) if len(unsorted) else None,
          float(low[unsorted[0]]) if len(unsorted) else None)


@kernel
def _spread(aabbs, n_static, n_total, static_moments):
    """Variance of the (doubled) box centres per axis, dynamic and static boxes pooled."""
    total = static_moments[0].copy()
    squares = static_moments[1].copy()
    for row in range(n_static, n_total):
        for k in range(3):
            c = aabbs[row, 0, k] + aabbs[row, 1, k]
            total[k] += c
            squares[k] += c * c
    mean = total / max(n_total, 1)
    return squares / max(n_total, 1) - mean * mean


@kernel
def _full_sort(aabbs, axis, order, keys):
    for i in range(len(order)):
        keys[i] = aabbs[order[i], 0, axis]
    by_key = np.argsort(keys, kind='mergesort')
    copy_into(order, order[by_key])
    copy_into(keys, keys[by_key])


@kernel
def _insertion_sort(aabbs, axis, order, keys, max_swaps):
    """Repair last tick's order for the new lower bounds; False when over budget."""
    for i in range(len(order)):
        keys[i] = aabbs[order[i], 0, axis]
    swaps = 0
    for i in range(1, len(order)):
        key = keys[i]
        row = order[i]
        j = i - 1
        while j >= 0 and keys[j] > key:
            keys[j + 1] = keys[j]
            order[j + 1] = order[j]
            j -= 1
        swaps += i - 1 - j
        keys[j + 1] = key
        order[j + 1] = row
        if swaps > max_swaps:
            return False
    return True


@kernel
def _gather(aabbs, order, out):
    for i in range(len(order)):
        copy_into(out[i], aabbs[order[i]])


@kernel
def _sweep(dynamic, order, static, static_order, n_static, axis, out):
    """Dynamic list against itself, then merged with the static list on ``axis``."""
    count = 0
    compared = 0
    n = len(order)
    for i in range(n):
        high = dynamic[i, 1, axis]
        a = order[i]
        j = i + 1
        while j < n and dynamic[j, 0, axis] <= high:
            compared += 1
            b = order[j]
            count = emit_if(out, count, overlap_across(dynamic, i, dynamic, j), min(a, b),
                            max(a, b))
            j += 1
    i = 0
    s = 0
    n_s = n_static
    while i < n and s < n_s:
        if dynamic[i, 0, axis] <= static[s, 0, axis]:  # dynamic box i starts first
            high = dynamic[i, 1, axis]
            t = s
            while t < n_s and static[t, 0, axis] <= high:
                compared += 1
                count = emit_if(out, count, overlap_across(dynamic, i, static, t), order[i],
                                static_order[t])
                t += 1
            i += 1
        else:  # static box s starts first
            high = static[s, 1, axis]
            t = i
            while t < n and dynamic[t, 0, axis] <= high:
                compared += 1
                count = emit_if(out, count, overlap_across(dynamic, t, static, s), order[t],
                                static_order[s])
                t += 1
            s += 1
    return count, compared
