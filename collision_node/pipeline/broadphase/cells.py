"""Integer cell ranges of AABBs on a regular lattice; shared by the octree and the grid.

A :class:`Lattice` has an origin, a cell side and clamping bounds. The cell of a coordinate
``x`` on axis ``k`` is ``floor((x - origin[k]) / side)`` clamped to ``[low, high]``, and the
cell range of an AABB is the cells of its two corners. Every step of that mapping
(subtraction, multiplication by a positive constant, floor, clamp) is non-decreasing, so two
closed intervals that intersect map to integer ranges that intersect *whatever the rounding*:
this is what makes the cell-based phases exact. Clamping makes a finite lattice cover all of
space: bodies beyond it share the border cells, which is slower but never loses a pair.

A pair of boxes whose cell ranges intersect meets in several cells; it is reported only in
its *first shared cell*, the per-axis maximum of the two range starts, so no pair is reported
twice and no set or sort is needed to remove duplicates. In a cell both ranges contain, that
cell is the first shared one exactly when, on every axis, it is the first cell of one of the
two ranges: with three "first on this axis" bits per entry (:func:`first_cell_flags`) the
test is ``flags_a | flags_b == ALL_FIRST``, with no look-up of either range.

A box spanning more than :data:`MAX_CELLS_PER_BODY` cells is *big*: instead of being entered
in all of them it is compared with every box (the helpers at the end of this module), which
caps the cost of one huge box at one brute-force row.
"""
import math
from typing import NamedTuple

import numpy as np

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.broadphase.hash_map import HASH_MULTIPLIER  # Fibonacci hashing
from collision_node.pipeline.broadphase.pair_buffer import emit
from collision_node.pipeline.flat_views import copy_into
from collision_node.pipeline.obb import aabbs_overlap

# Cell coordinates are packed into one int64 key with 21 bits per axis, so a lattice spans at
# most 2**21 cells per axis around its origin; farther coordinates are clamped to the border.
KEY_BITS = 21
KEY_OFFSET = 1 << (KEY_BITS - 1)
MAX_CELL = KEY_OFFSET - 1
MIN_CELL = -KEY_OFFSET
# Entering a box in k cells costs about k hash look-ups and the pairs of k cells; comparing it
# with everything costs one AABB test per body (~1-2 ns each). 64 cells (4 x 4 x 4) is where a
# box is far larger than the cells and the brute-force row becomes the cheaper way.
MAX_CELLS_PER_BODY = 64
ALL_FIRST = 7  # first_cell_flags of a pair's first shared cell, or'ed over the two boxes
BLOCK_BITS = 2  # hash blocks of 4 x 4 x 4 cells (see bucket_of)
BLOCK_MASK = (1 << BLOCK_BITS) - 1
LOCAL_BITS = 3 * BLOCK_BITS


class Lattice(NamedTuple):
    """Cells of side ``1 / inv_side`` from ``origin``, clamped to ``[low, high]``.

    Scalars only: numba passes such a tuple by value, while every read of an array field of a
    tuple costs a reference-count update (measured 20x slower in a pair loop).
    """

    origin_x: float
    origin_y: float
    origin_z: float
    inv_side: float
    low: int
    high: int


def make_lattice(origin, side, low=MIN_CELL, high=MAX_CELL):
    """Make a lattice with cells of ``side`` (any positive side is exact; it sets the speed)."""
    if not (side > 0.0 and math.isfinite(1.0 / side)):
        side = 1.0  # points only, or sizes that underflow: any positive side is correct
    x, y, z = (float(c) for c in origin)
    return Lattice(x, y, z, 1.0 / side, int(low), int(high))


@kernel
def mean_side_and_center(aabbs, first, stop):
    """Mean AABB side (over boxes and axes) and mean centre of rows ``first`` .. ``stop``."""
    side = 0.0
    center = np.zeros(3)
    n = stop - first
    for row in range(first, stop):
        for k in range(3):
            side += aabbs[row, 1, k] - aabbs[row, 0, k]
            center[k] += 0.5 * (aabbs[row, 0, k] + aabbs[row, 1, k])
    if n == 0:
        return 0.0, center
    return side / (3 * n), center / n


@kernel
def cell_of(lattice, x, axis):
    """Return the clamped cell index of coordinate ``x`` on ``axis``."""
    origin = lattice.origin_x if axis == 0 else lattice.origin_y if axis == 1 \
        else lattice.origin_z
    v = (x - origin) * lattice.inv_side
    # Clamp as a float before converting: an infinite or huge value has no int64 image.
    if not v >= lattice.low:  # also catches NaN, which validated boxes never have
        return lattice.low
    if v >= lattice.high:
        return lattice.high
    return int(math.floor(v))


@kernel
def cell_range(lattice, aabbs, row, ranges, slot):
    """Write the cell range of box ``row`` to ``ranges[slot]`` (2, 3); return its cell count.

    The count is capped at ``MAX_CELLS_PER_BODY + 1`` (enough to say "big") so it never
    overflows.
    """
    cells = 1
    for k in range(3):
        ranges[slot, 0, k] = cell_of(lattice, aabbs[row, 0, k], k)
        ranges[slot, 1, k] = cell_of(lattice, aabbs[row, 1, k], k)
        cells *= min(ranges[slot, 1, k] - ranges[slot, 0, k] + 1, MAX_CELLS_PER_BODY + 1)
    return min(cells, MAX_CELLS_PER_BODY + 1)


@kernel
def keeps_cells(lattice, aabbs, rows, ranges, slot_of_row, copies, kept):
    """Set ``kept[i]`` where box ``rows[i]`` still has the cell range of its slot in ``ranges``.

    A static box that moved within its cells is where a cell structure entered it: only its
    AABB changed, which the pair tests read, or which is copied to the structure's own
    ``copies`` (same slots; pass an empty array when there are none). The slot of row r is
    ``slot_of_row[r]``.
    """
    scratch = np.empty((1, 2, 3), np.int64)
    for i in range(len(rows)):
        row = rows[i]
        slot = slot_of_row[row]
        cell_range(lattice, aabbs, row, scratch, 0)
        same = True
        for end in range(2):
            for k in range(3):
                same &= scratch[0, end, k] == ranges[slot, end, k]
        kept[i] = same
        if same and len(copies):
            copy_into(copies[slot], aabbs[row])


@kernel
def cell_key(x, y, z):
    """One int64 for a cell; distinct cells of one lattice get distinct keys."""
    return ((x + KEY_OFFSET) << (2 * KEY_BITS)) | ((y + KEY_OFFSET) << KEY_BITS) \
        | (z + KEY_OFFSET)


@kernel
def bucket_of(x, y, z, shift):
    """Bucket of cell (x, y, z) in a table of ``2**(64 - shift + LOCAL_BITS)`` buckets.

    The block of 4 x 4 x 4 cells holding the cell is hashed (Fibonacci hashing: the top
    ``64 - shift`` bits of the product, which depend on every bit of the block key) and the
    cell's place in its block picks one of the block's 64 consecutive buckets, so cells that
    are neighbours in space are neighbours in memory.
    """
    block = cell_key(x >> BLOCK_BITS, y >> BLOCK_BITS, z >> BLOCK_BITS)
    local = (x & BLOCK_MASK) | ((y & BLOCK_MASK) << BLOCK_BITS) \
        | ((z & BLOCK_MASK) << (2 * BLOCK_BITS))
    hashed = np.int64((np.uint64(block) * HASH_MULTIPLIER) >> np.uint64(shift))
    return (hashed << LOCAL_BITS) | local


@kernel
def first_cell_flags(ranges, slot, x, y, z):
    """Bits 0, 1, 2: cell (x, y, z) is the first cell of range ``slot`` on axis x, y, z."""
    return np.uint8(int(x == ranges[slot, 0, 0]) | (int(y == ranges[slot, 0, 1]) << 1)
                    | (int(z == ranges[slot, 0, 2]) << 2))


@kernel
def pairs_with_all_static(aabbs, a, n_static, out, count):
    """Compare dynamic box ``a`` with every static box; return (count, compared)."""
    for b in range(n_static):
        if aabbs_overlap(aabbs, a, b):
            count = emit(out, count, a, b, n_static)
    return count, n_static


@kernel
def pairs_with_all_dynamic(aabbs, a, n_static, n_total, is_big, out, count):
    """Compare big dynamic box ``a`` with every other dynamic box; return (count, compared).

    ``is_big[i]`` flags dynamic box ``n_static + i``: a pair of two big boxes is compared only
    from its smaller row so that it is reported once; small boxes are compared with big ones
    nowhere else.
    """
    compared = 0
    for b in range(n_static, n_total):
        if b == a or (b < a and is_big[b - n_static]):
            continue
        compared += 1
        if aabbs_overlap(aabbs, a, b):
            count = emit(out, count, a, b, n_static)
    return count, compared
