"""Every broad phase's ``validate``: silent over random sequences of calls, loud on sabotage.

``validate`` checks a phase's whole structure (the API list of
``collision_node.pipeline.broadphase``). The phases are driven directly, on ``Boxes`` written
with ``set_boxes`` (no World): seeded random sequences of set_static, move_static (small and
large moves, resizes, boxes growing big) and find_pairs (bodies moving, still, appearing,
disappearing, flying far away and back; ``moved`` masks), with ``validate`` after every call
and the loose static rows tracked as the World tracks them. Then one structure at a time is
corrupted in a targeted way, and ``validate`` must say what is wrong: a check that cannot
fail proves nothing.
"""
import collections

from broadphase_reference import random_quaternions, sorted_pairs
import numpy as np
import pytest

from collision_node.pipeline.broadphase import (
    auto as auto_module, hash_map, InvalidStructure, make_broad_phase, NAMES, Settings)
from collision_node.pipeline.broadphase import octree as octree_module
from collision_node.pipeline.broadphase.cell_table import build_table
from collision_node.pipeline.broadphase.cells import cell_key, MAX_CELLS_PER_BODY
from collision_node.pipeline.obb import Boxes, set_boxes

S_MAX, D_MAX = 90, 150
SIDE = 5.0  # m: statics and bodies share this cube
FAR = 1e4   # m: where travellers go and come back from


def random_poses(rng, n, side=SIDE):
    """Return (n, 7) poses in the cube of ``side``, turned at random."""
    return np.concatenate([rng.uniform(0.0, side, (n, 3)), random_quaternions(rng, n)], axis=1)


def random_extents(rng, n):
    """Return (n, 3) half extents: mostly 5-50 cm, a few big boxes, a few points."""
    extents = rng.uniform(0.05, 0.5, (n, 3))
    extents[rng.random(n) < 0.03] *= 12.0  # a few big ones: more cells than a box may enter
    extents[rng.random(n) < 0.02] = 0.0    # and points
    return extents


class RandomRun:
    """One phase driven by a seeded random sequence of calls, validated after each one.

    ``loose`` follows the World's rule: a row move_static did not keep is loose until it is
    kept by a later move_static or set_static is called.
    """

    def __init__(self, name, seed, settings=None):
        """Make phase ``name`` and its random scene, and give it a first static scene."""
        self.rng = rng = np.random.default_rng(seed)
        if settings is None:
            settings = Settings(octree_max_depth=int(rng.choice([0, 0, 3, 5])),
                                octree_leaf_cooldown_ticks=int(rng.choice([0, 1, 4, 15])))
        self.phase = make_broad_phase(name, settings)
        self.boxes = Boxes(S_MAX + D_MAX)
        self.static_poses = random_poses(rng, S_MAX)
        self.static_extents = random_extents(rng, S_MAX)
        self.dynamic_poses = random_poses(rng, D_MAX)
        self.dynamic_extents = random_extents(rng, D_MAX)
        self.n_static = self.n_dynamic = 0
        self.loose = np.zeros(S_MAX, np.bool_)
        self.seen = collections.Counter()  # what the sequence exercised
        self.set_static(rng.integers(0, S_MAX + 1))

    def validate(self):
        """Validate the phase as the World would, loose rows and all."""
        self.phase.validate(self.boxes, self.n_static, self.n_dynamic, self.loose)

    def step(self):
        """Make one random call, then validate."""
        roll = self.rng.random()
        if roll < 0.05:
            self.set_static(self.rng.integers(0, S_MAX + 1) if self.rng.random() < 0.5
                            else self.n_static)  # the same count: the World's rebuild
        elif roll < 0.35 and self.n_static:
            self.move_static()
        else:
            self.find_pairs()
        self.validate()

    def set_static(self, n_static):
        """Write the first ``n_static`` statics and let the phase build for them."""
        self.n_static = int(n_static)
        set_boxes(self.boxes, 0, self.static_poses[:self.n_static],
                  self.static_extents[:self.n_static])
        self._write_dynamic(np.arange(self.n_dynamic))
        self.phase.set_static(self.boxes, self.n_static)
        self.loose[:] = False
        self.seen['set_static'] += 1

    def move_static(self):
        """Move, resize or rewrite a few or all static rows; note the loose ones."""
        rng = self.rng
        count = self.n_static if rng.random() < 0.15 else rng.integers(1, min(6, self.n_static)
                                                                       + 1)
        rows = np.sort(rng.choice(self.n_static, count, replace=False))
        kind = rng.choice(['small', 'large', 'far', 'resize', 'same'], p=[.4, .25, .05, .25, .05])
        poses, extents = self.static_poses, self.static_extents
        if kind == 'small':  # mostly within their cells and leaves
            poses[rows, :3] += rng.normal(0.0, 0.01, (count, 3))
        elif kind == 'large':
            poses[rows, :3] = rng.uniform(0.0, SIDE, (count, 3))
        elif kind == 'far':  # away, or back
            poses[rows, :3] = np.where(poses[rows, :3] > SIDE, rng.uniform(0.0, SIDE),
                                       rng.uniform(FAR / 2, FAR, (count, 3)))
        elif kind == 'resize':  # a little (within their cells, mostly), or anew
            extents[rows] = random_extents(rng, count) if rng.random() < 0.5 \
                else extents[rows] * rng.choice([0.95, 1.05], (count, 1))
        set_boxes(self.boxes, 0, poses[rows], extents[rows], rows)
        kept = self.phase.move_static(self.boxes, rows)
        assert kept.shape == (count,) and kept.dtype == np.bool_
        self.loose[rows] = ~kept
        self.seen['move_static'] += 1
        self.seen['loose_rows'] += int(np.count_nonzero(~kept))

    def find_pairs(self):
        """Let bodies move, stay, come or go, and run a tick."""
        rng = self.rng
        before = self.n_dynamic
        roll = rng.random()
        if roll < 0.1:
            self.n_dynamic = int(rng.integers(0, D_MAX + 1))  # bodies come or go
        elif roll < 0.15:
            self.n_dynamic = max(0, before - int(rng.integers(1, 4)))
        n = self.n_dynamic
        poses = self.dynamic_poses
        kind = rng.choice(['all', 'some', 'none', 'travel', 'resize'], p=[.45, .25, .1, .1, .1])
        if kind == 'all':
            movers = np.arange(n)
        elif kind == 'some':
            movers = np.flatnonzero(rng.random(n) < 0.3)
        elif kind == 'none':
            movers = np.zeros(0, np.int64)
        else:
            movers = rng.choice(n, min(n, 5), replace=False) if n else np.zeros(0, np.int64)
        if kind == 'travel':  # far away, or back
            poses[movers, :3] = np.where(poses[movers, :3] > SIDE, rng.uniform(0, SIDE),
                                         rng.uniform(FAR / 2, FAR, (len(movers), 3)))
        elif kind == 'resize':
            self.dynamic_extents[movers] = random_extents(rng, len(movers))
        else:
            poses[movers, :3] += rng.normal(0.0, 0.15, (len(movers), 3))
            poses[movers, :3] = np.abs(poses[movers, :3] % (2 * SIDE) - SIDE)  # walls
        moved = np.zeros(n, np.bool_)
        moved[movers] = True
        moved[before:] = True  # new bodies
        self._write_dynamic(np.arange(n))
        pairs, compared = self.phase.find_pairs(self.boxes, self.n_static, n,
                                                None if rng.random() < 0.3 else moved)
        assert compared >= 0 and len(sorted_pairs(pairs)) == len(pairs)
        self.seen['find_pairs'] += 1
        self.seen[self.phase.name] += 1

    def _write_dynamic(self, bodies):
        set_boxes(self.boxes, self.n_static, self.dynamic_poses[bodies],
                  self.dynamic_extents[bodies])


@pytest.fixture
def small_auto_thresholds(monkeypatch):
    """Let ``auto`` switch between all its phases at the test's body counts, and often."""
    monkeypatch.setattr(auto_module, 'BRUTE_FORCE_WORK', 300)
    monkeypatch.setattr(auto_module, 'GRID_BODIES', 150)
    monkeypatch.setattr(auto_module, 'SWITCH_AFTER_TICKS', 2)


def run(name, seed, steps):
    """Return a RandomRun of phase ``name`` after ``steps`` validated calls."""
    sequence = RandomRun(name, seed)
    sequence.validate()
    for _ in range(steps):
        sequence.step()
    return sequence


def check_exercised(name, seen):
    """Check that the sequence took the paths that matter for the phase."""
    assert seen['set_static'] >= 2 and seen['move_static'] >= 5 and seen['find_pairs'] >= 20
    if name in ('octree', 'grid'):  # the phases that keep only what stayed in its cells
        assert seen['loose_rows'] > 0
    if name == 'auto':
        assert len({'brute_force', 'sweep_and_prune', 'grid'} & set(seen)) >= 2, seen


@pytest.mark.parametrize('seed', [0, 1, 2])
@pytest.mark.parametrize('name', NAMES)
def test_validate_passes_after_every_call(name, seed, small_auto_thresholds):
    check_exercised(name, run(name, seed, 80).seen)


@pytest.mark.slow
@pytest.mark.parametrize('seed', range(10, 16))
@pytest.mark.parametrize('name', NAMES)
def test_validate_passes_over_long_sequences(name, seed, small_auto_thresholds):
    check_exercised(name, run(name, seed, 600).seen)


# Sabotage: a run that holds a bit of everything, then one targeted corruption at a time.

def tick(sequence, n_dynamic=None):
    """Run one tick with every body moved a little (``n_dynamic`` bodies, default: as now)."""
    sequence.n_dynamic = sequence.n_dynamic if n_dynamic is None else n_dynamic
    sequence.dynamic_poses[:, :3] += 0.02
    sequence._write_dynamic(np.arange(sequence.n_dynamic))
    sequence.phase.find_pairs(sequence.boxes, sequence.n_static, sequence.n_dynamic)
    sequence.validate()


TICKS_BEFORE_SABOTAGE = 6


def ready(name, seed=3, settings=Settings(octree_max_depth=4, octree_leaf_cooldown_ticks=15)):
    """Return a validated RandomRun with statics, bodies and a few ticks of history.

    With this seed it holds what each sabotage needs: big static and dynamic boxes, octree
    leaves cooling down, nodes and buckets of several boxes.
    """
    sequence = RandomRun(name, seed, settings)
    sequence.set_static(60)
    tick(sequence, 120)
    for _ in range(TICKS_BEFORE_SABOTAGE - 1):
        tick(sequence)
    return sequence


def static_box_moved_without_telling(sequence, row=None):
    """Move a static box far in the boxes, not calling move_static; return its row."""
    row = int(np.argmin(sequence.boxes.aabbs[:sequence.n_static, 1, 0]
                        - sequence.boxes.aabbs[:sequence.n_static, 0, 0])) if row is None else row
    poses = sequence.static_poses[row:row + 1].copy()
    poses[0, :3] += 2.0
    set_boxes(sequence.boxes, row, poses, sequence.static_extents[row:row + 1])
    return row


def expect_invalid(sequence, match):
    with pytest.raises(InvalidStructure, match=match):
        sequence.validate()


@pytest.mark.parametrize('name', ['octree', 'grid', 'kd_tree', 'sweep_and_prune'])
def test_a_static_box_moved_without_move_static_is_caught_unless_loose(name):
    sequence = ready(name)
    row = static_box_moved_without_telling(sequence)
    expect_invalid(sequence, {'octree': 'static box %d is held in cells' % row,
                              'grid': 'static table: the copy of box %d' % row,
                              'kd_tree': 'static tree: leaf .* around its boxes',
                              'sweep_and_prune': 'the copy of static box %d' % row}[name])
    sequence.loose[row] = True  # as if move_static had not kept it: the structure may lag
    sequence.validate()


@pytest.mark.parametrize('name', NAMES)
def test_after_set_static_on_new_boxes_only_the_static_structure_is_checked(name):
    """The World's set_static writes new storage: the dynamic rows are not the last tick's.

    With ``n_dynamic`` 0 the dynamic structures, made for other counts, are checked on their
    own; the next tick makes them anew and all is checked again.
    """
    sequence = ready(name)
    n_dynamic, sequence.n_dynamic = sequence.n_dynamic, 0
    sequence.boxes = Boxes(sequence.boxes.capacity)
    sequence.boxes.aabbs[:] = np.nan  # no dynamic row written yet
    sequence.set_static(sequence.n_static)
    sequence.validate()
    tick(sequence, n_dynamic)


@pytest.mark.parametrize('name', ['octree', 'grid', 'kd_tree', 'sweep_and_prune'])
def test_a_dynamic_box_moved_after_the_tick_is_caught(name):
    sequence = ready(name)
    row = sequence.n_static + 7
    sequence.boxes.aabbs[row] += 3.0
    expect_invalid(sequence, {'octree': 'dynamic box 7 is registered in cells',
                              'grid': 'dynamic table: the copy of box %d' % row,
                              'kd_tree': 'dynamic tree: leaf .* around its boxes',
                              'sweep_and_prune': 'dynamic list: the copy of box %d' % row}[name])


def octree_state(sequence):
    return sequence.phase._state


def used_leaves(state):
    used = np.ones(len(state.leaves), np.bool_)
    used[state.free_leaves[:state.counters[octree_module.FREE_LEAVES]]] = False
    return np.flatnonzero(used)


def crowded_leaf(state):
    """Return a leaf holding at least two dynamic boxes."""
    dynamic = state.leaves[:, octree_module.LEAF_DYNAMIC]
    return next(leaf for leaf in used_leaves(state) if dynamic[leaf] >= 2)


def drop_a_body_from_a_leaf(state):
    """Unlink the head entry of a leaf's list, as a buggy removal would."""
    o = octree_module
    leaf = crowded_leaf(state)
    head = state.leaves[leaf, o.LEAF_HEAD]
    following = state.entries[head, o.ENTRY_NEXT]
    state.leaves[leaf, o.LEAF_HEAD] = following
    state.entries[following, o.ENTRY_PREV] = o.NULL
    state.leaves[leaf, o.LEAF_DYNAMIC] -= 1


def miscount_a_leaf(state):
    state.leaves[crowded_leaf(state), octree_module.LEAF_DYNAMIC] += 1


def list_a_static_box_in_a_wrong_leaf(state):
    """Replace a leaf's first static box by one whose cells do not include the leaf's."""
    o = octree_module
    leaf = next(leaf for leaf in used_leaves(state) if state.leaves[leaf, o.LEAF_STATIC_COUNT])
    cell = state.leaves[leaf, :3]
    ranges = state.static_range
    outside = np.any((cell < ranges[:, 0]) | (cell > ranges[:, 1]), axis=1)
    state.static_members[state.leaves[leaf, o.LEAF_STATIC_START]] = np.flatnonzero(outside)[0]


def forget_a_leaf_in_the_map(state):
    leaf = used_leaves(state)[0]
    hash_map.remove(state.map_keys, state.map_leaves, cell_key(*state.leaves[leaf, :3]))


def swap_two_active_leaves(state):
    state.active[[0, 1]] = state.active[[1, 0]]


def cool_a_leaf_for_too_long(state):
    """Date an emptied leaf's emptying one tick before the cooldown would have dropped it."""
    o = octree_module
    active = state.active[:state.counters[o.ACTIVE]]
    leaf = next(leaf for leaf in active if state.leaves[leaf, o.LEAF_DYNAMIC] == 0)
    state.leaves[leaf, o.LEAF_EMPTY_SINCE] = TICKS_BEFORE_SABOTAGE - 15


def mark_an_occupied_leaf_empty(state):
    state.leaves[crowded_leaf(state), octree_module.LEAF_EMPTY_SINCE] = 3


def free_a_used_leaf(state):
    o = octree_module
    free = state.counters[o.FREE_LEAVES]
    state.free_leaves[free] = used_leaves(state)[-1]
    state.counters[o.FREE_LEAVES] += 1


def make_a_big_body_small(state):
    o = octree_module
    i = int(np.flatnonzero(state.bodies[:, o.BODY_STATE] == o.BIG)[0])
    state.bodies[i, o.BODY_STATE] = o.IN_LEAVES


OCTREE_SABOTAGE = [
    (drop_a_body_from_a_leaf, 'neither free nor in a leaf'),
    (miscount_a_leaf, r'lists \d+ dynamic boxes, counts'),
    (list_a_static_box_in_a_wrong_leaf, 'lists static box'),
    (forget_a_leaf_in_the_map, r'leaves \[\d+\] in use but not in the map'),
    (swap_two_active_leaves, 'of the active list, it says'),
    (cool_a_leaf_for_too_long, r'cools down since tick -?\d+: out of the cooldown \(15'),
    (mark_an_occupied_leaf_empty, 'dynamic boxes but is empty since tick 3'),
    (free_a_used_leaf, r'leaves \[\d+\] in the map but free'),
    (make_a_big_body_small, r'in leaves spans|is in 0 leaves'),
]


@pytest.mark.parametrize('sabotage, match', OCTREE_SABOTAGE,
                         ids=[sabotage.__name__ for sabotage, _ in OCTREE_SABOTAGE])
def test_octree_sabotage_is_caught(sabotage, match):
    sequence = ready('octree')
    sabotage(octree_state(sequence))
    expect_invalid(sequence, match)


def kd_trees(sequence):
    return sequence.phase._static, sequence.phase._dynamic


def shrink_a_leaf_box(tree):
    """Cut the upper x bound of the first leaf below its boxes' (its parent is still right)."""
    leaf = next(node for node in range(len(tree.node_start) - 1, -1, -1)
                if tree.node_end[node] > tree.node_start[node])
    tree.bounds[leaf, 1, 0] = tree.bounds[leaf, 0, 0] - 1.0


def shrink_the_root_box(tree):
    tree.bounds[0, 1] -= 0.5


def swap_boxes_of_two_far_leaves(tree):
    """Swap the first and the last box of ``perm``: each lands in a leaf far from it."""
    tree.perm[[0, -1]] = tree.perm[[-1, 0]]


def repeat_a_box(tree):
    tree.perm[1] = tree.perm[0]


def move_a_split(tree):
    tree.node_end[1] -= 1


def misstate_the_area(tree):
    tree.area[0] *= 1.5


KD_SABOTAGE = [
    (shrink_a_leaf_box, 'around its boxes'),
    (shrink_the_root_box, 'node 0 around child'),
    (swap_boxes_of_two_far_leaves, 'around its boxes'),
    (repeat_a_box, 'perm is not a permutation'),
    (move_a_split, r'node 0 \[0, \d+\) has children'),
    (misstate_the_area, 'area'),
]


@pytest.mark.parametrize('tree', ['static', 'dynamic'])
@pytest.mark.parametrize('sabotage, match', KD_SABOTAGE,
                         ids=[sabotage.__name__ for sabotage, _ in KD_SABOTAGE])
def test_kd_tree_sabotage_is_caught(sabotage, match, tree):
    sequence = ready('kd_tree')
    sabotage(kd_trees(sequence)[tree == 'dynamic'])
    expect_invalid(sequence, '%s tree.*(%s)' % (tree, match))


def swap_two_sorted_dynamic_entries(phase):
    """Swap the first and last entry of the sorted dynamic list (rows, copies and keys)."""
    for array in (phase._order, phase._sorted, phase._keys):
        array[[0, -1]] = array[[-1, 0]]


def swap_two_static_rows_not_their_copies(phase):
    phase._static_orders[2, [0, -1]] = phase._static_orders[2, [-1, 0]]


def swap_two_static_entries(phase):
    for array in (phase._static_orders[1], phase._static_sorted[1]):
        array[[0, -1]] = array[[-1, 0]]


def drop_a_dynamic_row(phase):
    phase._order[3] = phase._order[4]


def stale_key(phase):
    phase._keys[5] += 1e-9


SWEEP_SABOTAGE = [
    (swap_two_sorted_dynamic_entries, 'dynamic list: not sorted by the lower bound'),
    (swap_two_static_rows_not_their_copies, 'static list of axis 2: the copy of static box'),
    (swap_two_static_entries, 'static list of axis 1: not sorted'),
    (drop_a_dynamic_row, 'dynamic list is not a permutation'),
    (stale_key, 'keys are not the lower bounds'),
]


@pytest.mark.parametrize('sabotage, match', SWEEP_SABOTAGE,
                         ids=[sabotage.__name__ for sabotage, _ in SWEEP_SABOTAGE])
def test_sweep_and_prune_sabotage_is_caught(sabotage, match):
    sequence = ready('sweep_and_prune')
    sabotage(sequence.phase)
    expect_invalid(sequence, match)


def busy_entry(table):
    """Return an entry of a bucket holding two or more entries."""
    ends = table.bucket_end[:table.sizes[1]]
    bucket = int(np.flatnonzero(np.diff(ends, prepend=0) >= 2)[0])
    return int(ends[bucket - 1]) if bucket else 0


def enter_a_box_in_a_wrong_cell(table):
    table.entry_key[busy_entry(table)] += 100 << 42  # 100 cells along x: out of its range


def shift_a_bucket_border(table):
    ends = table.bucket_end[:table.sizes[1]]
    bucket = int(np.flatnonzero(np.diff(ends, prepend=0))[0])
    ends[bucket] -= 1  # its last entry now seems to be in the next bucket


def flip_first_cell_flags(table):
    table.entry_first[busy_entry(table)] ^= 1


def make_a_small_box_big(table):
    slot = int(table.entry_slot[busy_entry(table)])
    table.ranges[slot, 1] += MAX_CELLS_PER_BODY  # and its range with it


def lose_a_big_box(table):
    table.sizes[2] -= 1


GRID_SABOTAGE = [
    (enter_a_box_in_a_wrong_cell, 'names cell'),
    (shift_a_bucket_border, 'is in bucket'),
    (flip_first_cell_flags, 'first-cell flags'),
    (make_a_small_box_big, "cell range is not that of its AABB copy"),
    (lose_a_big_box, 'big rows'),
]


@pytest.mark.parametrize('table', ['static', 'dynamic'])
@pytest.mark.parametrize('sabotage, match', GRID_SABOTAGE,
                         ids=[sabotage.__name__ for sabotage, _ in GRID_SABOTAGE])
def test_grid_sabotage_is_caught(sabotage, match, table):
    sequence = ready('grid')
    sabotage(getattr(sequence.phase, '_' + table))
    expect_invalid(sequence, '%s table: .*%s' % (table, match))


def test_grid_tables_must_share_their_buckets():
    """A dynamic table right in itself but with twice the buckets of the static one."""
    sequence = ready('grid')
    grid = sequence.phase
    rows = np.arange(sequence.n_static, sequence.n_static + sequence.n_dynamic)
    grid._dynamic = build_table(grid._dynamic, grid._dynamic_lattice, sequence.boxes.aabbs,
                                rows, len(rows), sequence.n_static, grid._static.sizes[3] - 1)
    expect_invalid(sequence, 'dynamic table on another lattice or shift')


@pytest.mark.parametrize('name', ['brute_force', 'sphere'])
def test_brute_force_checks_the_counts(name):
    sequence = ready(name)
    sequence.validate()
    with pytest.raises(InvalidStructure, match='in storage for'):
        sequence.phase.validate(sequence.boxes, S_MAX, D_MAX + 1)
    with pytest.raises(InvalidStructure, match='a bool per static row'):
        sequence.phase.validate(sequence.boxes, 60, 10, np.zeros(5, np.bool_))


def test_auto_validates_the_phase_that_ran(small_auto_thresholds):
    sequence = ready('auto')
    auto = sequence.phase
    assert auto.name == 'grid'  # 180 bodies, over the lowered threshold
    auto._phases['grid']._dynamic.entry_key[0] += 100 << 42
    expect_invalid(sequence, 'dynamic table: .*names cell')
