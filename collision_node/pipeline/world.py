"""The collision pipeline without ROS: boxes in, sorted contacts out.

    world = World(broad_phase='auto', sphere_prefilter=True)
    world.set_static(static_poses, static_half_extents)        # (S, 7), (S, 3)
    result = world.step(dynamic_poses, dynamic_half_extents)   # (D, 7), (D, 3) or (3,)
    world.move_static(static_poses, static_half_extents)       # the same S boxes, changed

Boxes live in one preallocated :class:`~collision_node.pipeline.obb.Boxes`: static rows first
(written once), dynamic rows after them (each tick, those of the bodies that moved: the others
hold last step's boxes bit for bit), so a tick copies no static data and no still body.

Rows are in spatial order, not in the order of the input: static row i holds the static box
reported as ``static_ids[i]``, dynamic row ``n_static + i`` body ``dynamic_ids[i]``, the
boxes sorted along a Z-order curve (static ones when set, dynamic ones when their number
changes and again once the bodies have moved far from where they were sorted). Neighbours in
space are then neighbours in memory, and the narrow phase, which reads both boxes of every
candidate pair, ran 1.4x faster at 100,000 bodies (the boxes' arrays outgrow the L2 cache
there). Without the re-sort a long run loses that: 100,000 bouncing bodies, 2 minutes after
their rows were sorted, ticked in 70 ms instead of 54. Contacts are reported by input index
as before, and each pair is still computed in the frame of its smaller id
(contacts.orient_pairs), so the order changes no bit of the result.

Static boxes that change. :meth:`World.move_static` rewrites only the rows of the boxes that
changed and tells the broad phase, which keeps in its static structure those it can update
in place (the grid and the octree a box still in its cells, the k-d tree by a refit, sweep
and prune by re-sorting its nearly sorted lists). The others are "loose": the structure still
holds them where they were, so the World drops every pair the phase finds with a loose box
and pairs each loose box with every dynamic box itself (an AABB test per pair,
:func:`_with_loose_statics`). A phase never answers for a box it did not keep, so no
structure is silently stale. Once the loose boxes cost more than rebuilding the structure
(``LOOSE_REBUILD_WORK``), the World rebuilds it from the current boxes and nothing is loose.
The still-body shortcut keeps a contact only when both boxes are bit for bit those of the last
step: a pair with a static box that changed since then gets a fresh SAT.
"""
import math
import time
from typing import NamedTuple

import numpy as np

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.broadphase import make_broad_phase, NAMES, Settings
from collision_node.pipeline.broadphase.auto import GRID_BODIES
from collision_node.pipeline.broadphase.pair_buffer import emit, emit_if, PairBuffer
from collision_node.pipeline.contacts import (  # noqa: F401 (DYNAMIC re-exported)
    assemble_contacts, closest_contact, CONTACT_DTYPE, DYNAMIC, merge_contacts,
    MIN_PAIRS_PER_THREAD, orient_pairs, STATIC)
from collision_node.pipeline.continuous import (advance_pairs, boxes_at, CONTINUOUS_TOLERANCE,
                                                motion, NO_CONTACT, sweep_bounds)
from collision_node.pipeline.filters import (ALL_CATEGORIES, collision_bits, DEFAULT_CATEGORY,
                                             filters_nothing, PairFilter)
from collision_node.pipeline.obb import (Boxes, InvalidBox, MAX_COORDINATE, overlap_across,
                                         pad_bounds, set_boxes)
from collision_node.pipeline.sat import (collide_pairs, COLLIDING, empty_output, INVALID,
                                         NEAR)
from collision_node.pipeline.scenes import uniform
from collision_node.pipeline.workers import Workers

# Z-order curve resolution: 2**10 cells per axis over the bodies' bounding box (2**30 cells,
# far more than bodies, so each cell holds a few at most).
Z_ORDER_BITS = 10
Z_ORDER_INDEX_BITS = 63 - 3 * Z_ORDER_BITS  # the rest of an int64 key: 8e9 points
# The dynamic rows are sorted again once a sample of bodies has moved, on average, this many
# times their bounding radius since the last sort: by then neighbours in memory are no longer
# neighbours in space. At least Z_ORDER_MIN_TICKS apart, so that input that jumps about every
# tick pays the sort (0.2 ms at 10,000 bodies, 2.3 ms at 100,000), and the broad phase's
# slower tick after it, on one tick in that many.
Z_ORDER_SAMPLE = 64
Z_ORDER_STALE_RADII = 4.0
Z_ORDER_MIN_TICKS = 50
# The SAT's output arrays grow to this many times the pairs of the tick that outgrew them, so
# that a slowly growing count does not reallocate every tick.
SAT_OUTPUT_GROWTH = 1.5
# stats['continuous']: off, or swept over the motion since the previous input (else it says
# why the step was checked at its poses only).
OFF = 'off'
SWEPT = 'on'
# Least candidate pairs in a chunk when the SAT is spread over threads: ~0.15 ms of SAT
# (~75 ns a pair) against the ~10-50 µs a helper's dispatch costs.
MIN_PAIRS_PER_CHUNK = 2048
# From this many boxes (static and dynamic rows) the candidate pairs are sorted by row before
# the SAT (contacts.orient_pairs): once the boxes' arrays outgrow the L2 cache, the SAT reading
# each box's data together saves more than the sort costs; below, the sort only costs
# (doc/benchmarks.md, "Threads").
SORT_PAIRS_ROWS = 16384
# Least bodies in a chunk when their boxes are written over threads: ~35 ns a body (more at
# 100,000 bodies, whose rows leave the caches), so ~0.3 ms a chunk.
MIN_BODIES_PER_CHUNK = 8192
# The broad phase's static structure is rebuilt once the loose static boxes (moved since it was
# built, and not kept by the phase) have cost, summed over the ticks since it was built, as many
# AABB comparisons (loose x dynamic boxes per tick) as its rebuild costs: this many per static
# box. Measured at 10,000 and 100,000 bodies, half static: the grid's static table rebuilds in
# 90-125 ns a box, a loose comparison takes ~1 ns in a tick. Paying for the rebuild once the
# overlay has cost as much is at most twice the cost of the better choice in hindsight (ski
# rental), whether few boxes move for many ticks or many at once.
LOOSE_REBUILD_WORK = 100


class Result(NamedTuple):
    """Contacts sorted by (id_a, type_b, id_b), and the tick's statistics."""

    contacts: np.ndarray
    stats: dict


class World:
    """Static and dynamic oriented boxes and the broad phase that pairs them."""

    def __init__(self, broad_phase='auto', sphere_prefilter=True, octree_max_depth=0,
                 octree_leaf_cooldown_ticks=15, threads=1, margin=0.0, continuous=False,
                 continuous_tolerance=CONTINUOUS_TOLERANCE):
        self._boxes = Boxes(1024)
        self._n_static = 0
        self._static_ids = np.zeros(0, np.int64)
        self._static = _StaticInput(np.zeros((0, 7)), np.zeros((0, 3)), np.zeros(0, np.int64),
                                    np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64))
        # Per static row (spatial order), for the pair filter:
        self._static_categories = np.zeros(0, np.int64)
        self._static_masks = np.zeros(0, np.int64)
        self._static_ignorable = np.zeros(0, np.bool_)
        self._static_margins = False  # whether any static box has a margin of its own
        self._static_rows = np.zeros(0, np.int64)  # row of each box in set_static's order
        # Static rows moved since the broad phase built its static structure, and those changed
        # since the last step: a flag per row (at least one, for the kernels) and their list.
        self._loose = np.zeros(1, np.bool_)
        self._loose_rows = np.zeros(0, np.int64)
        self._loose_work = 0  # AABB comparisons of loose rows since the structure was built
        self._changed = np.zeros(1, np.bool_)
        self._changed_rows = np.zeros(0, np.int64)
        self._loose_buffer = PairBuffer()
        self._filter = PairFilter()
        self._filtering = False  # whether any setting can filter a pair
        self._margin = _checked_margin('margin', margin)
        self._dynamic_ids = np.zeros(0, np.int64)  # body in each dynamic row (spatial order)
        self._dynamic_rows = np.zeros(0, np.int64)  # its inverse: row of each body - n_static
        self._sampled = np.zeros(0, np.int64)  # bodies whose travel tells when to sort again
        self._sampled_at = np.zeros((0, 3))    # their positions when the rows were sorted
        self._ticks_since_sort = 0
        self._sat_output = empty_output(0)  # reused from tick to tick, grown as needed
        self._pairs_by_row = np.zeros((0, 2), np.int64)  # the candidate pairs, as the SAT reads
        self._row_starts = np.zeros(1, np.int64)  # their counting sort's scratch
        self._continuous = bool(continuous)
        self._tolerance = _checked_tolerance(continuous_tolerance)
        self._previous = None  # the poses of the last accepted input (the motion's start)
        self._sweep = _Sweep(Boxes(0), np.zeros((0, 3)), np.zeros((0, 4)))
        self._workers = Workers(threads)
        self._settings = Settings(octree_max_depth, octree_leaf_cooldown_ticks)
        self._phase_name = broad_phase
        self._phase = None
        self.sphere_prefilter = sphere_prefilter
        self.configure(broad_phase=broad_phase, octree_max_depth=octree_max_depth,
                       octree_leaf_cooldown_ticks=octree_leaf_cooldown_ticks)

    @property
    def broad_phase(self):
        return self._phase_name

    @property
    def sphere_prefilter(self):
        return self._sphere_prefilter

    @property
    def margin(self):
        """Pairs whose boxes are at most this far apart (m, exact distance) are reported."""
        return self._margin

    @margin.setter
    def margin(self, value):
        margin = _checked_margin('margin', value)
        if margin != self._margin:
            self._margin = margin
            self.set_static(*self._static)  # the static bounds are padded by half the margin

    @sphere_prefilter.setter
    def sphere_prefilter(self, value):
        self._sphere_prefilter = bool(value)
        self._last = None

    @property
    def continuous(self):
        """Whether pairs are checked over the motion since the last input (continuous.py)."""
        return self._continuous

    @continuous.setter
    def continuous(self, value):
        self._continuous = bool(value)
        self._last = None

    @property
    def continuous_tolerance(self):
        """Metres: a continuous pair's boxes are within margin + this at its ``toi``."""
        return self._tolerance

    @continuous_tolerance.setter
    def continuous_tolerance(self, value):
        self._tolerance = _checked_tolerance(value)
        self._last = None

    def configure(self, broad_phase=None, octree_max_depth=None,
                  octree_leaf_cooldown_ticks=None):
        """Change the broad phase or its settings; raises ValueError on invalid values."""
        name = self._phase_name if broad_phase is None else broad_phase
        settings = self._settings._replace(**{
            key: value for key, value in (
                ('octree_max_depth', octree_max_depth),
                ('octree_leaf_cooldown_ticks', octree_leaf_cooldown_ticks))
            if value is not None})
        if self._phase is None or name != self._phase_name or settings != self._settings:
            phase = make_broad_phase(name, settings, self._workers)  # checks name and settings
            self._phase_name, self._settings, self._phase = name, settings, phase
            self._build_static_structure()
            self._last = None

    def _build_static_structure(self):
        """Let the broad phase build its static structure from the current boxes."""
        self._phase.set_static(self._boxes, self._n_static)
        self._loose[self._loose_rows] = False
        self._loose_rows = np.zeros(0, np.int64)
        self._loose_work = 0

    def set_static(self, poses, half_extents, ids=None, margins=0.0,
                   categories=DEFAULT_CATEGORY, masks=ALL_CATEGORIES):
        """Replace the static boxes; ``ids`` (default 0..S-1) are reported as their id_b.

        ``margins`` (m, one for all or one per box) are added to the World's margin for pairs
        with that box; ``categories`` and ``masks`` (one for all or one per box) are their
        collision filter bits. Raises ValueError naming the first invalid box or value.
        """
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 7)
        count = len(poses)
        if ids is None:
            ids = np.arange(count)
        ids = np.asarray(ids, dtype=np.int64)
        if ids.shape != (count,):
            raise ValueError('ids must have one entry per static pose')
        margins = _per_box('static margins', np.asarray(margins, np.float64), count)
        for margin in margins:
            _checked_margin('static margin', margin)
        categories = _per_box('static categories',
                              collision_bits('static categories', categories), count)
        masks = _per_box('static masks', collision_bits('static masks', masks), count)
        # Written into new storage so that an invalid box leaves the world as it was.
        boxes = Boxes(count + self._boxes.capacity)
        order = _z_order(poses[:, :3])  # static rows in spatial order too
        rows = _inverse(order)
        try:
            set_boxes(boxes, 0, poses, half_extents, rows)
        except ValueError as error:
            raise ValueError('static %s' % error) from None
        boxes.margins[:count] = margins[order]
        if self._margin > 0.0 or np.any(margins > 0.0):  # padding with 0 changes no bit
            pad_bounds(boxes.aabbs, boxes.radii, boxes.margins, rows, 0, self._margin / 2)
        self._static = _StaticInput(
            poses.copy(), np.broadcast_to(np.asarray(half_extents, np.float64), (count, 3)).copy(),
            ids, margins, categories, masks)
        self._boxes = boxes
        self._static_margins = bool(np.any(margins > 0.0))
        self._n_static = count
        self._static_ids = ids[order]
        self._static_rows = rows
        self._static_categories = categories[order]
        self._static_masks = masks[order]
        self._loose = np.zeros(max(count, 1), np.bool_)
        self._loose_rows = np.zeros(0, np.int64)
        self._changed = np.zeros(max(count, 1), np.bool_)
        self._changed_rows = np.zeros(0, np.int64)
        self._update_filtering()
        self._build_static_structure()
        self._last = None

    def move_static(self, poses, half_extents=None):
        """Move (and resize) static boxes in place from the next step on; return how many changed.

        ``poses`` (S, 7) and ``half_extents`` (S, 3; default: as they are) give every static box
        in the order of the last set_static, S its count; ids, margins and filter bits stay.
        Only the boxes that differ from their last pose or size are written, checked and
        re-tested (see the module docstring). Raises ValueError naming the first invalid box
        (InvalidBox, its index in ``poses``); then nothing changes.
        """
        count = self._n_static
        poses = np.require(poses, np.float64, ['C', 'A', 'W'])
        if poses.shape != (count, 7):
            raise ValueError('static poses: need shape (%d, 7), one per static box, got %s'
                             % (count, poses.shape))
        extents = self._static.half_extents
        if half_extents is not None:
            extents = np.require(half_extents, np.float64, ['C', 'A', 'W'])
            if extents.shape != (count, 3):
                raise ValueError('static half extents: need shape (%d, 3), got %s'
                                 % (count, extents.shape))
        changed = np.zeros(count, np.bool_)
        _mark_changed_rows(self._static.poses, poses, changed)
        if half_extents is not None:
            _mark_changed_rows(self._static.half_extents, extents, changed)
        boxes_changed = np.flatnonzero(changed)
        if not len(boxes_changed):
            return 0
        # All of them (every tick, for statics that move like dynamic bodies): views, no copies.
        take = slice(None) if len(boxes_changed) == count else boxes_changed
        try:
            rows = _write_bodies(self._boxes, 0, poses, extents, self._static_rows, take,
                                 self._workers)
        except InvalidBox:
            # Boxes are written (before the invalid one, and other threads' chunks): all of
            # them back to their last (valid) state.
            rows = _write_bodies(self._boxes, 0, self._static.poses, self._static.half_extents,
                                 self._static_rows, take, self._workers)
            self._pad_static_rows(rows)
            raise
        self._pad_static_rows(rows)
        self._static.poses[take] = poses[take]
        self._static.half_extents[take] = extents[take]
        rows = np.arange(count) if isinstance(take, slice) else np.sort(rows)  # memory order
        self._loose[rows] = ~self._phase.move_static(self._boxes, rows)
        self._loose_rows = np.flatnonzero(self._loose)
        self._changed[rows] = True
        self._changed_rows = np.flatnonzero(self._changed)
        return len(rows)

    def _pad_static_rows(self, rows):
        """Grow the bounds of static ``rows`` by half the margin and their own, as set_static."""
        if self._margin > 0.0 or self._static_margins:
            pad_bounds(self._boxes.aabbs, self._boxes.radii, self._boxes.margins, rows, 0,
                       self._margin / 2)

    def set_filters(self, categories=DEFAULT_CATEGORY, masks=ALL_CATEGORIES, ignored_pairs=()):
        """Set the dynamic bodies' collision bits and the pairs never to check.

        ``categories`` and ``masks``: one integer for every dynamic body, or one per body in
        input order; ``ignored_pairs``: rows ``(id_a, type_a, id_b, type_b)`` as in the cloud.
        A pair is checked only if ``category_a & mask_b`` and ``category_b & mask_a`` are both
        non-zero and it is not ignored (filters.py). Raises ValueError on invalid values.
        """
        self._filter = PairFilter(categories, masks, ignored_pairs)
        self._update_filtering()
        self._last = None

    def _update_filtering(self):
        flags = self._filter.static_ignorable
        self._static_ignorable = np.zeros(self._n_static, np.bool_) if not len(flags) else \
            flags[np.minimum(self._static_ids, len(flags) - 1)] & (self._static_ids < len(flags))
        self._filtering = not (self._filter.is_default and filters_nothing(
            self._static_categories, self._static_masks))

    @property
    def static_count(self):
        return self._n_static

    def step(self, poses, half_extents):
        """Collide the dynamic boxes (poses (D, 7), half extents (D, 3) or (3,)).

        Raises ValueError naming the first invalid dynamic body; then nothing is reported.
        An input identical to the previous one returns the previous result again; pairs of
        bodies that kept their pose and size since the previous step keep their contacts
        without a SAT. The result's contacts are read-only: later steps reuse them.
        """
        start = time.perf_counter()
        poses = np.require(poses, np.float64, ['C', 'A', 'W']).reshape(-1, 7)
        half_extents = np.asarray(half_extents, dtype=np.float64)
        self._filter.check_count(len(poses))
        # Continuous: every pair is swept over its motion, so no contact is kept from the
        # last step (its toi belonged to that step's motion).
        moved = None if self._continuous else self._moved_bodies(poses, half_extents)
        changed_rows = self._changed_rows  # static rows changed since the last step
        if moved is not None and not moved.any() and not len(changed_rows):
            return self._last[2]._replace(stats=dict(self._last[2].stats, reused=True))
        if moved is not None and moved.all():
            moved = None  # nothing to keep: the plain path
        n_dynamic = len(poses)
        n_static = self._n_static
        written = moved  # the bodies whose rows are written (None: all)
        if n_static + n_dynamic > self._boxes.capacity:
            self._boxes = self._boxes.grown(2 * (n_static + n_dynamic), n_static)
            self._build_static_structure()
            written = None  # the dynamic rows were not copied
        self._ticks_since_sort += 1
        if len(self._dynamic_ids) != n_dynamic or self._rows_are_stale(poses, half_extents):
            self._sort_dynamic_rows(poses)
            written = None  # rows now hold other bodies
        rows = self._write_dynamic_boxes(poses, half_extents, written)
        mode = self._continuous_mode(n_dynamic)
        if mode == SWEPT:
            self._sweep_bounds(poses, half_extents)
        if self._margin > 0.0:
            pad_bounds(self._boxes.aabbs, self._boxes.radii, self._boxes.margins, rows,
                       n_static, self._margin / 2)
        prepared = time.perf_counter()

        stats = {'broad_phase': self._phase.name, 'dynamic_bodies': n_dynamic,
                 'static_bodies': n_static, 'compared': 0, 'candidate_pairs': 0,
                 'filtered_pairs': 0, 'sat_tests': 0, 'colliding_pairs': 0, 'near_pairs': 0,
                 'min_distance': math.nan, 'min_distance_pair': None, 'reused': False,
                 'still_bodies': 0 if moved is None else int(n_dynamic - moved.sum()),
                 'continuous': mode, 'swept_pairs': 0, 'advance_steps': 0,
                 'unresolved_pairs': 0,
                 'broad_phase_stats': {}}
        if n_dynamic == 0:  # nothing moves: nothing to pair
            contacts = np.zeros(0, CONTACT_DTYPE)
            broad_done = narrow_done = prepared
        else:
            if len(self._loose_rows):
                self._loose_work += len(self._loose_rows) * n_dynamic
                if self._loose_work > LOOSE_REBUILD_WORK * n_static:
                    self._build_static_structure()
            moved_rows = None if moved is None else moved[self._dynamic_ids]
            if not self._loose[changed_rows].all():
                # A box changed and the phase holds it (kept in place, or rebuilt): it must
                # pair it with the bodies that kept their pose too.
                moved_rows = None
            pairs, compared = self._phase.find_pairs(self._boxes, n_static, n_dynamic, moved_rows)
            if len(self._loose_rows):
                pairs, loose_compared = self._loose_buffer.fill(
                    _with_loose_statics, pairs, self._loose, self._loose_rows, self._boxes.aabbs,
                    n_static, n_static + n_dynamic)
                compared += loose_compared
            stats['broad_phase'] = self._phase.name
            stats['broad_phase_stats'] = dict(self._phase.stats)
            broad_done = time.perf_counter()
            candidates = len(pairs)
            pairs = self._oriented(pairs)
            if self._filtering:
                pairs = pairs[:self._filter.keep_checked(
                    pairs, n_static, self._static_ids, self._static_categories,
                    self._static_masks, self._static_ignorable, self._dynamic_ids)]
            checked = len(pairs)
            if moved is not None:  # the other pairs' contacts are those of the last step
                pairs = pairs[:_front_pairs_with_a_moved_body(pairs, n_static, self._dynamic_ids,
                                                              moved, self._changed)]
            if mode == SWEPT:
                contacts, sat_tests = self._collide_swept(pairs, stats)
            else:
                status, depth, normal, point, sat_tests = self._collide(pairs)
                _check_valid(status)
                contacts = assemble_contacts(pairs, status, depth, normal, point, n_static,
                                             n_dynamic, self._static_ids, self._dynamic_ids,
                                             workers=self._workers)
            if moved is not None:
                contacts = merge_contacts(
                    self._contacts_of_still_bodies(moved, self._static_ids[changed_rows]),
                    contacts)
            narrow_done = time.perf_counter()
            stats.update(compared=int(compared), candidate_pairs=candidates,
                         filtered_pairs=candidates - checked, sat_tests=int(sat_tests),
                         **_distance_stats(contacts))
        stats.update(prepare_ms=1e3 * (prepared - start), broad_ms=1e3 * (broad_done - prepared),
                     narrow_ms=1e3 * (narrow_done - broad_done),
                     total_ms=1e3 * (time.perf_counter() - start))
        contacts.flags.writeable = False
        result = Result(contacts, stats)
        self._last = (poses.copy(), half_extents.copy(), result)
        self._previous = self._last[0]
        if len(changed_rows):
            self._changed[changed_rows] = False
            self._changed_rows = np.zeros(0, np.int64)
        return result

    def _oriented(self, pairs):
        """Return ``pairs`` oriented (contacts.orient_pairs), by row from SORT_PAIRS_ROWS rows.

        Sorted pairs are written to a buffer of the World's, the others oriented in place.
        """
        rows = self._n_static + len(self._dynamic_ids)
        if rows < SORT_PAIRS_ROWS:
            orient_pairs(pairs, self._n_static, self._dynamic_ids, None, pairs)
            return pairs
        if len(self._pairs_by_row) < len(pairs):
            self._pairs_by_row = np.empty((int(SAT_OUTPUT_GROWTH * len(pairs)), 2), np.int64)
        if len(self._row_starts) != rows + 1:
            self._row_starts = np.empty(rows + 1, np.int64)
        out = self._pairs_by_row[:len(pairs)]
        orient_pairs(pairs, self._n_static, self._dynamic_ids, self._row_starts, out)
        return out

    def _write_dynamic_boxes(self, poses, half_extents, moved):
        """Write the bodies that ``moved`` (None: all) to their rows; return the rows written.

        The rows of the others hold their boxes, bit for bit, since the last step. Raises
        InvalidBox naming the first invalid body by its index in ``poses``; the rows before
        it then hold refused input, so the next step writes every row.
        """
        bodies = slice(None) if moved is None else np.flatnonzero(moved)
        try:
            return _write_bodies(self._boxes, self._n_static, poses, half_extents,
                                 self._dynamic_rows, bodies, self._workers)
        except InvalidBox:
            self._last = None
            raise

    def _continuous_mode(self, n_dynamic):
        """Return how this step is checked: OFF, SWEPT, or why it falls back to discrete."""
        if not self._continuous:
            return OFF
        if self._previous is None:
            return 'discrete (no previous input)'
        if len(self._previous) != n_dynamic:
            return 'discrete (pose count changed from %d to %d)' % (len(self._previous),
                                                                    n_dynamic)
        return SWEPT

    def _sweep_bounds(self, poses, half_extents):
        """Set the motion since the previous input and grow the dynamic bounds to hold it."""
        n_static, n_dynamic = self._n_static, len(poses)
        if self._sweep.start.capacity < n_dynamic:
            capacity = 2 * n_dynamic
            self._sweep = _Sweep(Boxes(capacity), np.zeros((capacity, 3)),
                                 np.zeros((capacity, 4)))
        start, velocity, spin = self._sweep
        set_boxes(start, 0, self._previous, half_extents, self._dynamic_rows)
        motion(self._previous, poses, self._dynamic_rows, velocity, spin)
        boxes = self._boxes
        sweep_bounds(boxes.aabbs, boxes.radii, boxes.half_extents, start.aabbs, velocity, spin,
                     n_static, n_static + n_dynamic)

    def _collide_swept(self, pairs, stats):
        """Return the contacts of ``pairs`` over the motion, and the SAT tests at t = 1.

        Conservative advancement finds each pair's toi; the pairs that touch at t = 1 get the
        contacts of the discrete SAT there, the others (touching only in between) those of
        the boxes at their toi, with depth 0.
        """
        boxes, n_static = self._boxes, self._n_static
        n_dynamic = len(self._dynamic_ids)
        start, velocity, spin = self._sweep
        margins = boxes.margins if self._margin > 0.0 or self._static_margins else None
        toi = np.empty(len(pairs))

        def chunk(_, first, stop):
            return advance_pairs(pairs[first:stop], n_static, boxes.centers, boxes.rotations,
                                 boxes.half_extents, start.centers, start.rotations, velocity,
                                 spin, self._margin, margins, self._tolerance,
                                 toi[first:stop])

        counts = self._workers.map_ranges(chunk, len(pairs), MIN_PAIRS_PER_CHUNK)
        hit = toi != NO_CONTACT
        pairs, toi = pairs[hit], toi[hit]
        status, depth, normal, point, sat_tests = self._collide(pairs)
        _check_valid(status)
        contacts = assemble_contacts(pairs, status, depth, normal, point, n_static, n_dynamic,
                                     self._static_ids, self._dynamic_ids, toi, self._workers)
        between = (status != COLLIDING) & (status != NEAR)
        if between.any():
            pairs, toi = pairs[between], toi[between]
            centers, rotations, extents = boxes_at(pairs, toi, n_static, boxes, start.centers,
                                                   start.rotations, velocity, spin)
            # An infinite margin: the signed distance of every pair (sat.signed_distance).
            status, depth, normal, point, _ = collide_pairs(
                centers, rotations, extents, np.zeros(len(centers)),
                np.arange(len(centers)).reshape(-1, 2), margin=math.inf)
            _check_valid(status)
            swept = assemble_contacts(pairs, status, depth, normal, point, n_static, n_dynamic,
                                      self._static_ids, self._dynamic_ids, toi, self._workers)
            swept['depth'] = 0.0
            contacts = merge_contacts(contacts, swept)
        stats.update(swept_pairs=int(between.sum()),
                     advance_steps=sum(steps for steps, _ in counts),
                     unresolved_pairs=sum(unresolved for _, unresolved in counts))
        return contacts, sat_tests

    def _moved_bodies(self, poses, half_extents):
        """Return which bodies changed pose or size since the last step, bool (D,).

        None when there is nothing to compare with: no last step (or the World changed since:
        static boxes, broad phase, prefilter), another body count, or another size for all.
        NaN differs from everything, so a body with a NaN always counts as moved.
        """
        if self._last is None:
            return None
        last_poses, last_extents, _ = self._last
        if last_poses.shape != poses.shape or last_extents.shape != half_extents.shape:
            return None
        moved = np.zeros(len(poses), np.bool_)
        _mark_changed_rows(last_poses, poses, moved)
        if half_extents.ndim == 2:
            _mark_changed_rows(last_extents, np.ascontiguousarray(half_extents), moved)
        elif not np.array_equal(last_extents, half_extents):
            return None
        return moved

    def _contacts_of_still_bodies(self, moved, changed_static_ids):
        """Return the last step's contacts between bodies that did not move or change.

        Their boxes are bit for bit those of the last step, so the broad phase pairs them as
        then and the SAT would give the same bits. ``changed_static_ids``: the static boxes
        moved or resized since then.
        """
        last = self._last[2].contacts
        still = ~moved
        is_static = last['type_b'] == STATIC
        b_still = np.where(is_static, True, still[np.minimum(last['id_b'], len(still) - 1)])
        if len(changed_static_ids):
            b_still &= ~(is_static & np.isin(last['id_b'], changed_static_ids))
        return last[still[last['id_a']] & b_still]

    def _sort_dynamic_rows(self, poses):
        """Give the dynamic bodies rows in Z-order of their positions.

        The broad phase keeps what it knew of each row; a row now holding another body is to
        it a body that moved, which every phase handles (one slower tick).
        """
        self._dynamic_ids = _z_order(poses[:, :3])
        self._dynamic_rows = _inverse(self._dynamic_ids)
        self._sampled = np.linspace(0, len(poses) - 1, min(Z_ORDER_SAMPLE, len(poses))).astype(
            np.int64)
        self._sampled_at = poses[self._sampled, :3].copy()
        self._ticks_since_sort = 0

    def _rows_are_stale(self, poses, half_extents):
        """Whether the sampled bodies moved far, on average, since the rows were sorted."""
        if self._ticks_since_sort < Z_ORDER_MIN_TICKS or not len(self._sampled):
            return False
        if half_extents.shape == (3,):
            extents = half_extents
        elif half_extents.shape == (len(poses), 3):
            extents = half_extents[self._sampled]
        else:  # set_boxes refuses the shape, naming it
            return False
        travel = np.linalg.norm(poses[self._sampled, :3] - self._sampled_at, axis=1)
        radius = np.linalg.norm(extents, axis=-1)
        # NaN or Inf (input the boxes then refuse) compares False: no sort.
        return bool(np.mean(travel) > Z_ORDER_STALE_RADII * np.mean(radius))

    def _collide(self, pairs):
        """Run the SAT on ``pairs`` over the World's threads; as sat.collide_pairs returns."""
        if len(self._sat_output[0]) < len(pairs):
            self._sat_output = empty_output(int(SAT_OUTPUT_GROWTH * len(pairs)))
        boxes = self._boxes
        margins = boxes.margins if self._margin > 0.0 or self._static_margins else None

        def chunk(_, start, stop):
            return collide_pairs(boxes.centers, boxes.rotations, boxes.half_extents,
                                 boxes.radii, pairs[start:stop], self._sphere_prefilter,
                                 [array[start:stop] for array in self._sat_output],
                                 self._margin, margins)[-1]

        sat_tests = sum(self._workers.map_ranges(chunk, len(pairs), MIN_PAIRS_PER_CHUNK))
        return tuple(array[:len(pairs)] for array in self._sat_output) + (sat_tests,)

    def close(self):
        """Stop the World's helper threads (none with ``threads=1``)."""
        self._workers.close()


class _Sweep(NamedTuple):
    """Each dynamic row's motion since the previous input (continuous.py)."""

    start: Boxes           # the boxes at the previous input's poses (centres, rotations, AABBs)
    velocity: np.ndarray   # (D, 3) Δc
    spin: np.ndarray       # (D, 4) unit axis and angle of the rotation


class _StaticInput(NamedTuple):
    """The arguments of the last set_static, kept to pad the boxes again for a new margin."""

    poses: np.ndarray
    half_extents: np.ndarray
    ids: np.ndarray
    margins: np.ndarray
    categories: np.ndarray
    masks: np.ndarray


def _checked_tolerance(value):
    tolerance = float(value)
    if not 0.0 < tolerance <= MAX_COORDINATE:  # also refuses NaN
        raise ValueError('continuous tolerance must be in (0, %g] m, got %r'
                         % (MAX_COORDINATE, value))
    return tolerance


def _write_bodies(boxes, first, poses, half_extents, rows, bodies, workers):
    """Write ``poses[bodies]`` to rows ``first + rows[bodies]``; return ``rows[bodies]``.

    ``bodies``: an index array, or ``slice(None)`` for all (views, no copies); ``half_extents``
    one per pose or (3,) for all. The bodies are cut into chunks over the ``workers``' threads
    (each writes its own rows). Raises InvalidBox naming the first invalid body by its index
    in ``poses``, whichever thread met it; the other chunks may be written.
    """
    if half_extents.shape not in ((3,), (len(poses), 3)):  # chunks would hide a mismatch
        raise ValueError('half extents must have shape (3,) or (%d, 3), got %s'
                         % (len(poses), half_extents.shape))
    written = rows[bodies]
    taken = poses[bodies]
    extents = half_extents[bodies] if half_extents.ndim == 2 else half_extents

    def chunk(_, start, stop):
        try:
            set_boxes(boxes, first, taken[start:stop],
                      extents[start:stop] if extents.ndim == 2 else extents,
                      written[start:stop])
        except InvalidBox as error:
            return start + error.body, error.reason
        return None

    refused = [bad for bad in workers.map_ranges(chunk, len(written), MIN_BODIES_PER_CHUNK)
               if bad is not None]
    if refused:
        index, reason = min(refused)
        raise InvalidBox(int(np.arange(len(poses))[bodies][index]), reason)
    return written


def _check_valid(status):
    if np.any(status == INVALID):  # bounded, finite input cannot get here; never guess
        raise RuntimeError('the SAT met NaN, Inf or overflow on validated input')


def _checked_margin(name, value):
    margin = float(value)
    if not 0.0 <= margin <= MAX_COORDINATE:  # also refuses NaN
        raise ValueError('%s must be in [0, %g] m, got %r' % (name, MAX_COORDINATE, value))
    return margin


def _per_box(name, values, count):
    """Return ``values`` (one for all, or one per box) as one per box."""
    values = np.atleast_1d(values)
    if values.ndim != 1 or len(values) not in (1, count):
        raise ValueError('%s: give one value or one per box (%d), got %d'
                         % (name, count, values.size))
    return np.broadcast_to(values, (count,)).copy()


def _distance_stats(contacts):
    """Return colliding_pairs, near_pairs, min_distance and min_distance_pair of contacts."""
    near, smallest, closest = closest_contact(contacts['distance'])
    if closest < 0:
        return {'colliding_pairs': 0, 'near_pairs': 0, 'min_distance': math.nan,
                'min_distance_pair': None}
    row = contacts[closest]
    return {'colliding_pairs': len(contacts) - near, 'near_pairs': near,
            'min_distance': smallest,
            'min_distance_pair': (int(row['id_a']), int(row['type_a']), int(row['id_b']),
                                  int(row['type_b']))}


@kernel
def _mark_changed_rows(previous, current, changed):
    """Set ``changed[i]`` where row ``i`` of ``current`` differs from ``previous``'s."""
    for i in range(current.shape[0]):
        k = 0
        # A moving body differs in its first value: one comparison, not a whole row.
        while not changed[i] and k < current.shape[1]:
            changed[i] = not previous[i, k] == current[i, k]  # NaN is never equal: changed
            k += 1


@kernel
def _front_pairs_with_a_moved_body(pairs, n_static, dynamic_ids, moved, static_changed):
    """Move the pairs with a moved or changed body to the front of ``pairs``; return how many.

    A pair is kept when its dynamic body moved or its static box changed (``static_changed``
    per static row, at least one entry).
    """
    count = 0
    for k in range(pairs.shape[0]):
        a = pairs[k, 0]
        b = pairs[k, 1]
        # Without a branch, as in orient_pairs: a static b looks up a valid dummy body, a
        # dynamic b a valid dummy static flag (False when there are no static boxes).
        keep = moved[dynamic_ids[a - n_static]] | (
            (b >= n_static) & moved[dynamic_ids[max(b - n_static, 0)]]) | (
            (b < n_static) & static_changed[min(b, max(n_static - 1, 0))])
        pairs[count, 0] = a
        pairs[count, 1] = b
        count += keep
    return count


@kernel
def _with_loose_statics(pairs, loose, loose_rows, aabbs, n_static, n_total, out):
    """Write ``pairs`` without those of loose static rows, then each loose row's own pairs.

    A loose row is compared with every dynamic row by its current AABB. Returns (count,
    compared), as the broad phases do.
    """
    count = 0
    for k in range(pairs.shape[0]):
        b = pairs[k, 1]
        count = emit_if(out, count, b >= n_static or not loose[b], pairs[k, 0], b)
    # Dynamic rows outside, the few loose boxes inside (their bounds stay in cache), and a
    # branch on the rare hit: 0.4 ns a comparison, a third of a branch-free store per pair.
    loose_bounds = aabbs[loose_rows]
    for a in range(n_static, n_total):
        for i in range(len(loose_rows)):
            if overlap_across(aabbs, a, loose_bounds, i):
                count = emit(out, count, a, loose_rows[i], n_static)
    return count, len(loose_rows) * (n_total - n_static)


def _z_order(points):
    """Return the indices of ``points`` (N, 3) sorted along a Z-order curve.

    The points are yet to be checked: NaN, Inf and far points are put somewhere, and the
    order stays a permutation.
    """
    # Sorting the keys with each point's index in their low bits is a stable argsort, ~8x
    # faster than np.argsort(kind='stable') at 100,000 points: numpy sorts plain int64 by SIMD.
    keys = np.sort(_indexed_morton_keys(np.ascontiguousarray(points, np.float64)))
    return keys & ((1 << Z_ORDER_INDEX_BITS) - 1)


@kernel
def _indexed_morton_keys(points):
    """Return each point's Z-order key over ``Z_ORDER_INDEX_BITS`` bits holding its index.

    The key interleaves the bits of the point's cell in a 2**Z_ORDER_BITS grid per axis over
    the points' bounding box.
    """
    n = len(points)
    low = np.full(3, np.inf)
    high = np.full(3, -np.inf)
    for i in range(n):
        for axis in range(3):
            x = _clamped(points[i, axis])
            low[axis] = min(low[axis], x)
            high[axis] = max(high[axis], x)
    span = np.maximum(high - low, np.finfo(np.float64).tiny)
    keys = np.zeros(n, np.int64)
    for i in range(n):
        key = 0
        for axis in range(3):
            cell = np.int64((_clamped(points[i, axis]) - low[axis]) / span[axis]
                            * ((1 << Z_ORDER_BITS) - 1))
            for bit in range(Z_ORDER_BITS):
                key |= ((cell >> bit) & 1) << (3 * bit + axis)
        keys[i] = (key << Z_ORDER_INDEX_BITS) | i
    return keys


@kernel
def _clamped(x):
    """Return ``x`` within ±MAX_COORDINATE; NaN as 0."""
    return 0.0 if math.isnan(x) else min(max(x, -MAX_COORDINATE), MAX_COORDINATE)


def _inverse(permutation):
    inverse = np.empty_like(permutation)
    inverse[permutation] = np.arange(len(permutation))
    return inverse


WARM_UP_BODIES = 64  # half static: enough for every broad phase to run its full code path
AUTO_SPREAD_BODIES = 2 * GRID_BODIES  # auto's choice past sweep and prune


def warm_up():
    """Run every broad phase and the SAT on a small scene, so that no later tick compiles.

    numba compiles a kernel (or loads it from its cache) on its first call with each type
    signature; the node calls this before it subscribes, the benchmarks before they time.
    """
    scene = uniform(WARM_UP_BODIES, seed=1)
    for name in NAMES:
        for statics in (True, False):
            world = World(broad_phase=name)
            if statics:
                world.set_static(scene.static_poses, scene.static_half_extents)
            for sphere_prefilter in (True, False):
                world.sphere_prefilter = sphere_prefilter
                # Bodies move between steps so that update paths (bodies leaving their cell or
                # leaf) run too, and half of them only, so that still bodies keep their
                # contacts; one size per body, then one size for all, one body, none.
                world.step(scene.dynamic_poses(0.0), scene.dynamic_half_extents)
                world.step(_half_moved(scene, 0.5), scene.dynamic_half_extents)
                world.step(scene.dynamic_poses(1.0), scene.dynamic_half_extents[0])
                world.step(_half_moved(scene, 1.0), scene.dynamic_half_extents[0])
                world.step(scene.dynamic_poses(1.5)[:1], scene.dynamic_half_extents[0])
                world.step(np.zeros((0, 7)), scene.dynamic_half_extents[0])
    # auto measures the boxes' spread only from AUTO_SPREAD_BODIES bodies on.
    large = uniform(AUTO_SPREAD_BODIES, seed=1)
    world = World(broad_phase='auto')
    world.set_static(large.static_poses, large.static_half_extents)
    world.step(large.dynamic_poses(0.0), large.dynamic_half_extents)
    # Margins (padded bounds, exact distances) and filters (masks per body, ignored pairs).
    world = World(broad_phase='brute_force', margin=0.1)
    world.set_static(scene.static_poses, scene.static_half_extents, margins=0.05, masks=3)
    world.set_filters(categories=np.arange(len(scene.dynamic_poses(0.0))) % 2 + 1,
                      ignored_pairs=[(0, DYNAMIC, 1, DYNAMIC), (0, DYNAMIC, 0, STATIC)])
    world.step(scene.dynamic_poses(0.0), scene.dynamic_half_extents)
    world.step(_half_moved(scene, 0.5), scene.dynamic_half_extents)
    # Continuous checking (swept bounds, advancement, pairs touching only in between), with
    # and without margins: a bullet through a wall besides the scene.
    bullet = np.array([[0.0, 0.0, -2.0, 0.0, 0.0, 0.0, 1.0]])
    poses = [np.concatenate([scene.dynamic_poses(t), bullet + [[0.0, 0.0, 4.0 * t] + [0.0] * 4]])
             for t in (0.0, 0.5, 1.0)]
    for margin in (0.0, 0.1):
        world = World(broad_phase='brute_force', margin=margin, continuous=True)
        world.set_static(np.concatenate([scene.static_poses, [[0.0] * 6 + [1.0]]]),
                         np.concatenate([scene.static_half_extents, [[1.0, 1.0, 0.01]]]),
                         margins=margin)
        for step_poses in poses:
            world.step(step_poses, [0.05, 0.05, 0.05])
    # Candidate pairs sorted by row, which only scenes of SORT_PAIRS_ROWS boxes are.
    pairs = np.array([[0, 1]])
    orient_pairs(pairs, 0, np.arange(2), np.zeros(3, np.int64), pairs.copy())
    # Contacts listed by ranges of bodies for threads (discrete and swept ticks alike), which
    # only ticks of MIN_PAIRS_PER_THREAD candidate pairs a thread are: two bodies against one
    # static box, many times over.
    pairs = np.tile([[1, 0], [2, 0]], (MIN_PAIRS_PER_THREAD, 1))
    status, depth, normal, point = empty_output(len(pairs))
    status[:] = COLLIDING
    depth[:] = normal[:] = point[:] = 0.0
    workers = Workers(2)
    assemble_contacts(pairs, status, depth, normal, point, 1, 2, np.zeros(1, np.int64),
                      np.arange(2), workers=workers)
    workers.close()
    # Static boxes that moved under still bodies: a little (kept in every phase's structure),
    # then far (loose in the grid and the octree: paired by the World itself).
    for name in NAMES:
        world = World(broad_phase=name)
        world.set_static(scene.static_poses, scene.static_half_extents)
        world.step(scene.dynamic_poses(0.0), scene.dynamic_half_extents)
        moved = scene.static_poses.copy()
        for shift in (1e-3, 2.0):
            moved[:2, 0] += shift
            world.move_static(moved)
            world.step(_half_moved(scene, 0.5), scene.dynamic_half_extents)


def _half_moved(scene, time_s):
    """Return the scene's poses at ``time_s``, every other body still where it was at 0 s."""
    poses = scene.dynamic_poses(time_s)
    poses[::2] = scene.dynamic_poses(0.0)[::2]
    return poses
