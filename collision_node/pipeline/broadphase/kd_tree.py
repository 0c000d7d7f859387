"""k-d tree ("Discrete Collision Algorithms"): median splits on the widest axis, node AABBs.

Algorithm. The boxes are put in an order (``perm``) in which every node of an implicit binary
tree owns a contiguous range: the root owns all, node k's children 2k+1 and 2k+2 own the two
halves after its range is partitioned at the median of the box centres along the axis where
they spread most (quickselect, O(n) per level, O(n log n) in all). A node with at most
``LEAF_SIZE`` boxes is a leaf. Every node stores the AABB of its boxes, so a box straddling a
split plane is stored once and never duplicated; this is the k-d tree of the paper with
bounding intervals instead of cutting planes, which is what makes refitting possible.

A query walks the tree with a fixed-size stack, skipping nodes whose AABB misses the query
box. Dynamic pairs: box ``perm[p]`` queries the dynamic tree only for positions after ``p``,
so each pair is met once and whole subtrees at earlier positions are skipped. Static pairs:
the static tree is built once per static set and only queried, by the dynamic boxes in
``perm`` order (neighbours after each other, so the nodes they visit stay in cache).

Rebuild or refit. Refitting keeps ``perm`` and recomputes the node AABBs bottom-up (O(n));
rebuilding partitions again (O(n log n)). Refitting degrades as boxes move relative to each
other: node boxes grow and overlap. So the tree refits every tick and rebuilds when its total
node surface area, relative to the root's, has grown by ``REBUILD_AREA_RATIO`` since the last
build (the surface area is the expected cost of a random query, the SAH idea). Measured here
(CPU ms per tick of the broad phase, ``scenes`` of the benchmark;
``python test/broadphase_bench.py --study kd_tree``):

    scene (ticks measured)                   rebuild   refit only   refit, rebuild at 1.2
    seed scene, 1,024 bodies (300 at 60 Hz)    0.34       0.24        0.24 (1 build)
    uniform, 10,000 (100 at 30 Hz)             4.33       4.47        3.70 (4 builds)
    clustered, 10,000 (100 at 30 Hz)           8.66      12.4         7.9  (5 builds)

Rebuilding every tick costs a partition per tick for nothing while the tree is still good;
refitting alone lets the tree decay (clustered: 50 % more pairs compared after 100 ticks);
refit-then-rebuild-when-worse is at or below the better of the two everywhere.

:meth:`KdTreePhase.validate` (for tests) checks both trees node by node (:func:`validate_tree`).

When to use: scenes of mixed sizes where no cell size suits all boxes, and static scenes with
few moving bodies (the static tree is built once). The grid is faster on uniform sizes.
"""
from typing import NamedTuple

import numpy as np

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.broadphase.pair_buffer import emit_if, PairBuffer
from collision_node.pipeline.broadphase.validation import (
    check, check_contains, check_permutation, loose_mask)
from collision_node.pipeline.obb import overlap_across

LEAF_SIZE = 4           # boxes per leaf: fewer means deeper trees, more means more pair tests
REBUILD_AREA_RATIO = 1.2  # rebuild when the refitted tree's relative area grew this much
STACK_SIZE = 128        # depth of a balanced tree over < 2**60 boxes, twice over


class KdTree(NamedTuple):
    """An implicit median-split tree over rows ``perm`` (see the module docstring)."""

    perm: np.ndarray        # (n,) rows, in tree order
    keys: np.ndarray        # (n,) scratch: split coordinate of perm[i] while building
    node_start: np.ndarray  # (M,) first position of each node (nodes that exist)
    node_end: np.ndarray    # (M,) one past its last position; 0 for nodes that do not exist
    bounds: np.ndarray      # (M, 2, 3) AABB of each node's boxes
    area: np.ndarray        # (1,) total node surface area / root surface area (after refit)


def tree_for(rows):
    """Make an unbuilt tree over ``rows`` (int64 array)."""
    n = len(rows)
    nodes = 1
    while nodes * LEAF_SIZE < n:  # leaves of a balanced tree, rounded up to a power of two
        nodes *= 2
    nodes = 2 * nodes - 1
    return KdTree(np.array(rows, np.int64), np.zeros(n), np.zeros(nodes, np.int64),
                  np.zeros(nodes, np.int64), np.zeros((nodes, 2, 3)), np.zeros(1))


class KdTreePhase:
    """Dynamic tree refitted every tick (rebuilt when it degrades), static tree built once."""

    name = 'kd_tree'

    def __init__(self, settings=None, rebuild_ratio=REBUILD_AREA_RATIO):
        self._rebuild_ratio = rebuild_ratio  # <= 1: rebuild every tick; inf: refit only
        self._buffer = PairBuffer()
        self._static = None
        self._dynamic = None
        self._dynamic_of = None  # (n_static, n_dynamic) the dynamic tree was made for
        self._built_area = 0.0
        self._static_built_area = 0.0
        self._stack = np.zeros(STACK_SIZE, np.int64)
        self.stats = {'builds': 0, 'refits': 0}

    def set_static(self, boxes, n_static):
        self._static = tree_for(np.arange(n_static))
        build(self._static, boxes.aabbs)
        self._static_built_area = self._static.area[0]

    def move_static(self, boxes, rows):
        """Refit the static tree to the moved boxes (O(S)); rebuild it once it degraded."""
        refit(self._static, boxes.aabbs)
        if self._static.area[0] > self._rebuild_ratio * self._static_built_area:
            build(self._static, boxes.aabbs)
            self._static_built_area = self._static.area[0]
        return np.ones(len(rows), np.bool_)

    def find_pairs(self, boxes, n_static, n_dynamic, moved=None):
        aabbs = boxes.aabbs
        tree = self._dynamic
        if self._dynamic_of != (n_static, n_dynamic):  # bodies came or went
            tree = self._dynamic = tree_for(np.arange(n_static, n_static + n_dynamic))
            self._dynamic_of = (n_static, n_dynamic)
            self._build(aabbs)
        elif self._rebuild_ratio <= 1.0:
            self._build(aabbs)
        else:
            refit(tree, aabbs)
            self.stats['refits'] += 1
            if tree.area[0] > self._rebuild_ratio * self._built_area:
                self._build(aabbs)
        return self._buffer.fill(_tree_pairs, tree, self._static, aabbs, n_static,
                                 self._stack)

    def validate(self, boxes, n_static, n_dynamic, loose=None):
        """Check both trees against ``boxes``; raise InvalidStructure if wrong. For testing.

        See :func:`validate_tree`. A dynamic tree made for other counts than ``n_static`` and
        ``n_dynamic`` is checked on its own only: the next tick makes a new one.
        """
        loose = loose_mask(loose, n_static)
        check(self._static is not None or n_static == 0,
              'no static tree for %d static boxes: set_static was not called', n_static)
        if self._static is not None:
            check(len(self._static.perm) == n_static, 'static tree over %d boxes, the scene '
                  'has %d', len(self._static.perm), n_static)
            validate_tree(self._static, boxes.aabbs, np.arange(n_static), ~loose,
                          'static tree')
        if self._dynamic is not None:
            first, count = self._dynamic_of
            current = self._dynamic_of == (n_static, n_dynamic)
            validate_tree(self._dynamic, boxes.aabbs, np.arange(first, first + count),
                          np.full(count, current), 'dynamic tree')

    def _build(self, aabbs):
        build(self._dynamic, aabbs)
        self._built_area = self._dynamic.area[0]
        self.stats['builds'] += 1


def validate_tree(tree, aabbs, rows, held, what):
    """Check a built tree over ``rows``; raise InvalidStructure at the first break.

    ``perm`` is a permutation of ``rows``; nodes exist exactly where the heap layout of
    :func:`build` puts them (the root, and both children of every node split at its middle);
    a split node has more than ``LEAF_SIZE`` boxes, a leaf at most that many (the node count
    of :func:`tree_for` guarantees it); every node's AABB contains its children's and those
    of its boxes that are ``held`` (bool per position of ``rows``: the boxes as they are in
    ``aabbs``, i.e. not loose), and ``area`` is that of the node AABBs.
    """
    perm, node_start, node_end, bounds = tree.perm, tree.node_start, tree.node_end, \
        tree.bounds
    n = len(rows)
    check_permutation(perm, rows, what + ' perm')
    nodes = len(tree_for(rows).node_start)
    check(len(node_start) == len(node_end) == len(bounds) == nodes,
          '%s: %d node starts, %d ends, %d bounds; %d boxes need %d nodes', what,
          len(node_start), len(node_end), len(bounds), n, nodes)
    exists = np.zeros(nodes, np.bool_)
    exists[0] = True
    check(node_start[0] == 0 and node_end[0] == n, '%s: root owns [%d, %d), not [0, %d)',
          what, node_start[0], node_end[0], n)
    for node in range(nodes):  # parents before children: the children of split nodes exist
        start, end = node_start[node], node_end[node]
        left = 2 * node + 1
        if not exists[node]:
            check(end <= start, '%s: node %d does not exist but owns [%d, %d)', what, node,
                  start, end)
        elif left < nodes and node_end[left] > node_start[left]:
            middle = (start + end) // 2
            check(end - start > LEAF_SIZE, '%s: node %d of %d boxes is split', what, node,
                  end - start)
            check(node_start[left] == start and node_end[left] == middle
                  and node_start[left + 1] == middle and node_end[left + 1] == end,
                  '%s: node %d [%d, %d) has children [%d, %d) and [%d, %d)', what, node, start,
                  end, node_start[left], node_end[left], node_start[left + 1],
                  node_end[left + 1])
            exists[left] = exists[left + 1] = True
        else:
            check(end - start <= LEAF_SIZE, '%s: leaf %d holds %d boxes, more than %d', what,
                  node, end - start, LEAF_SIZE)
    is_held = dict(zip(rows.tolist(), np.asarray(held, np.bool_).tolist()))
    area = 0.0
    for node in np.flatnonzero(exists & (node_end > node_start)):
        area += _surface(bounds, node)
        start, end = node_start[node], node_end[node]
        left = 2 * node + 1
        if left < nodes and exists[left]:
            for child in (left, left + 1):
                check_contains(bounds[node], bounds[child],
                               '%s: node %d around child %d' % (what, node, child))
        else:
            boxes = np.array([row for row in perm[start:end] if is_held[row]], np.int64)
            check_contains(np.broadcast_to(bounds[node], (len(boxes), 2, 3)), aabbs[boxes],
                           '%s: leaf %d around its boxes %s' % (what, node, boxes.tolist()))
    root = _surface(bounds, 0)
    area = area / root if root > 0.0 else 1.0
    check(np.isclose(tree.area[0], area, rtol=1e-9, atol=0.0),
          '%s: area %r, its node AABBs give %r', what, float(tree.area[0]), float(area))


@kernel
def build(tree, aabbs):
    """Partition ``tree.perm`` top-down and compute the node AABBs."""
    perm, keys, node_start, node_end = tree.perm, tree.keys, tree.node_start, tree.node_end
    n_nodes = len(node_start)
    node_end[:] = 0
    node_start[0] = 0
    node_end[0] = len(perm)
    for node in range(n_nodes):  # parents before children: heap order is breadth first
        start, end = node_start[node], node_end[node]
        if end - start <= LEAF_SIZE or 2 * node + 2 >= n_nodes:
            continue
        axis = _widest_axis(aabbs, perm, start, end)
        for i in range(start, end):
            keys[i] = aabbs[perm[i], 0, axis] + aabbs[perm[i], 1, axis]
        middle = (start + end) // 2
        _select(keys, perm, start, end, middle)
        node_start[2 * node + 1], node_end[2 * node + 1] = start, middle
        node_start[2 * node + 2], node_end[2 * node + 2] = middle, end
    refit(tree, aabbs)


@kernel
def refit(tree, aabbs):
    """Recompute every node's AABB bottom-up for the boxes' current positions."""
    perm, node_start, node_end, bounds = tree.perm, tree.node_start, tree.node_end, \
        tree.bounds
    n_nodes = len(node_start)
    area = 0.0
    for node in range(n_nodes - 1, -1, -1):
        start, end = node_start[node], node_end[node]
        if end <= start:
            continue
        left = 2 * node + 1
        if left < n_nodes and node_end[left] > node_start[left]:  # internal node
            for k in range(3):
                bounds[node, 0, k] = min(bounds[left, 0, k], bounds[left + 1, 0, k])
                bounds[node, 1, k] = max(bounds[left, 1, k], bounds[left + 1, 1, k])
        else:
            for k in range(3):
                bounds[node, 0, k] = np.inf
                bounds[node, 1, k] = -np.inf
            for i in range(start, end):
                for k in range(3):
                    bounds[node, 0, k] = min(bounds[node, 0, k], aabbs[perm[i], 0, k])
                    bounds[node, 1, k] = max(bounds[node, 1, k], aabbs[perm[i], 1, k])
        area += _surface(bounds, node)
    root = _surface(bounds, 0)
    tree.area[0] = area / root if root > 0.0 else 1.0


@kernel
def _surface(bounds, node):
    dx = bounds[node, 1, 0] - bounds[node, 0, 0]
    dy = bounds[node, 1, 1] - bounds[node, 0, 1]
    dz = bounds[node, 1, 2] - bounds[node, 0, 2]
    return dx * dy + dy * dz + dz * dx


@kernel
def _widest_axis(aabbs, perm, start, end):
    low = np.full(3, np.inf)
    high = np.full(3, -np.inf)
    for i in range(start, end):
        for k in range(3):
            center = aabbs[perm[i], 0, k] + aabbs[perm[i], 1, k]
            low[k] = min(low[k], center)
            high[k] = max(high[k], center)
    spread = high - low
    return int(np.argmax(spread))


@kernel
def _select(keys, perm, start, end, nth):
    """Put the element of sorted rank ``nth`` of keys/perm[start:end] at position ``nth``.

    Smaller-or-equal keys end up before it, greater-or-equal ones after (Hoare quickselect).
    """
    low, high = start, end - 1
    while low < high:
        middle = (low + high) // 2
        # median of three as pivot: robust on already sorted input (refits keep order)
        a, b, c = keys[low], keys[middle], keys[high]
        pivot = max(min(a, b), min(max(a, b), c))
        i, j = low, high
        while i <= j:
            while keys[i] < pivot:
                i += 1
            while keys[j] > pivot:
                j -= 1
            if i <= j:
                keys[i], keys[j] = keys[j], keys[i]
                perm[i], perm[j] = perm[j], perm[i]
                i += 1
                j -= 1
        if nth <= j:
            high = j
        elif nth >= i:
            low = i
        else:
            return


@kernel
def _tree_pairs(tree, static, aabbs, n_static, stack, out):
    """Pairs among the dynamic tree's boxes, then of each of them with the static tree's."""
    count, compared = _query(tree, tree.perm, aabbs, stack, out, 0, True)
    if n_static:
        count, tested = _query(static, tree.perm, aabbs, stack, out, count, False)
        compared += tested
    return count, compared


@kernel
def _query(tree, queries, aabbs, stack, out, count, dynamic):
    """Pairs of each box ``queries[p]`` with the boxes of ``tree``; return (count, compared).

    ``dynamic``: ``queries`` is the tree's own ``perm`` and box ``queries[p]`` meets only the
    boxes at positions after ``p``, so each pair is met once.
    """
    perm, node_start, node_end, bounds = tree.perm, tree.node_start, tree.node_end, \
        tree.bounds
    n_nodes = len(node_start)
    compared = 0
    for p in range(len(queries)):
        a = queries[p]
        first = p + 1 if dynamic else 0
        stack[0] = 0
        top = 1
        while top:
            top -= 1
            node = stack[top]
            end = node_end[node]
            if end <= first or not overlap_across(bounds, node, aabbs, a):
                continue
            left = 2 * node + 1
            if left < n_nodes and node_end[left] > node_start[left]:
                stack[top] = left
                stack[top + 1] = left + 1
                top += 2
                continue
            for q in range(max(node_start[node], first), end):
                b = perm[q]
                compared += 1
                hit = overlap_across(aabbs, a, aabbs, b)
                if dynamic:
                    count = emit_if(out, count, hit, min(a, b), max(a, b))
                else:
                    count = emit_if(out, count, hit, a, b)
    return count, compared
