"""Octree ("Engine Algorithms"): a leaf-only octree, leaves created lazily, empty ones cooling.

Algorithm, as "Engine Algorithms" describes it. The root cube is cut ``depth`` times into octants,
but only the leaves exist ("leaf only"), and only those something touches: a leaf is created the
first time a box enters it, found again through a hash map keyed by its cell, and every box is
referenced from every leaf it touches. Each tick:

* a dynamic box whose AABB is still inside the leaves it is registered in skips re-insertion
  (the paper's AABB check, done on cell indices so that it agrees exactly with insertion);
  any other dynamic box leaves its old leaves and enters its new ones;
* a leaf emptied by its last dynamic box is kept for ``leaf_cooldown_ticks`` ticks (default
  15) and then dropped, so a box going back and forth over a border does not create and drop
  leaves every tick;
* the pairs are found leaf by leaf, within the leaves that hold dynamic boxes (or cool down):
  dynamic against dynamic, and dynamic against the leaf's static boxes. A pair sharing several
  leaves is reported once, in its first shared leaf (:mod:`~.cells`).

Static boxes are inserted once per build and never move; static-static pairs are never
formed. The tree is rebuilt (everything re-inserted, depth chosen again) only when the static
set changes, the body count outgrows its arrays, more than ``OUTSIDE_FRACTION`` of the
dynamic boxes have left the root cube since the last build, or all boxes have shrunk into a
quarter of its side. Boxes outside the root cube are clamped into its
border leaves: slower, never lost. The root cube covers the central ``ROOT_QUANTILE`` ..
``1 - ROOT_QUANTILE`` of the box centres, with ``ROOT_SLACK`` room to grow, so one body far
away does not stretch the tree over it.

Depth: ``octree.max_depth`` when not 0, else chosen at each build by :func:`size_depth`:
leaves about ``LEAF_SIDE_FACTOR`` mean AABB sides wide. The rule of "Discrete Collision
Algorithms", L = min(6, log2(n) - 4) (:func:`paper_depth`, available as
``Octree(settings, depth_rule='paper')``) was the starting point. Measured (CPU ms per tick of
the broad phase; depth chosen in brackets; the best fixed depth found by trying 2..7;
``python test/broadphase_bench.py --study octree``):

    scene, bodies          paper rule    size rule     best fixed depth
    uniform, 1,024         3.10 (6)      0.43 (4)      0.40 (4)
    clustered, 1,024       3.41 (6)      1.40 (4)      1.40 (4)
    seed scene, 1,024      2.89 (6)      0.50 (4, 5)   0.45 (4)
    uniform, 10,000        11.8 (6)      5.6 (5)       6.2 (5)
    clustered, 10,000      33.4 (6)      20.3 (5)      21.0 (5)
    seed scene, 10,000     46.5 (6)      16.6 (5)      18.0 (5)

The size rule is within noise of the best depth everywhere, the paper's rule 2-7x slower: the
best leaf follows the body size, and in a scene of constant density the root side grows as
n^(1/3), so the best depth grows a third as fast as log2(n).

Invariants: a leaf is in the map iff it holds a box or cools down; a dynamic box is in every
leaf of its registered cell range, which contains its current one; the active list holds
exactly the leaves that hold dynamic boxes or cool down. test_broadphase.py checks their
consequence, brute force's pairs, over hundreds of ticks of bodies coming, going and moving;
:meth:`Octree.validate` (for tests) checks them and the bookkeeping behind them directly.

When to use: as the paper's reference and where bodies stay in their leaves for many ticks
(slow motion, many static boxes). The hashed grid does the same job without a root cube or
per-body bookkeeping and is faster on every scene measured (doc/benchmarks.md).
"""
import math
from typing import NamedTuple

import numpy as np

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.broadphase import hash_map
from collision_node.pipeline.broadphase.cells import (
    ALL_FIRST, cell_key, cell_range, first_cell_flags, keeps_cells, make_lattice,
    MAX_CELLS_PER_BODY, mean_side_and_center, pairs_with_all_dynamic, pairs_with_all_static)
from collision_node.pipeline.broadphase.pair_buffer import emit, emit_if, PairBuffer
from collision_node.pipeline.broadphase.validation import (
    cell_counts, cell_of_key, cell_ranges, check, check_distinct, check_hash_map, loose_mask,
    range_holds)
from collision_node.pipeline.flat_views import copy_into
from collision_node.pipeline.obb import aabbs_overlap, overlap_across

NULL = -1  # no leaf, no entry
NO_COPIES = np.zeros((0, 2, 3))  # keeps_cells: the octree reads the boxes' own AABBs

# The depth rule of "Discrete Collision Algorithms": L = min(PAPER_MAX_DEPTH, log2(n) -
# PAPER_DEPTH_OFFSET).
PAPER_MAX_DEPTH = 6
PAPER_DEPTH_OFFSET = 4
# The size rule (the default, measured better: see the module docstring): leaves of about
# LEAF_SIDE_FACTOR mean AABB sides, like the grid's cells, at most MAX_DEPTH levels.
LEAF_SIDE_FACTOR = 1.5
MAX_DEPTH = 10

ROOT_QUANTILE = 0.01  # the root cube covers these quantiles of the box centres
ROOT_SLACK = 2.0      # root side / side of the boxes' cube at a build: room to fly out
OUTSIDE_FRACTION = 0.1  # rebuild when this many more dynamic boxes left the root than at build
SHRINK_RATIO = 4.0      # rebuild when all boxes fit in 1/4 of the root side
GROWTH = 1.5

# Columns of the leaf table.
LEAF_X, LEAF_Y, LEAF_Z = 0, 1, 2   # cell of the leaf
LEAF_HEAD = 3                      # first entry of its dynamic boxes, or NULL
LEAF_DYNAMIC = 4                   # number of dynamic boxes in it
LEAF_STATIC_START = 5              # its static boxes: static_members[start : start + count]
LEAF_STATIC_COUNT = 6
LEAF_EMPTY_SINCE = 7               # tick its last dynamic box left it, NULL while occupied
LEAF_ACTIVE_SLOT = 8               # its index in ``active``, NULL when not active
LEAF_FIELDS = 9
# Columns of the entry table: one entry per (dynamic box, leaf), in two linked lists.
ENTRY_BODY = 0     # dynamic index of the box
ENTRY_LEAF = 1
ENTRY_PREV = 2     # previous and next entry of the same leaf
ENTRY_NEXT = 3
ENTRY_BODY_NEXT = 4  # next entry of the same box
ENTRY_FIELDS = 5
# Columns of the body table, and a body's states.
BODY_FIRST_ENTRY = 0
BODY_STATE = 1
BODY_FIELDS = 2
OUTSIDE_TREE = 0  # not inserted (new, or gone)
IN_LEAVES = 1
BIG = 2           # too many leaves: compared with everything instead
# Counters.
FREE_LEAVES = 0     # number of free leaves on the free_leaves stack
FREE_ENTRIES = 1    # number of free entries on the free_entries stack
ACTIVE = 2          # length of the active list
DYNAMIC_COUNT = 3   # dynamic boxes the tree holds (those of the last tick)
BIG_DYNAMIC = 4     # valid rows in big_rows
BIG_STATIC = 5      # valid rows in static_big
LEAVES_CREATED = 6  # statistics since the last build
LEAVES_DROPPED = 7
REINSERTED = 8
STAYED = 9
INSERTED = 10
COUNTERS = 11


class OctreeState(NamedTuple):
    """The whole tree as flat arrays (see the column constants)."""

    map_keys: np.ndarray        # hash map cell key -> leaf
    map_leaves: np.ndarray
    leaves: np.ndarray          # (L, LEAF_FIELDS) int64
    free_leaves: np.ndarray     # (L,) stack of free leaves
    active: np.ndarray          # (L,) leaves holding dynamic boxes or cooling down
    entries: np.ndarray         # (E, ENTRY_FIELDS) int64
    free_entries: np.ndarray    # (E,) stack of free entries
    bodies: np.ndarray          # (D, BODY_FIELDS) int64
    body_range: np.ndarray      # (D, 2, 3) registered cell range of each dynamic box
    new_range: np.ndarray       # (D, 2, 3) this tick's cell range (scratch)
    moves: np.ndarray           # (D,) bool scratch: the box leaves its leaves this tick
    big_rows: np.ndarray        # (D,) rows of the big dynamic boxes
    members: np.ndarray         # (D,) scratch: rows of one leaf's dynamic boxes
    member_flags: np.ndarray    # (D,) uint8 scratch: their first-cell flags
    static_range: np.ndarray    # (S, 2, 3) cell range of each static box
    static_members: np.ndarray  # (Es,) static rows, leaf by leaf
    static_big: np.ndarray      # (S,) rows of the big static boxes
    counters: np.ndarray        # (COUNTERS,) int64


def new_state(leaves, entries, bodies, statics, static_entries):
    """Make an empty tree with room for the given numbers of leaves, entries, boxes."""
    map_size = 2
    while map_size < 2 * leaves:  # load at most 1/2
        map_size *= 2
    map_keys, map_leaves = hash_map.empty_map(map_size)
    return OctreeState(
        map_keys, map_leaves, np.zeros((leaves, LEAF_FIELDS), np.int64),
        np.zeros(leaves, np.int64), np.zeros(leaves, np.int64),
        np.zeros((entries, ENTRY_FIELDS), np.int64), np.zeros(entries, np.int64),
        np.zeros((bodies, BODY_FIELDS), np.int64), np.zeros((bodies, 2, 3), np.int64),
        np.zeros((bodies, 2, 3), np.int64), np.zeros(bodies, np.bool_),
        np.zeros(bodies, np.int64), np.zeros(bodies, np.int64), np.zeros(bodies, np.uint8),
        np.zeros((statics, 2, 3), np.int64), np.zeros(static_entries, np.int64),
        np.zeros(statics, np.int64), np.zeros(COUNTERS, np.int64))


def paper_depth(n_bodies, root_side, mean_side):
    """Return the depth rule of "Discrete Collision Algorithms": min(6, log2(n) - 4), >= 0."""
    return max(0, min(PAPER_MAX_DEPTH,
                      int(math.floor(math.log2(max(n_bodies, 1)))) - PAPER_DEPTH_OFFSET))


def size_depth(n_bodies, root_side, mean_side):
    """Return the depth whose leaves are closest to ``LEAF_SIDE_FACTOR`` mean AABB sides.

    The papers' rule grows with log2(n), but in a scene of constant density the root side
    grows as n^(1/3), so the best depth grows three times slower; and the rule ignores the
    body size, which is what sets how many leaves a body touches.
    """
    if not mean_side > 0.0:
        return 0
    depth = round(math.log2(max(root_side / (LEAF_SIDE_FACTOR * mean_side), 1.0)))
    return int(min(MAX_DEPTH, depth))


DEPTH_RULES = {'size': size_depth, 'paper': paper_depth}


class Octree:
    """Leaf-only octree over a root cube; see the module docstring."""

    name = 'octree'

    def __init__(self, settings, depth_rule='size'):
        self._max_depth = settings.octree_max_depth
        self._cooldown = settings.octree_leaf_cooldown_ticks
        self._depth_rule = DEPTH_RULES[depth_rule]
        self._buffer = PairBuffer()
        self._state = None      # None: build at the next tick
        self._lattice = None
        self._root_side = 0.0
        self._depth = 0
        self._outside_at_build = 0
        self._tick = 0
        self.stats = {'depth': 0, 'builds': 0}

    def set_static(self, boxes, n_static):
        self._state = None  # static boxes are inserted once, at the next build

    def move_static(self, boxes, rows):
        """Keep the static boxes that stayed in their leaves (the pair tests read the boxes)."""
        kept = np.ones(len(rows), np.bool_)
        if self._state is not None:  # else they are inserted as they are at the next build
            keeps_cells(self._lattice, boxes.aabbs, rows, self._state.static_range,
                        np.arange(len(self._state.static_range)), NO_COPIES, kept)
        return kept

    def find_pairs(self, boxes, n_static, n_dynamic, moved=None):
        aabbs = boxes.aabbs
        self._tick += 1
        if self._needs_build(aabbs, n_static, n_dynamic):
            self._build(aabbs, n_static, n_dynamic, 0)
        else:
            needed = _update(self._state, self._lattice, aabbs, n_static, n_dynamic,
                             self._tick, self._cooldown)
            if needed:  # out of free leaves or entries: rebuild with room for that many
                self._build(aabbs, n_static, n_dynamic, needed)
        state = self._state
        pairs, compared = self._buffer.fill(_leaf_pairs, state, aabbs, n_static,
                                            n_static + n_dynamic)
        counters = state.counters
        self.stats.update(
            depth=self._depth, leaves=int(len(state.leaves) - counters[FREE_LEAVES]),
            active_leaves=int(counters[ACTIVE]), leaves_created=int(counters[LEAVES_CREATED]),
            leaves_dropped=int(counters[LEAVES_DROPPED]), reinserted=int(counters[REINSERTED]),
            stayed=int(counters[STAYED]), inserted=int(counters[INSERTED]),
            big_dynamic=int(counters[BIG_DYNAMIC]))
        return pairs, compared

    def validate(self, boxes, n_static, n_dynamic, loose=None):
        """Check the whole tree against ``boxes``; raise InvalidStructure if wrong. For testing.

        See :func:`validate_state`. Between set_static and the next tick there is no tree.
        """
        loose = loose_mask(loose, n_static)
        if self._state is None:
            return  # the next tick inserts every box as it is then
        cells = 1 << self._depth
        check(self._lattice.low == 0 and self._lattice.high == cells - 1,
              'lattice clamps to cells %d..%d, the depth %d has 0..%d', self._lattice.low,
              self._lattice.high, self._depth, cells - 1)
        validate_state(self._state, self._lattice, boxes.aabbs, n_static, n_dynamic, loose,
                       self._tick, self._cooldown)

    def _needs_build(self, aabbs, n_static, n_dynamic):
        if self._state is None or len(self._state.bodies) < n_dynamic:
            return True
        outside, extent = _outside_and_extent(self._lattice, aabbs, n_static,
                                              n_static + n_dynamic, self._root_side)
        return outside > self._outside_at_build + OUTSIDE_FRACTION * n_dynamic \
            or SHRINK_RATIO * extent < self._root_side

    def _build(self, aabbs, n_static, n_dynamic, more):
        """Re-insert everything into a new tree, with room for ``more`` leaves and entries."""
        n_total = n_static + n_dynamic
        centers = 0.5 * (aabbs[:n_total, 0] + aabbs[:n_total, 1])
        low, high = np.quantile(centers, [ROOT_QUANTILE, 1.0 - ROOT_QUANTILE], axis=0)
        mean_side = mean_side_and_center(aabbs, 0, n_total)[0]
        side = ROOT_SLACK * max(np.max(high - low), 2.0 * mean_side)
        if not side > 0.0:
            side = 1.0  # all boxes are one point: any root holds them
        self._depth = self._max_depth or self._depth_rule(n_total, side, mean_side)
        cells = 1 << self._depth
        self._root_side = side
        self._lattice = make_lattice(0.5 * (low + high) - 0.5 * side, side / cells, 0, cells - 1)
        static_entries = _count_entries(self._lattice, aabbs, 0, n_static)
        dynamic_entries = _count_entries(self._lattice, aabbs, n_static, n_total)
        entries = int(GROWTH * (dynamic_entries + more)) + 64
        leaves = int(GROWTH * (static_entries + dynamic_entries + more)) + 64
        self._state = new_state(leaves, entries, int(GROWTH * n_dynamic) + 1, max(n_static, 1),
                                max(static_entries, 1))
        _build(self._state, self._lattice, aabbs, n_static, n_dynamic, self._tick)
        self._outside_at_build = _outside_and_extent(self._lattice, aabbs, n_static, n_total,
                                                     side)[0]
        self.stats['builds'] += 1


@kernel
def _count_entries(lattice, aabbs, first, stop):
    """Leaf references the boxes ``first`` .. ``stop`` need (big boxes need none)."""
    scratch = np.empty((1, 2, 3), np.int64)
    entries = 0
    for row in range(first, stop):
        cells = cell_range(lattice, aabbs, row, scratch, 0)
        if cells <= MAX_CELLS_PER_BODY:
            entries += cells
    return entries


@kernel
def _outside_and_extent(lattice, aabbs, n_static, n_total, root_side):
    """Dynamic boxes not inside the root cube, and the extent of all boxes' AABBs."""
    origin = (lattice.origin_x, lattice.origin_y, lattice.origin_z)
    outside = 0
    low = np.full(3, np.inf)
    high = np.full(3, -np.inf)
    for row in range(n_total):
        out = False
        for k in range(3):
            low[k] = min(low[k], aabbs[row, 0, k])
            high[k] = max(high[k], aabbs[row, 1, k])
            out |= aabbs[row, 0, k] < origin[k] or aabbs[row, 1, k] > origin[k] + root_side
        outside += out and row >= n_static
    return outside, np.max(high - low) if n_total else 0.0


@kernel
def _build(state, lattice, aabbs, n_static, n_dynamic, tick):
    """Fill a new tree: static boxes once (CSR per leaf), then the dynamic boxes."""
    leaves, free_leaves, counters = state.leaves, state.free_leaves, state.counters
    map_keys, map_leaves = state.map_keys, state.map_leaves
    static_range, static_members, static_big = (state.static_range, state.static_members,
                                                state.static_big)
    n_leaves = len(leaves)
    for i in range(n_leaves):  # leaves are handed out from the top: 0, 1, 2, ...
        free_leaves[i] = n_leaves - 1 - i
    for i in range(len(state.free_entries)):
        state.free_entries[i] = len(state.free_entries) - 1 - i
    counters[:] = 0
    counters[FREE_LEAVES] = n_leaves
    counters[FREE_ENTRIES] = len(state.free_entries)
    state.bodies[:, BODY_STATE] = OUTSIDE_TREE
    state.bodies[:, BODY_FIRST_ENTRY] = NULL
    # Static boxes: count per leaf, prefix sums, fill. Static leaves are created first, so
    # they are leaves 0 .. k-1 and their CSR ranges are laid out in that order.
    big = 0
    for s in range(n_static):
        if cell_range(lattice, aabbs, s, static_range, s) > MAX_CELLS_PER_BODY:
            static_big[big] = s
            big += 1
            continue
        for x in range(static_range[s, 0, 0], static_range[s, 1, 0] + 1):
            for y in range(static_range[s, 0, 1], static_range[s, 1, 1] + 1):
                for z in range(static_range[s, 0, 2], static_range[s, 1, 2] + 1):
                    leaf = _find_or_create_leaf(state, x, y, z)
                    leaves[leaf, LEAF_STATIC_COUNT] += 1
    counters[BIG_STATIC] = big
    start = 0
    for leaf in range(n_leaves - counters[FREE_LEAVES]):
        leaves[leaf, LEAF_STATIC_START] = start
        start += leaves[leaf, LEAF_STATIC_COUNT]
        leaves[leaf, LEAF_STATIC_COUNT] = 0  # counted up again while filling
    for s in range(n_static):
        if _cell_count(static_range, s) > MAX_CELLS_PER_BODY:
            continue
        for x in range(static_range[s, 0, 0], static_range[s, 1, 0] + 1):
            for y in range(static_range[s, 0, 1], static_range[s, 1, 1] + 1):
                for z in range(static_range[s, 0, 2], static_range[s, 1, 2] + 1):
                    leaf = hash_map.find(map_keys, map_leaves, cell_key(x, y, z))
                    static_members[leaves[leaf, LEAF_STATIC_START]
                                   + leaves[leaf, LEAF_STATIC_COUNT]] = s
                    leaves[leaf, LEAF_STATIC_COUNT] += 1
    counters[LEAVES_CREATED] = 0  # count the dynamic leaves only
    _update(state, lattice, aabbs, n_static, n_dynamic, tick, 0)


@kernel
def _update(state, lattice, aabbs, n_static, n_dynamic, tick, cooldown):
    """Move the dynamic boxes that left their leaves, drop cooled leaves; return 0.

    When the free leaves or entries might not suffice, nothing is changed and the number of
    leaf references to insert is returned instead, for a rebuild with more room.
    """
    counters, bodies, moves = state.counters, state.bodies, state.moves
    body_range, new_range, big_rows = state.body_range, state.new_range, state.big_rows
    n_before = counters[DYNAMIC_COUNT]
    needed = 0
    freed = 0
    for i in range(n_dynamic):  # plan: who stays (the paper's AABB check), who moves
        cells = cell_range(lattice, aabbs, n_static + i, new_range, i)
        in_leaves = i < n_before and bodies[i, BODY_STATE] == IN_LEAVES
        moves[i] = not (in_leaves and _contains(body_range, new_range, i))
        if moves[i] and in_leaves:
            freed += _cell_count(body_range, i)
        if moves[i] and cells <= MAX_CELLS_PER_BODY:
            needed += cells
    for i in range(n_dynamic, n_before):
        if bodies[i, BODY_STATE] == IN_LEAVES:
            freed += _cell_count(body_range, i)
    # Leaves emptied now cool down before they are freed: they cannot be counted on.
    if needed > counters[FREE_ENTRIES] + freed or needed > counters[FREE_LEAVES]:
        return needed
    for i in range(n_dynamic, n_before):  # bodies that are gone
        if bodies[i, BODY_STATE] == IN_LEAVES:
            _remove_body(state, i, tick)
        bodies[i, BODY_STATE] = OUTSIDE_TREE
    for i in range(n_dynamic):  # all removals first, so their entries can be reused
        if not moves[i]:
            counters[STAYED] += 1
        elif i < n_before and bodies[i, BODY_STATE] == IN_LEAVES:
            _remove_body(state, i, tick)
            counters[REINSERTED] += 1
        else:
            counters[INSERTED] += 1
    big = 0
    for i in range(n_dynamic):
        if moves[i]:
            copy_into(body_range[i], new_range[i])
            if _cell_count(body_range, i) > MAX_CELLS_PER_BODY:
                bodies[i, BODY_STATE] = BIG
            else:
                bodies[i, BODY_STATE] = IN_LEAVES
                _insert_body(state, i)
        if bodies[i, BODY_STATE] == BIG:
            big_rows[big] = n_static + i
            big += 1
    counters[BIG_DYNAMIC] = big
    counters[DYNAMIC_COUNT] = n_dynamic
    _drop_cooled_leaves(state, tick, cooldown)
    return 0


@kernel
def _contains(outer, inner, i):
    """Tell whether cell range ``inner[i]`` lies within ``outer[i]`` (stay-in-leaf test)."""
    for k in range(3):
        if inner[i, 0, k] < outer[i, 0, k] or inner[i, 1, k] > outer[i, 1, k]:
            return False
    return True


@kernel
def _cell_count(ranges, i):
    cells = 1
    for k in range(3):
        cells *= min(ranges[i, 1, k] - ranges[i, 0, k] + 1, MAX_CELLS_PER_BODY + 1)
    return cells


@kernel
def _find_or_create_leaf(state, x, y, z):
    """Return the leaf of cell (x, y, z), made (and mapped) if there is none."""
    leaves, free_leaves, counters = state.leaves, state.free_leaves, state.counters
    map_keys, map_leaves = state.map_keys, state.map_leaves
    key = cell_key(x, y, z)
    leaf = hash_map.find(map_keys, map_leaves, key)
    if leaf != NULL:
        return leaf
    counters[FREE_LEAVES] -= 1
    leaf = free_leaves[counters[FREE_LEAVES]]
    leaves[leaf, LEAF_X] = x
    leaves[leaf, LEAF_Y] = y
    leaves[leaf, LEAF_Z] = z
    leaves[leaf, LEAF_HEAD] = NULL
    leaves[leaf, LEAF_DYNAMIC] = 0
    leaves[leaf, LEAF_STATIC_START] = 0
    leaves[leaf, LEAF_STATIC_COUNT] = 0
    leaves[leaf, LEAF_EMPTY_SINCE] = NULL
    leaves[leaf, LEAF_ACTIVE_SLOT] = NULL
    hash_map.insert(map_keys, map_leaves, key, leaf)
    counters[LEAVES_CREATED] += 1
    return leaf


@kernel
def _insert_body(state, i):
    """Enter dynamic box ``i`` in every leaf of its registered range."""
    leaves, active, counters = state.leaves, state.active, state.counters
    entries, free_entries, bodies = state.entries, state.free_entries, state.bodies
    body_range = state.body_range
    bodies[i, BODY_FIRST_ENTRY] = NULL
    for x in range(body_range[i, 0, 0], body_range[i, 1, 0] + 1):
        for y in range(body_range[i, 0, 1], body_range[i, 1, 1] + 1):
            for z in range(body_range[i, 0, 2], body_range[i, 1, 2] + 1):
                leaf = _find_or_create_leaf(state, x, y, z)
                counters[FREE_ENTRIES] -= 1
                e = free_entries[counters[FREE_ENTRIES]]
                entries[e, ENTRY_BODY] = i
                entries[e, ENTRY_LEAF] = leaf
                entries[e, ENTRY_PREV] = NULL
                entries[e, ENTRY_NEXT] = leaves[leaf, LEAF_HEAD]
                if leaves[leaf, LEAF_HEAD] != NULL:
                    entries[leaves[leaf, LEAF_HEAD], ENTRY_PREV] = e
                leaves[leaf, LEAF_HEAD] = e
                entries[e, ENTRY_BODY_NEXT] = bodies[i, BODY_FIRST_ENTRY]
                bodies[i, BODY_FIRST_ENTRY] = e
                leaves[leaf, LEAF_DYNAMIC] += 1
                leaves[leaf, LEAF_EMPTY_SINCE] = NULL
                if leaves[leaf, LEAF_ACTIVE_SLOT] == NULL:
                    leaves[leaf, LEAF_ACTIVE_SLOT] = counters[ACTIVE]
                    active[counters[ACTIVE]] = leaf
                    counters[ACTIVE] += 1


@kernel
def _remove_body(state, i, tick):
    """Unlink dynamic box ``i`` from all its leaves; a leaf it empties starts cooling."""
    leaves, entries, free_entries, bodies, counters = (state.leaves, state.entries,
                                                       state.free_entries, state.bodies,
                                                       state.counters)
    e = bodies[i, BODY_FIRST_ENTRY]
    while e != NULL:
        leaf = entries[e, ENTRY_LEAF]
        prev = entries[e, ENTRY_PREV]
        following = entries[e, ENTRY_NEXT]
        if prev == NULL:
            leaves[leaf, LEAF_HEAD] = following
        else:
            entries[prev, ENTRY_NEXT] = following
        if following != NULL:
            entries[following, ENTRY_PREV] = prev
        leaves[leaf, LEAF_DYNAMIC] -= 1
        if leaves[leaf, LEAF_DYNAMIC] == 0:
            leaves[leaf, LEAF_EMPTY_SINCE] = tick
        free_entries[counters[FREE_ENTRIES]] = e
        counters[FREE_ENTRIES] += 1
        e = entries[e, ENTRY_BODY_NEXT]
    bodies[i, BODY_FIRST_ENTRY] = NULL


@kernel
def _drop_cooled_leaves(state, tick, cooldown):
    """Take leaves empty for ``cooldown`` ticks off the active list; drop non-static ones."""
    leaves, free_leaves, active, counters = (state.leaves, state.free_leaves, state.active,
                                             state.counters)
    map_keys, map_leaves = state.map_keys, state.map_leaves
    k = 0
    while k < counters[ACTIVE]:
        leaf = active[k]
        if leaves[leaf, LEAF_DYNAMIC] > 0 or tick - leaves[leaf, LEAF_EMPTY_SINCE] < cooldown:
            k += 1
            continue
        last = active[counters[ACTIVE] - 1]  # swap-remove: the last leaf takes slot k
        active[k] = last
        leaves[last, LEAF_ACTIVE_SLOT] = k
        counters[ACTIVE] -= 1
        leaves[leaf, LEAF_ACTIVE_SLOT] = NULL
        if leaves[leaf, LEAF_STATIC_COUNT] == 0:  # leaves of static boxes stay for good
            hash_map.remove(map_keys, map_leaves,
                            cell_key(leaves[leaf, LEAF_X], leaves[leaf, LEAF_Y],
                                     leaves[leaf, LEAF_Z]))
            free_leaves[counters[FREE_LEAVES]] = leaf
            counters[FREE_LEAVES] += 1
            counters[LEAVES_DROPPED] += 1


@kernel
def _leaf_pairs(state, aabbs, n_static, n_total, out):
    """Pairs leaf by leaf, each in its first shared leaf; big boxes against everything."""
    leaves, active, entries, counters = state.leaves, state.active, state.entries, \
        state.counters
    bodies, body_range, members, member_flags = (state.bodies, state.body_range,
                                                 state.members, state.member_flags)
    static_range, static_members = state.static_range, state.static_members
    count = 0
    compared = 0
    for k in range(counters[ACTIVE]):
        leaf = active[k]
        if leaves[leaf, LEAF_DYNAMIC] == 0:
            continue  # cooling down: one loop cycle, as the paper says
        x, y, z = leaves[leaf, LEAF_X], leaves[leaf, LEAF_Y], leaves[leaf, LEAF_Z]
        m = 0
        e = leaves[leaf, LEAF_HEAD]
        while e != NULL:
            body = entries[e, ENTRY_BODY]
            members[m] = n_static + body
            member_flags[m] = first_cell_flags(body_range, body, x, y, z)
            m += 1
            e = entries[e, ENTRY_NEXT]
        for i in range(m):
            a = members[i]
            for j in range(i + 1, m):
                owned = (member_flags[i] | member_flags[j]) == ALL_FIRST
                compared += owned
                b = members[j]
                count = emit_if(out, count, owned & overlap_across(aabbs, a, aabbs, b),
                                min(a, b), max(a, b))
        start = leaves[leaf, LEAF_STATIC_START]
        for t in range(start, start + leaves[leaf, LEAF_STATIC_COUNT]):
            s = static_members[t]
            flags = first_cell_flags(static_range, s, x, y, z)
            for i in range(m):
                owned = (member_flags[i] | flags) == ALL_FIRST
                compared += owned
                count = emit_if(out, count, owned & overlap_across(aabbs, members[i], aabbs, s),
                                members[i], s)
    is_big = bodies[:, BODY_STATE] == BIG if counters[BIG_DYNAMIC] else bodies[:0, 0] == BIG
    for i in range(counters[BIG_DYNAMIC]):
        a = state.big_rows[i]
        count, tested = pairs_with_all_dynamic(aabbs, a, n_static, n_total, is_big, out,
                                               count)
        compared += tested
        count, tested = pairs_with_all_static(aabbs, a, n_static, out, count)
        compared += tested
    for i in range(counters[BIG_STATIC]):
        s = state.static_big[i]
        for a in range(n_static, n_total):
            if bodies[a - n_static, BODY_STATE] != BIG:
                compared += 1
                if aabbs_overlap(aabbs, a, s):
                    count = emit(out, count, a, s, n_static)
    return count, compared


def validate_state(state, lattice, aabbs, n_static, n_dynamic, loose, tick, cooldown):
    """Check every invariant of the module docstring; raise InvalidStructure at the first break.

    ``aabbs``: static rows as of the last build or move_static, dynamic rows as of the last
    tick (the tree's ``n_dynamic`` boxes); ``loose`` (bool per static row) marks the static
    boxes move_static did not keep, which the tree still holds where they were. ``tick`` is
    that of the last update, ``cooldown`` the leaves' cooling time in ticks.
    """
    leaves, entries, bodies, counters = state.leaves, state.entries, state.bodies, \
        state.counters
    n_leaves, n_entries = len(leaves), len(entries)
    check(0 <= counters[FREE_LEAVES] <= n_leaves and 0 <= counters[FREE_ENTRIES] <= n_entries
          and 0 <= counters[ACTIVE] <= n_leaves, 'counters out of range: %s', counters.tolist())
    check(counters[DYNAMIC_COUNT] == n_dynamic <= len(bodies),
          'the tree holds %d dynamic boxes (room for %d), the scene has %d',
          counters[DYNAMIC_COUNT], len(bodies), n_dynamic)
    check(len(state.static_range) == max(n_static, 1),
          'the tree was built for %d static boxes, the scene has %d', len(state.static_range),
          n_static)
    used = _validate_leaves(state, lattice, tick, cooldown)
    _validate_static(state, lattice, aabbs, n_static, loose, used)
    _validate_dynamic(state, lattice, aabbs, n_static, n_dynamic, used)


def _validate_leaves(state, lattice, tick, cooldown):
    """Check that free stack, map and active list agree; return the leaves in use (bool each)."""
    leaves, counters, active = state.leaves, state.counters, state.active
    free = state.free_leaves[:counters[FREE_LEAVES]]
    check(np.all((free >= 0) & (free < len(leaves))), 'free leaf stack holds a non-leaf')
    check_distinct(free, 'free leaf stack')
    used = np.ones(len(leaves), np.bool_)
    used[free] = False
    in_map = check_hash_map(state.map_keys, state.map_leaves, 'leaf map')
    check(len(state.map_keys) >= 2 * len(leaves), 'leaf map of %d slots for %d leaves: load '
          'above 1/2', len(state.map_keys), len(leaves))
    mapped, in_use = set(in_map.values()), set(np.flatnonzero(used).tolist())
    check(mapped == in_use, 'leaf map and free stack disagree: leaves %s in use but not in the '
          'map, leaves %s in the map but free', sorted(in_use - mapped)[:10],
          sorted(mapped - in_use)[:10])
    for key, leaf in in_map.items():
        cell = _cell(leaves, leaf)
        check(cell_of_key(key) == cell, 'leaf %d of cell %s is mapped from cell %s', leaf, cell,
              cell_of_key(key))
        check(all(lattice.low <= c <= lattice.high for c in cell),
              'leaf %d of cell %s lies outside the lattice %d..%d', leaf, cell, lattice.low,
              lattice.high)
    listed = active[:counters[ACTIVE]]
    check(np.all(used[listed]), 'active list holds a free leaf')
    check_distinct(listed, 'active list')
    slots = leaves[:, LEAF_ACTIVE_SLOT]
    for k, leaf in enumerate(listed):
        check(slots[leaf] == k, 'leaf %d is at slot %d of the active list, it says %d', leaf, k,
              slots[leaf])
    check(np.count_nonzero(used & (slots != NULL)) == len(listed),
          'leaves with an active slot: %d, on the active list: %d',
          np.count_nonzero(used & (slots != NULL)), len(listed))
    for leaf in np.flatnonzero(used):
        dynamic, since = leaves[leaf, LEAF_DYNAMIC], leaves[leaf, LEAF_EMPTY_SINCE]
        is_active = slots[leaf] != NULL
        check(dynamic > 0 or leaves[leaf, LEAF_STATIC_COUNT] > 0 or is_active,
              'leaf %d holds nothing and is not cooling down, yet is not dropped', leaf)
        if dynamic > 0:
            check(is_active and since == NULL, 'leaf %d holds %d dynamic boxes but is %s',
                  leaf, dynamic, 'empty since tick %d' % since if is_active else 'not active')
        elif is_active:
            check(since != NULL and 0 <= tick - since < cooldown,
                  'leaf %d cools down since tick %d: out of the cooldown (%d ticks at tick %d)',
                  leaf, since, cooldown, tick)
    return used


def _cell(leaves, leaf):
    return tuple(int(c) for c in leaves[leaf, LEAF_X:LEAF_Z + 1])


def _validate_static(state, lattice, aabbs, n_static, loose, used):
    """Check that each small static box is in exactly the leaves of its range, big ones listed."""
    leaves, static_range, counters = state.leaves, state.static_range[:n_static], \
        state.counters
    kept = np.flatnonzero(~loose)
    now = cell_ranges(lattice, aabbs, kept)
    stale = np.flatnonzero(np.any(now != static_range[kept], axis=(1, 2)))
    check(not len(stale), 'static box %d is held in cells %s, its box now covers %s (moved '
          'without move_static, or kept by it though it left its cells)',
          kept[stale[0]] if len(stale) else -1,
          static_range[kept[stale[0]]].tolist() if len(stale) else None,
          now[stale[0]].tolist() if len(stale) else None)
    counts = cell_counts(static_range)
    big = counts > MAX_CELLS_PER_BODY
    listed = state.static_big[:counters[BIG_STATIC]]
    check(listed.tolist() == np.flatnonzero(big).tolist(),
          'big static list %s, static boxes over %d cells %s', listed.tolist()[:20],
          MAX_CELLS_PER_BODY, np.flatnonzero(big)[:20].tolist())
    seen = np.zeros(n_static, np.int64)
    spans = []
    for leaf in np.flatnonzero(used & (leaves[:, LEAF_STATIC_COUNT] != 0)):
        start, count = leaves[leaf, LEAF_STATIC_START], leaves[leaf, LEAF_STATIC_COUNT]
        check(count > 0 and start >= 0 and start + count <= len(state.static_members),
              'leaf %d: static boxes [%d, %d) outside the member array (%d)', leaf, start,
              start + count, len(state.static_members))
        spans.append((start, start + count))
        members = state.static_members[start:start + count]
        check(np.all((members >= 0) & (members < n_static)),
              'leaf %d lists static rows %s, the scene has %d', leaf, members.tolist(), n_static)
        check_distinct(members, 'static boxes of leaf %d' % leaf)
        cell = _cell(leaves, leaf)
        for s in members:
            check(not big[s] and range_holds(static_range, s, cell),
                  'leaf %d of cell %s lists static box %d of cells %s%s', leaf, cell, s,
                  static_range[s].tolist(), ' (big)' if big[s] else '')
            seen[s] += 1
    spans.sort()
    for (_, end), (start, _) in zip(spans, spans[1:]):
        check(end <= start, 'static member ranges of two leaves overlap at %d', start)
    small = ~big
    wrong = np.flatnonzero(seen[small] != counts[small])
    check(not len(wrong), 'static box %d is in %d leaves, its range has %d cells',
          np.flatnonzero(small)[wrong[0]] if len(wrong) else -1,
          seen[small][wrong[0]] if len(wrong) else 0, counts[small][wrong[0]] if len(wrong) else 0)


def _validate_dynamic(state, lattice, aabbs, n_static, n_dynamic, used):
    """Check that each dynamic box is in exactly the leaves of its range, which holds its AABB."""
    leaves, entries, bodies, body_range = state.leaves, state.entries, state.bodies, \
        state.body_range
    counters = state.counters
    n_entries = len(entries)
    free = state.free_entries[:counters[FREE_ENTRIES]]
    check(np.all((free >= 0) & (free < n_entries)), 'free entry stack holds a non-entry')
    check_distinct(free, 'free entry stack')
    owner = np.full(n_entries, NULL, np.int64)  # leaf whose list holds the entry
    owner[free] = -2
    for leaf in np.flatnonzero(used):
        e, previous, length = leaves[leaf, LEAF_HEAD], NULL, 0
        while e != NULL:
            check(0 <= e < n_entries and owner[e] == NULL,
                  'leaf %d lists entry %d, which is free, invalid or in another list', leaf, e)
            check(entries[e, ENTRY_LEAF] == leaf and entries[e, ENTRY_PREV] == previous,
                  'entry %d in the list of leaf %d names leaf %d and previous %d, not %d', e,
                  leaf, entries[e, ENTRY_LEAF], entries[e, ENTRY_PREV], previous)
            owner[e] = leaf
            previous, e, length = e, entries[e, ENTRY_NEXT], length + 1
        check(length == leaves[leaf, LEAF_DYNAMIC], 'leaf %d lists %d dynamic boxes, counts %d',
              leaf, length, leaves[leaf, LEAF_DYNAMIC])
    orphans = np.flatnonzero(owner == NULL)
    check(not len(orphans), 'entry %d is neither free nor in a leaf', orphans[0]
          if len(orphans) else -1)
    states = bodies[:, BODY_STATE]
    gone = np.flatnonzero((states[n_dynamic:] != OUTSIDE_TREE)
                          | (bodies[n_dynamic:, BODY_FIRST_ENTRY] != NULL))
    check(not len(gone), 'dynamic box %d is gone but still in the tree',
          n_dynamic + gone[0] if len(gone) else -1)
    now = cell_ranges(lattice, aabbs, np.arange(n_static, n_static + n_dynamic))
    in_body_list = np.zeros(n_entries, np.bool_)
    for i in range(n_dynamic):
        registered = body_range[i]
        if states[i] == BIG:
            check(bodies[i, BODY_FIRST_ENTRY] == NULL and np.array_equal(registered, now[i])
                  and cell_counts(registered[None])[0] > MAX_CELLS_PER_BODY,
                  'big dynamic box %d: range %s, box now in %s, first entry %d', i,
                  registered.tolist(), now[i].tolist(), bodies[i, BODY_FIRST_ENTRY])
            continue
        check(states[i] == IN_LEAVES, 'dynamic box %d is not in the tree (state %d)', i,
              states[i])
        check(np.all(registered[0] <= now[i, 0]) and np.all(now[i, 1] <= registered[1]),
              'dynamic box %d is registered in cells %s, its box now covers %s', i,
              registered.tolist(), now[i].tolist())
        cells = cell_counts(registered[None])[0]
        check(cells <= MAX_CELLS_PER_BODY, 'dynamic box %d in leaves spans %d cells', i, cells)
        e, found = bodies[i, BODY_FIRST_ENTRY], set()
        while e != NULL and len(found) <= cells:
            check(0 <= e < n_entries and owner[e] >= 0 and not in_body_list[e]
                  and entries[e, ENTRY_BODY] == i,
                  'dynamic box %d lists entry %d, which is free, invalid or not its own', i, e)
            in_body_list[e] = True
            cell = _cell(leaves, entries[e, ENTRY_LEAF])
            check(range_holds(body_range, i, cell) and cell not in found,
                  'dynamic box %d (cells %s) is in the leaf of cell %s%s', i,
                  registered.tolist(), cell, ' twice' if cell in found else '')
            found.add(cell)
            e = entries[e, ENTRY_BODY_NEXT]
        check(len(found) == cells, 'dynamic box %d is in %d leaves, its range has %d cells', i,
              len(found), cells)
    strays = np.flatnonzero((owner >= 0) & ~in_body_list)
    check(not len(strays), "entry %d (box %d) is in a leaf but not in its box's list",
          strays[0] if len(strays) else -1, entries[strays[0], ENTRY_BODY] if len(strays) else -1)
    big_rows = state.big_rows[:counters[BIG_DYNAMIC]]
    expected = n_static + np.flatnonzero(states[:n_dynamic] == BIG)
    check(big_rows.tolist() == expected.tolist(), 'big dynamic rows %s, big boxes at rows %s',
          big_rows.tolist()[:20], expected.tolist()[:20])
