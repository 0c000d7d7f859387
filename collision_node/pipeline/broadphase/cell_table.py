"""Boxes entered in the cells of a lattice, grouped by hashed cell key (a counting sort).

The uniform grid's data structure. A box is entered once per cell of its range
(:mod:`~collision_node.pipeline.broadphase.cells`); each entry lands in bucket
``hash(cell key)`` of a power-of-two table with at least twice as many buckets as entries,
and a counting sort lays the entries out bucket by bucket (CSR): building is
O(boxes + entries + buckets), no comparison sort. Distinct cells may share a bucket, so every
entry keeps its cell key and readers compare keys. Big boxes (more than
``MAX_CELLS_PER_BODY`` cells) are not entered; they are listed in ``big_rows`` for a
brute-force row each.

Memory order decides the speed. The boxes are taken in the order of ``rows`` and the table
keeps a copy of their AABBs in that order (``aabbs``, one gather per box); entries refer to
that copy by slot and carry their first-cell flags, so the pair loop reads small entries and
nearby slots instead of scattered rows. Given a spatially coherent order (the grid passes
last tick's :func:`spatial_order`) every array is read and written nearly in sequence:
measured 2x faster than entries carrying rows and AABBs read from the boxes' rows.

Kernels read the table's arrays into locals first: each read of an array field of a tuple
costs numba a reference-count update, which made the pair loop 20x slower. Kernels never
allocate: :func:`fill_table` reports the sizes it needs and :func:`build_table` grows the
arrays and calls again, so growing is paid once per new maximum.
"""
from typing import NamedTuple

import numpy as np

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.broadphase.cells import (
    ALL_FIRST, bucket_of, cell_key, cell_range, first_cell_flags, LOCAL_BITS,
    MAX_CELLS_PER_BODY)
from collision_node.pipeline.broadphase.validation import (
    cell_counts, cell_of_key, cell_ranges, check, check_permutation, range_holds)
from collision_node.pipeline.flat_views import copy_into

# Buckets per entry: at 2 a bucket holds ~1 entry on average, so reading one is nearly free.
BUCKETS_PER_ENTRY = 2
GROWTH = 1.5
AUTO_SHIFT = 0  # build_table: choose the number of buckets from the number of entries


class CellTable(NamedTuple):
    """Entries of boxes ``rows[:n]`` in CSR order of their bucket (see fill_table)."""

    rows: np.ndarray        # (N,) int64: row of the box in slot i (slot i: rows[i] of fill)
    aabbs: np.ndarray       # (N, 2, 3) float64: AABB of the box in slot i
    ranges: np.ndarray      # (N, 2, 3) int64: cell range (first, last cell) of slot i
    is_big: np.ndarray      # (N,) bool: box first_row + i spans too many cells, not entered
    big_rows: np.ndarray    # (N,) int64: rows of the big boxes, the first sizes[2] are valid
    bucket_end: np.ndarray  # (B,) int64: bucket b holds entries [bucket_end[b-1], bucket_end[b])
    # Unsigned, so that numba indexes the slot's arrays without its negative-index fix-up
    # (measured: the grid's pair loop 8 % faster than with int32 slots).
    entry_slot: np.ndarray  # (E,) uint32: slot of each entry's box
    entry_key: np.ndarray   # (E,) int64: cell key of each entry
    entry_first: np.ndarray  # (E,) uint8: first_cell_flags of the entry's cell in its range
    sizes: np.ndarray       # (4,) int64: entries, buckets (a power of two), big boxes, shift


def empty_table(boxes=0, entries=0, buckets=2 << LOCAL_BITS):
    """Make a table with room for the given numbers of boxes, entries and buckets."""
    return CellTable(np.zeros(boxes, np.int64), np.zeros((boxes, 2, 3)),
                     np.zeros((boxes, 2, 3), np.int64), np.zeros(boxes, np.bool_),
                     np.zeros(boxes, np.int64), np.zeros(buckets, np.int64),
                     np.zeros(entries, np.uint32), np.zeros(entries, np.int64),
                     np.zeros(entries, np.uint8), np.zeros(4, np.int64))


def validate_table(table, lattice, aabbs, rows, first_row, held, what):
    """Check a table filled with boxes ``rows`` (sorted; filled in any order). For testing.

    Raises InvalidStructure at the first break. The slots hold each of ``rows`` once; a
    slot's cell range is that of its AABB copy, and the copy is the row's box in ``aabbs``
    where ``held`` (bool per row of ``rows``; a loose static box's copy keeps where it was
    entered); a box is big exactly when its range has more than ``MAX_CELLS_PER_BODY``
    cells, and then it is listed in ``big_rows`` and has no entry; every other box has one
    entry per cell of its range, in the bucket of that cell, with the cell's key and
    first-cell flags; the buckets partition the entries (CSR).
    """
    n = len(rows)
    entries, buckets, big, shift = (int(size) for size in table.sizes)
    check(0 < shift < 64 and buckets == 1 << (64 - shift + LOCAL_BITS)
          and buckets <= len(table.bucket_end) and 0 <= entries <= len(table.entry_slot)
          and n <= len(table.rows), '%s: sizes %s do not fit its arrays', what,
          table.sizes.tolist())
    slot_rows = table.rows[:n]
    check_permutation(slot_rows, rows, what + ' slots')
    copies, ranges = table.aabbs[:n], table.ranges[:n]
    check(np.array_equal(ranges, cell_ranges(lattice, copies, range(n))),
          "%s: a slot's cell range is not that of its AABB copy", what)
    held_slots = np.asarray(held, np.bool_)[np.searchsorted(rows, slot_rows)] \
        if n else np.zeros(0, np.bool_)
    stale = np.flatnonzero(held_slots & np.any(copies != aabbs[slot_rows], axis=(1, 2)))
    check(not len(stale), '%s: the copy of box %d is %s, the box is %s', what,
          slot_rows[stale[0]] if len(stale) else -1,
          copies[stale[0]].tolist() if len(stale) else None,
          aabbs[slot_rows[stale[0]]].tolist() if len(stale) else None)
    counts = cell_counts(ranges)
    is_big = counts > MAX_CELLS_PER_BODY
    check(np.array_equal(table.is_big[slot_rows - first_row], is_big),
          '%s: big flags disagree with the cell ranges', what)
    check(table.big_rows[:big].tolist() == slot_rows[is_big].tolist(),
          '%s: big rows %s, boxes over %d cells %s', what, table.big_rows[:big].tolist()[:20],
          MAX_CELLS_PER_BODY, slot_rows[is_big].tolist()[:20])
    check(entries == np.sum(counts[~is_big]), '%s: %d entries for %d cells of small boxes',
          what, entries, np.sum(counts[~is_big]))
    ends = table.bucket_end[:buckets]
    check(np.all(np.diff(ends) >= 0) and ends[0] >= 0 and ends[-1] == entries,
          '%s: bucket ends are not a partition of the %d entries', what, entries)
    seen = set()
    for bucket in np.flatnonzero(np.diff(ends, prepend=0)):
        for e in range(bucket_start(ends, bucket), ends[bucket]):
            slot, key = int(table.entry_slot[e]), int(table.entry_key[e])
            cell = cell_of_key(key)
            check(slot < n and not is_big[slot] and range_holds(ranges, slot, cell)
                  and (slot, cell) not in seen,
                  '%s: entry %d of slot %d (range %s) names cell %s%s', what, e, slot,
                  ranges[slot].tolist() if slot < n else None, cell,
                  ' twice' if (slot, cell) in seen else '')
            seen.add((slot, cell))
            check(bucket_of(*cell, shift) == bucket, '%s: entry %d of cell %s is in bucket %d, '
                  'not %d', what, e, cell, bucket, bucket_of(*cell, shift))
            check(table.entry_first[e] == first_cell_flags(ranges, slot, *cell),
                  '%s: entry %d of cell %s has first-cell flags %d, not %d', what, e, cell,
                  table.entry_first[e], first_cell_flags(ranges, slot, *cell))


def build_table(table, lattice, aabbs, rows, n, first_row, shift=AUTO_SHIFT):
    """Fill ``table`` (or a bigger table it returns) with boxes ``rows[:n]``.

    ``first_row`` is the smallest row the boxes can have (``is_big`` is indexed from it);
    ``shift`` fixes the number of buckets (:func:`~.cells.bucket_of`) so that two tables can be
    read bucket by bucket together, or is ``AUTO_SHIFT``: from the number of entries.
    """
    if len(table.is_big) < n:
        table = empty_table(int(n * GROWTH) + 1, len(table.entry_slot), len(table.bucket_end))
    while not fill_table(table, lattice, aabbs, rows, n, first_row, shift):
        entries, buckets = table.sizes[0], table.sizes[1]
        table = empty_table(len(table.is_big), max(int(entries * GROWTH) + 1,
                                                   len(table.entry_slot)),
                            max(BUCKETS_PER_ENTRY * int(entries * GROWTH) + 2, buckets))
    return table


@kernel
def fill_table(table, lattice, aabbs, rows, n, first_row, shift):
    """Enter boxes ``rows[:n]``; False (with ``sizes`` set) when the arrays are too small."""
    slot_rows, slot_aabbs, ranges, is_big = table.rows, table.aabbs, table.ranges, table.is_big
    big_rows, sizes, bucket_end = table.big_rows, table.sizes, table.bucket_end
    entry_slot, entry_key, entry_first = table.entry_slot, table.entry_key, table.entry_first
    entries = 0
    big = 0
    for i in range(n):
        row = rows[i]
        slot_rows[i] = row
        copy_into(slot_aabbs[i], aabbs[row])
        cells = cell_range(lattice, slot_aabbs, i, ranges, i)
        is_big[row - first_row] = cells > MAX_CELLS_PER_BODY
        if cells > MAX_CELLS_PER_BODY:
            big_rows[big] = row
            big += 1
        else:
            entries += cells
    if shift == AUTO_SHIFT:
        shift = shift_for(entries)
    buckets = 1 << (64 - shift + LOCAL_BITS)
    sizes[0] = entries
    sizes[1] = buckets
    sizes[2] = big
    sizes[3] = shift
    if entries > len(entry_slot) or buckets > len(bucket_end):
        return False
    bucket_end[:buckets] = 0
    for i in range(n):  # count the entries of each bucket
        if not is_big[rows[i] - first_row]:
            for x in range(ranges[i, 0, 0], ranges[i, 1, 0] + 1):
                for y in range(ranges[i, 0, 1], ranges[i, 1, 1] + 1):
                    for z in range(ranges[i, 0, 2], ranges[i, 1, 2] + 1):
                        bucket_end[bucket_of(x, y, z, shift)] += 1
    start = 0
    for b in range(buckets):  # exclusive prefix sum: bucket_end[b] = first entry of b
        size = bucket_end[b]
        bucket_end[b] = start
        start += size
    for i in range(n):  # scatter; each cursor ends at its bucket's end
        if not is_big[rows[i] - first_row]:
            for x in range(ranges[i, 0, 0], ranges[i, 1, 0] + 1):
                for y in range(ranges[i, 0, 1], ranges[i, 1, 1] + 1):
                    for z in range(ranges[i, 0, 2], ranges[i, 1, 2] + 1):
                        bucket = bucket_of(x, y, z, shift)
                        e = bucket_end[bucket]
                        bucket_end[bucket] = e + 1
                        entry_slot[e] = i
                        entry_key[e] = cell_key(x, y, z)
                        entry_first[e] = first_cell_flags(ranges, i, x, y, z)
    return True


@kernel
def shift_for(entries):
    """Return the hash shift giving at least ``BUCKETS_PER_ENTRY`` buckets per entry."""
    buckets = 2 << LOCAL_BITS  # the block hash keeps at least 1 bit: its shift stays < 64
    shift = 63
    while buckets < BUCKETS_PER_ENTRY * entries:
        buckets *= 2
        shift -= 1
    return shift


@kernel
def bucket_start(bucket_end, bucket):
    """Index of the first entry of ``bucket`` (``bucket_end`` of a filled table)."""
    return 0 if bucket == 0 else bucket_end[bucket - 1]


@kernel
def spatial_order(table, order):
    """Write the boxes' rows to ``order`` in the bucket order of their first cell, big last.

    Buckets follow space block by block, so this order keeps neighbours together.
    """
    slot_rows, entry_slot, entry_first = table.rows, table.entry_slot, table.entry_first
    big_rows = table.big_rows
    n = 0
    for e in range(table.sizes[0]):
        if entry_first[e] == ALL_FIRST:
            order[n] = slot_rows[entry_slot[e]]
            n += 1
    for i in range(table.sizes[2]):
        order[n] = big_rows[i]
        n += 1
    return n
