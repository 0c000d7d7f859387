"""Uniform grid: boxes binned by hashed cell keys, dynamic boxes re-binned every tick.

Algorithm. Space is cut into cubic cells of side ``GRID_CELL_FACTOR`` × the mean AABB side
(of the static or the dynamic boxes, whichever is larger). The static boxes are entered in a
:class:`~.cell_table.CellTable` once; every tick the dynamic boxes are entered in a second
table on the same lattice with the same number of buckets, by a counting sort on hashed cell
keys (O(D + entries), no comparison sort, no allocation once the arrays have grown). A cell
lands in the same bucket of both tables, so one pass over the dynamic buckets finds every
pair: dynamic entries of a bucket against each other and against the static entries of the
same bucket, a pair counted only in its first shared cell. Boxes spanning more than
``MAX_CELLS_PER_BODY`` cells are compared with everything instead.

The static table is rebuilt only when the dynamic sizes drift by more than
``STATIC_RESIZE_RATIO`` from those it was sized for, or when the dynamic entries outgrow its
buckets. Without static boxes the lattice follows the dynamic boxes every tick.

Speed comes from memory order and from avoiding unpredictable branches: boxes are entered in
the order of the previous tick's table (neighbours together) and their AABBs copied in that
order, buckets are hashed per block of cells (neighbouring cells share cache lines), both
tables are read sequentially bucket by bucket, and the pair test and the pair output have no
branches (in a cell a hit is a coin flip).

Invariants: the cell mapping is monotone, so boxes whose AABBs overlap have intersecting
cell ranges and meet in their first shared cell, in which both are entered; the lattice is
unbounded (hashed keys, clamped at ±2**20 cells), so there is no domain to leave.
:meth:`Grid.validate` (for tests) checks both tables entry by entry.

When to use: many bodies of similar size, anywhere in space (uniform, clustered or flying
apart: the hash has no domain and the cell side follows the body size). It degrades when sizes
differ by orders of magnitude (the cell side follows the mean) and when many bodies share one
cell (all at one point: brute force within the cell).
"""
import numpy as np

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.broadphase.cell_table import (
    AUTO_SHIFT, bucket_start, BUCKETS_PER_ENTRY, build_table, empty_table,
    shift_for, spatial_order, validate_table)
from collision_node.pipeline.broadphase.cells import (
    ALL_FIRST, keeps_cells, make_lattice, mean_side_and_center, pairs_with_all_dynamic,
    pairs_with_all_static)
from collision_node.pipeline.broadphase.pair_buffer import emit, emit_if, PairBuffer
from collision_node.pipeline.broadphase.validation import check, check_permutation, loose_mask
from collision_node.pipeline.obb import overlap_across
from collision_node.pipeline.workers import Workers

# Cell side / mean AABB side: the fastest measured on the uniform and seed scenes.
GRID_CELL_FACTOR = 1.5
# The static table is rebuilt when the cell side the dynamic sizes ask for differs from its
# own by more than this factor, or when the dynamic entries exceed its buckets this many times
# over (load factor 2 instead of 1 / BUCKETS_PER_ENTRY): both are rare, and the margins stop
# a scene near a threshold from rebuilding every tick.
STATIC_RESIZE_RATIO = 4.0
MAX_DYNAMIC_LOAD = 2.0
# Least buckets in a chunk when the pair search is spread over threads: a bucket holds at most
# half an entry on average (BUCKETS_PER_ENTRY), so a chunk is up to ~1,000 entries' work, well
# above the ~10-50 µs a helper's dispatch costs.
MIN_BUCKETS_PER_CHUNK = 2048
GROWTH = 1.5


class Grid:
    """Hashed uniform grid; static table built once, dynamic table every tick."""

    name = 'grid'

    def __init__(self, settings=None, workers=None):
        self._workers = Workers() if workers is None else workers
        # One buffer per chunk of buckets (see Workers.map_ranges), one for the big boxes.
        self._buffers = [PairBuffer() for _ in range(self._workers.max_chunks)]
        self._big_buffer = PairBuffer()
        self._pairs = np.zeros((0, 2), np.int64)  # the parts joined
        self._dynamic = empty_table()
        self._static = empty_table()
        self._static_lattice = None   # None: static table to be built at the next tick
        self._static_side = 0.0       # the cell side the static table was built with
        self._static_slots = np.zeros(0, np.int64)  # slot of each static row in the table
        self._static_reuse = None  # (spatial order, shift) of a table built for these boxes
        self._static_mean_side = 0.0
        self._order = np.zeros(0, np.int64)  # dynamic rows, neighbours together
        self._order_of = (0, 0)  # (n_static, n_dynamic) the order was made for
        self._dynamic_lattice = None  # the lattice of the last dynamic table, for validate
        self.stats = {'static_builds': 0}

    def set_static(self, boxes, n_static):
        self._static_mean_side = mean_side_and_center(boxes.aabbs, 0, n_static)[0]
        # As many boxes as the table holds (the World rebuilds it after static boxes moved):
        # its spatial order and bucket count serve again, one build instead of two. Any order
        # and count are correct; these are fast when the boxes are the same, moved a little.
        self._static_reuse = None
        if self._static_lattice is not None and len(self._static_slots) == n_static:
            self._static_reuse = (self._static.rows[:n_static].copy(), self._static.sizes[3])
        self._static_lattice = None  # built at the next tick, when dynamic sizes are known

    def move_static(self, boxes, rows):
        """Keep the static boxes that stayed in their cells: refresh the table's AABB copies."""
        kept = np.ones(len(rows), np.bool_)
        if self._static_lattice is not None:  # else it is built from the boxes as they are
            keeps_cells(self._static_lattice, boxes.aabbs, rows, self._static.ranges,
                        self._static_slots, self._static.aabbs, kept)
        return kept

    def find_pairs(self, boxes, n_static, n_dynamic, moved=None):
        aabbs = boxes.aabbs
        n_total = n_static + n_dynamic
        if self._order_of != (n_static, n_dynamic):  # bodies came or went: start afresh
            self._order = np.arange(n_static, n_total)
            self._order_of = (n_static, n_dynamic)
        side, center = mean_side_and_center(aabbs, n_static, n_total)
        if n_static == 0:
            self._fill_dynamic(aabbs, n_static, n_dynamic,
                               make_lattice(center, GRID_CELL_FACTOR * side), AUTO_SHIFT)
        else:
            wanted_side = GRID_CELL_FACTOR * max(self._static_mean_side, side)
            if self._static_lattice is None or \
                    not _within_ratio(wanted_side, self._static_side, STATIC_RESIZE_RATIO):
                self._build_static(aabbs, n_static, wanted_side, 0)
            shift = self._static.sizes[3]
            self._fill_dynamic(aabbs, n_static, n_dynamic, self._static_lattice, shift)
            entries = self._dynamic.sizes[0]
            if entries > MAX_DYNAMIC_LOAD * self._static.sizes[1]:
                self._build_static(aabbs, n_static, wanted_side, entries)
                self._fill_dynamic(aabbs, n_static, n_dynamic, self._static_lattice,
                                   self._static.sizes[3])
        dynamic, static = self._dynamic, self._static

        def chunk(k, first_bucket, stop_bucket):
            return self._buffers[k].fill(_bucket_pairs, n_static, dynamic, static, moved,
                                         first_bucket, stop_bucket)

        parts = self._workers.map_ranges(chunk, dynamic.sizes[1], MIN_BUCKETS_PER_CHUNK)
        parts.append(self._big_buffer.fill(_big_pairs, aabbs, n_static, n_total, dynamic,
                                           static))
        spatial_order(dynamic, self._order)  # next tick's filling order
        return self._joined([pairs for pairs, _ in parts]), sum(c for _, c in parts)

    def validate(self, boxes, n_static, n_dynamic, loose=None):
        """Check both tables against ``boxes``; raise InvalidStructure if wrong. For testing.

        See :func:`~.cell_table.validate_table`: the static table (once built) holds every
        static box, a loose one in the cells it was entered in; the dynamic table holds the
        dynamic boxes of the last tick and, when there are static boxes, has the static
        table's lattice and buckets (the pair loop reads the two bucket by bucket). A dynamic
        table made for other counts than ``n_static`` and ``n_dynamic`` is left alone: the
        next tick fills a new one.
        """
        loose = loose_mask(loose, n_static)
        aabbs = boxes.aabbs
        static = self._static
        if n_static and self._static_lattice is not None:
            check(len(self._static_slots) == n_static, 'static slots for %d boxes, the scene '
                  'has %d', len(self._static_slots), n_static)
            validate_table(static, self._static_lattice, aabbs, np.arange(n_static), 0,
                           ~loose, 'static table')
            check(np.array_equal(self._static_slots[static.rows[:n_static]],
                                 np.arange(n_static)), 'static slots are not those of the rows')
        if self._static_reuse is not None:
            check_permutation(self._static_reuse[0], np.arange(n_static), 'reused static order')
        n_total = n_static + n_dynamic
        if self._order_of != (n_static, n_dynamic):
            return
        check_permutation(self._order[:n_dynamic], np.arange(n_static, n_total), 'fill order')
        if self._dynamic_lattice is None:
            return  # no tick yet
        dynamic = self._dynamic
        validate_table(dynamic, self._dynamic_lattice, aabbs, np.arange(n_static, n_total),
                       n_static, np.ones(n_dynamic, np.bool_), 'dynamic table')
        if n_static and self._static_lattice is not None:
            check(self._dynamic_lattice == self._static_lattice
                  and dynamic.sizes[3] == static.sizes[3],
                  'dynamic table on another lattice or shift (%d) than the static one (%d)',
                  dynamic.sizes[3], static.sizes[3])

    def _joined(self, parts):
        """Return the pairs of all parts in one array (the only part, if the others are empty)."""
        filled = [pairs for pairs in parts if len(pairs)]
        if len(filled) <= 1:
            return filled[0] if filled else parts[0]
        count = sum(len(pairs) for pairs in filled)
        if len(self._pairs) < count:
            self._pairs = np.empty((int(count * GROWTH) + 1, 2), np.int64)
        return np.concatenate(filled, out=self._pairs[:count])

    def _fill_dynamic(self, aabbs, n_static, n_dynamic, lattice, shift):
        self._dynamic_lattice = lattice
        self._dynamic = build_table(self._dynamic, lattice, aabbs, self._order, n_dynamic,
                                    n_static, shift)

    def _build_static(self, aabbs, n_static, side, dynamic_entries):
        """Build the static table; buckets for its entries and twice ``dynamic_entries``.

        The dynamic table shares the static table's buckets, so they must suit both.
        """
        self._static_side = side
        self._static_lattice = make_lattice(mean_side_and_center(aabbs, 0, n_static)[1], side)
        if self._static_reuse is not None and not dynamic_entries:
            rows, shift = self._static_reuse
        else:
            rows = np.arange(n_static)
            self._static = build_table(self._static, self._static_lattice, aabbs, rows,
                                       n_static, 0)
            shift = min(self._static.sizes[3], shift_for(BUCKETS_PER_ENTRY * dynamic_entries))
            # Built again in spatial order, so that the slots of neighbours are neighbours.
            spatial_order(self._static, rows)
        self._static_reuse = None
        self._static = build_table(self._static, self._static_lattice, aabbs, rows, n_static,
                                   0, shift)
        self._static_slots = np.empty(n_static, np.int64)
        self._static_slots[self._static.rows[:n_static]] = np.arange(n_static)
        self.stats['static_builds'] += 1


def _within_ratio(a, b, ratio):
    return a <= ratio * b and b <= ratio * a


@kernel
def _bucket_pairs(n_static, dynamic, static, moved, first_bucket, stop_bucket, out):
    """Pairs of the small boxes entered in buckets ``[first_bucket, stop_bucket)``.

    A dynamic box that has not ``moved`` (None: every box moved) gets no pairs with static
    boxes nor with another such box (see find_pairs).
    """
    rows, boxes = dynamic.rows, dynamic.aabbs
    bucket_end, entry_slot = dynamic.bucket_end, dynamic.entry_slot
    entry_key, entry_first = dynamic.entry_key, dynamic.entry_first
    static_rows, static_boxes, static_end = static.rows, static.aabbs, static.bucket_end
    static_slot, static_key, static_first = static.entry_slot, static.entry_key, \
        static.entry_first
    count = 0
    compared = 0
    for bucket in range(first_bucket, stop_bucket):
        end = bucket_end[bucket]
        start = bucket_start(bucket_end, bucket)
        if start == end:
            continue
        static_start = bucket_start(static_end, bucket) if n_static else 0
        static_stop = static_end[bucket] if n_static else 0
        for e in range(start, end):
            key = entry_key[e]
            first = entry_first[e]
            slot = entry_slot[e]
            row = rows[slot]
            # The box's AABB in locals: the stores to ``out`` would make LLVM reload it.
            x0, y0, z0 = boxes[slot, 0, 0], boxes[slot, 0, 1], boxes[slot, 0, 2]
            x1, y1, z1 = boxes[slot, 1, 0], boxes[slot, 1, 1], boxes[slot, 1, 2]
            has_moved = True if moved is None else moved[row - n_static]
            # Only the first shared cell of a pair owns it; tested without branches. Two boxes
            # that have not moved are no pair either (see find_pairs); with ``moved`` None
            # (all moved) numba compiles that test away.
            for f in range(e + 1, end):
                owned = (entry_key[f] == key) & ((first | entry_first[f]) == ALL_FIRST)
                compared += owned
                other = entry_slot[f]
                other_row = rows[other]
                if moved is not None:
                    owned &= has_moved | moved[other_row - n_static]
                hit = owned & _overlaps(x0, y0, z0, x1, y1, z1, boxes, other)
                count = emit_if(out, count, hit, min(row, other_row), max(row, other_row))
            # A box that has not moved skips the static boxes: two thirds of the loop's steps
            # at 10,000 bodies. When every box moved the test always passes, at no cost.
            static_until = static_stop if has_moved else static_start
            for s in range(static_start, static_until):
                owned = (static_key[s] == key) & ((first | static_first[s]) == ALL_FIRST)
                compared += owned
                other = static_slot[s]
                hit = owned & _overlaps(x0, y0, z0, x1, y1, z1, static_boxes, other)
                count = emit_if(out, count, hit, row, static_rows[other])
    return count, compared


@kernel
def _big_pairs(aabbs, n_static, n_total, dynamic, static, out):
    """Pairs of the big boxes, which are in no bucket: a brute-force row or column each."""
    is_big = dynamic.is_big
    count = 0
    compared = 0
    for i in range(dynamic.sizes[2]):  # big dynamic boxes: a brute-force row each
        a = dynamic.big_rows[i]
        count, tested = pairs_with_all_dynamic(aabbs, a, n_static, n_total, is_big, out, count)
        compared += tested
        count, tested = pairs_with_all_static(aabbs, a, n_static, out, count)
        compared += tested
    for i in range(static.sizes[2] if n_static else 0):  # big static boxes: a column each
        b = static.big_rows[i]
        for a in range(n_static, n_total):
            if not is_big[a - n_static]:
                compared += 1
                if overlap_across(aabbs, a, aabbs, b):
                    count = emit(out, count, a, b, n_static)
    return count, compared


@kernel
def _overlaps(x0, y0, z0, x1, y1, z1, aabbs, b):
    """:func:`~collision_node.pipeline.obb.overlap_across`, the first box given by its corners."""
    return not ((x0 > aabbs[b, 1, 0]) | (aabbs[b, 0, 0] > x1) | (y0 > aabbs[b, 1, 1])
                | (aabbs[b, 0, 1] > y1) | (z0 > aabbs[b, 1, 2]) | (aabbs[b, 0, 2] > z1))
