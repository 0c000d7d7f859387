"""The general path: a broad phase over static and dynamic rows, then the SAT on its pairs.

Boxes live in one preallocated :class:`~collision_node.pipeline.obb.Boxes` of this path's
own: a copy of the static rows (scene_rows.py) first, the dynamic rows after them, both in
spatial order (z_order.py). The static rows are copied when the World derives them again,
and row by row when colliders move; dynamic rows each tick, only those of the bodies that
moved (the others hold last step's boxes bit for bit). Contacts are reported by input index
and collider id, and each pair is computed in the frame of its smaller id
(contacts.orient_pairs), so no bit of a result depends on the row order.

Cached state, keyed on the scene rows' versions (scene_rows.py) and this path's own inputs:
the broad phase, made again when its name or settings change, and its static structure, built
again when the rows are derived again; the last step's input and result, with the version it
was computed at. A step derives from these numbers alone what it may keep: the whole last
answer when nothing moved and no static row was stamped since; the contacts between bodies
that kept their pose (and static rows unstamped since) otherwise; nothing when a change came
after it. The one pass (one_pass.py) has rows of its own: it never touches these.

Static boxes that move. Their rows are copied and the broad phase told, which keeps in its
static structure those it can update in place (the grid and the octree a box still in its
cells, the k-d tree by a refit, sweep and prune by re-sorting its nearly sorted lists). The
others are "loose": the structure still holds them where they were, so the path drops every
pair the phase finds with a loose box and pairs each loose box with every dynamic box itself
(an AABB test per pair, :func:`_with_loose_statics`). A phase never answers for a box it did
not keep, so no structure is silently stale. Once the loose boxes cost more than rebuilding
the structure (``LOOSE_REBUILD_WORK``), the path rebuilds it and nothing is loose.

Continuous mode sweeps each pair over the motion since the previous accepted input, which the
World hands in (whichever path checked it).

:meth:`GeneralPath.broad_phase_pairs` (World.broad_phase_pairs) gives what a discrete step's
broad phase hands the SAT, on a path of its own: it writes only that path's rows and phase.
"""
import math
import time
from typing import NamedTuple

import numpy as np

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.broadphase import make_broad_phase
from collision_node.pipeline.broadphase.pair_buffer import emit, emit_if, PairBuffer
from collision_node.pipeline.contacts import (assemble_contacts, CONTACT_DTYPE, DYNAMIC,
                                              merge_contacts, orient_pairs, STATIC)
from collision_node.pipeline.continuous import (advance_pairs, boxes_at, motion, NO_CONTACT,
                                                sweep_bounds)
from collision_node.pipeline.obb import Boxes, InvalidBox, overlap_across, pad_bounds, set_boxes
from collision_node.pipeline.sat import collide_pairs, COLLIDING, empty_output, INVALID, NEAR
from collision_node.pipeline.scene_rows import as_poses, write_bodies
from collision_node.pipeline.stats import OFF, Result, reused, Stats, SWEPT
from collision_node.pipeline.z_order import inverse, z_order

# The dynamic rows are sorted again once a sample of bodies has moved, on average, this many
# times their bounding radius since the last sort: by then neighbours in memory are no longer
# neighbours in space. At least Z_ORDER_MIN_TICKS apart, so that input that jumps about every
# tick pays the sort, and the broad phase's slower tick after it, on one tick in that many.
Z_ORDER_SAMPLE = 64
Z_ORDER_STALE_RADII = 4.0
Z_ORDER_MIN_TICKS = 50
# The SAT's output arrays grow to this many times the pairs of the tick that outgrew them, so
# that a slowly growing count does not reallocate every tick.
SAT_OUTPUT_GROWTH = 1.5
# Least candidate pairs in a chunk when the SAT is spread over threads: ~0.15 ms of SAT
# (~75 ns a pair) against the ~10-50 µs a helper's dispatch costs.
MIN_PAIRS_PER_CHUNK = 2048
# From this many boxes (static and dynamic rows) the candidate pairs are sorted by row before
# the SAT (contacts.orient_pairs): once the boxes' arrays outgrow the L2 cache, the SAT reading
# each box's data together saves more than the sort costs; below, the sort only costs
# (doc/benchmarks.md, "Threads").
SORT_PAIRS_ROWS = 16384
# The broad phase's static structure is rebuilt once the loose static boxes (moved since it was
# built, and not kept by the phase) have cost, summed over the ticks since it was built, as many
# AABB comparisons (loose x dynamic boxes per tick) as its rebuild costs: this many per static
# box (a rebuild takes ~100 ns a box, a loose comparison ~1 ns). Paying for the rebuild once the
# overlay has cost as much is at most twice the cost of the better choice in hindsight (ski
# rental), whether few boxes move for many ticks or many at once.
LOOSE_REBUILD_WORK = 100


class _Last(NamedTuple):
    """The last step's input and result, and the version it was computed at."""

    poses: np.ndarray
    half_extents: np.ndarray
    result: Result
    version: int


class BroadPhasePairs(NamedTuple):
    """What a discrete general-path step's broad phase hands the SAT (World.broad_phase_pairs).

    Row r of ``boxes`` is static collider ``ids[r]`` (``types[r]`` STATIC) or dynamic body
    ``ids[r]``, its index in the input (DYNAMIC); the dynamic rows follow the static ones in
    spatial order. The arrays are read-only views, valid until the next call.
    """

    pairs: np.ndarray    # (P, 2) rows after the filters; first a body's (of two, the smaller)
    ids: np.ndarray      # (N,) each row's collider id or body index
    types: np.ndarray    # (N,) each row's STATIC or DYNAMIC
    boxes: Boxes         # the N rows as the SAT reads them (AABBs and radii padded by margin)
    compared: int        # the phase's comparisons (stats' ``compared``)
    candidates: int      # its pairs before the filters (stats' ``candidate_pairs``)


class GeneralPath:
    """Steps of any size through the broad phase (module docstring)."""

    def __init__(self, scene, continuous=True):
        """Read ``scene`` (scene_rows.SceneRows), never write it.

        ``continuous`` False: never sweep, whatever the World's option (a batch's states have
        no motion between them).
        """
        self._scene = scene
        self._may_sweep = continuous
        self._workers = scene.workers
        self._phase_key = None  # (name, settings) of the phase
        self.phase = None
        self.boxes = Boxes(1024)
        self.loose = _Loose(0)
        self._built_at = -1  # the scene's built_at the static rows were copied at
        self._moved_to = 0   # the last move copied
        self.dynamic = _DynamicRows()
        self._last = None      # _Last of the last step
        self._sweep = _Sweep(Boxes(0), np.zeros((0, 3)), np.zeros((0, 4)))
        self._previous = None  # the step's motion start (continuous)
        self._sat_output = empty_output(0)  # reused from tick to tick, grown as needed
        self._pairs_by_row = np.zeros((0, 2), np.int64)  # the candidate pairs, as the SAT reads
        self._row_starts = np.zeros(1, np.int64)  # their counting sort's scratch
        self._loose_buffer = PairBuffer()
        self._phase_rows = 0  # dynamic rows the phase's structure holds as they are (validate)
        self.sync()

    def sync(self):
        """Bring the phase and the static rows to the scene's version (module docstring)."""
        scene = self._scene
        options = scene.options
        key = (options.broad_phase, options.phase_settings)
        if key != self._phase_key:
            self.phase = make_broad_phase(options.broad_phase, options.phase_settings,
                                          self._workers)
            self._phase_key = key
            self._built_at = -1
        if self._built_at != scene.built_at:
            count = scene.count
            self.boxes = scene.boxes.grown(count + self.boxes.capacity, count)
            self._build_static_structure()
            self._built_at, self._moved_to = scene.built_at, scene.moved_version
        elif self._moved_to != scene.moved_version:
            count = scene.count
            rows = np.flatnonzero(scene.rows.moved_at[:count] > self._moved_to)
            for mine, theirs in zip(self.boxes, scene.boxes):
                mine[rows] = theirs[rows]
            self.loose.mark(rows, self.phase.move_static(self.boxes, rows))
            self._moved_to = scene.moved_version

    def step(self, poses, half_extents, previous, start):
        """Collide the dynamic boxes as World.step does; ``previous`` the motion's start.

        ``start`` the step's perf_counter at its call (the stats' times count from it).
        """
        scene = self._scene
        self.sync()
        scene.filter.check_count(len(poses))
        continuous = scene.options.continuous and self._may_sweep
        self._previous = previous
        last = self._last if self._last is not None \
            and self._last.version >= scene.rebuilt_at else None
        # Continuous: every pair is swept over its motion, so no contact is kept from the
        # last step (its toi belonged to that step's motion).
        moved = None if continuous or last is None else \
            _moved_bodies(last, poses, half_extents)
        # Static rows moved since the last step (bool per row, at least one; None: no step).
        changed = None if last is None else scene.rows.moved_at > last.version
        if moved is not None and not moved.any() and not changed.any():
            return Result(last.result.contacts, reused(last.result.record))
        if moved is not None and moved.all():
            moved = None  # nothing to keep: the plain path
        n_dynamic = len(poses)
        mode = self._continuous_mode(n_dynamic)
        self._write_dynamic_rows(poses, half_extents, moved, mode)
        prepared = time.perf_counter()
        counts, sweep, phase_stats = (0, 0, 0, 0), (0, 0, 0), {}
        if n_dynamic == 0:  # nothing moves: nothing to pair
            contacts = np.zeros(0, CONTACT_DTYPE)
            broad_done = narrow_done = prepared
        else:
            pairs, compared = self._candidate_pairs(n_dynamic, moved, changed)
            phase_stats = dict(self.phase.stats)
            broad_done = time.perf_counter()
            candidates = len(pairs)
            pairs = self._checked_pairs(pairs)
            contacts, sat_tests, sweep = self._contacts(pairs, moved, changed, mode)
            narrow_done = time.perf_counter()
            counts = (compared, candidates, candidates - len(pairs), sat_tests)
        contacts.flags.writeable = False
        result = Result(contacts, Stats(
            self.phase.name, n_dynamic, scene.count, counts,
            False, 0 if moved is None else int(n_dynamic - moved.sum()), mode, *sweep,
            phase_stats, 1e3 * (prepared - start), 1e3 * (broad_done - prepared),
            1e3 * (narrow_done - broad_done), 1e3 * (time.perf_counter() - start), None))
        self._last = _Last(poses.copy(), half_extents.copy(), result, scene.version)
        return result

    def broad_phase_pairs(self, poses, half_extents):
        """Return the :class:`BroadPhasePairs` of a discrete step at these poses (no SAT).

        Writes every dynamic row and pairs them all, as a step with nothing to keep does; a
        path used for this only (World's) holds no step's state. Raises ValueError as step.
        """
        poses, half_extents = as_poses(poses), np.asarray(half_extents, dtype=np.float64)
        self.sync()
        self._scene.filter.check_count(len(poses))
        self._write_dynamic_rows(poses, half_extents, None, OFF)
        n_static, n_dynamic = self._scene.count, len(poses)
        pairs, compared = self._candidate_pairs(n_dynamic, None, None) if n_dynamic else \
            (np.zeros((0, 2), np.int64), 0)
        candidates = len(pairs)
        pairs = self._checked_pairs(pairs)
        ids = np.concatenate([self._scene.rows.ids[:n_static], self.dynamic.ids])
        types = np.repeat(np.array([STATIC, DYNAMIC], np.uint8), [n_static, n_dynamic])
        boxes = Boxes._make(_read_only(array[:n_static + n_dynamic]) for array in self.boxes)
        return BroadPhasePairs(_read_only(pairs), _read_only(ids), _read_only(types), boxes,
                               int(compared), candidates)

    def validate(self):
        """Check the copied static rows, the loose rows and the phase's structure (testing).

        Brings the path to the scene's version first, as its next step would.
        """
        self.sync()
        count = self._scene.count
        for mine, theirs in zip(self.boxes, self._scene.boxes):
            assert np.array_equal(mine[:count], theirs[:count]), \
                "a static row differs from the scene rows' copy"
        assert np.array_equal(self.loose.rows, np.flatnonzero(self.loose.flags)), \
            'loose rows and flags disagree'
        self.phase.validate(self.boxes, count, self._phase_rows, self.loose.flags)

    @property
    def last_poses(self):
        """Return the poses of the last step's input (None before one)."""
        return None if self._last is None else self._last.poses

    def _build_static_structure(self):
        """Let the broad phase build its static structure from the current boxes."""
        self.phase.set_static(self.boxes, self._scene.count)
        self.loose = _Loose(self._scene.count)
        self._phase_rows = 0

    def _write_dynamic_rows(self, poses, half_extents, moved, mode):
        """Write the rows of the bodies that ``moved`` (None: all), their sweep and padding."""
        n_static, n_dynamic = self._scene.count, len(poses)
        written = moved  # the bodies whose rows are written (None: all)
        if n_static + n_dynamic > self.boxes.capacity:
            self.boxes = self.boxes.grown(2 * (n_static + n_dynamic), n_static)
            self._build_static_structure()
            written = None  # the dynamic rows were not copied
        self.dynamic.ticks_since_sort += 1
        if len(self.dynamic.ids) != n_dynamic or self.dynamic.stale(poses, half_extents):
            self.dynamic.sort(poses)
            written = None  # rows now hold other bodies
        bodies = slice(None) if written is None else np.flatnonzero(written)
        try:
            rows = write_bodies(self.boxes, n_static, poses, half_extents, self.dynamic.rows,
                                bodies, self._workers)
        except InvalidBox:
            self._last = None  # rows before the refused body hold its input: rewrite them all
            self._phase_rows = 0
            raise
        if mode == SWEPT:
            self._sweep_bounds(poses, half_extents)
        margin = self._scene.options.margin
        if margin > 0.0:
            pad_bounds(self.boxes.aabbs, self.boxes.radii, self.boxes.margins, rows,
                       n_static, margin / 2)

    def _candidate_pairs(self, n_dynamic, moved, changed):
        """Return the broad phase's pairs (with the loose statics' own) and the comparisons."""
        n_static = self._scene.count
        loose = self.loose
        if len(loose.rows):
            loose.work += len(loose.rows) * n_dynamic
            if loose.work > LOOSE_REBUILD_WORK * n_static:
                self._build_static_structure()
                loose = self.loose
        moved_rows = None if moved is None else moved[self.dynamic.ids]
        if changed is not None and not loose.flags[changed].all():
            # A collider moved and the phase holds it (kept in place, or rebuilt): it must
            # pair it with the bodies that kept their pose too.
            moved_rows = None
        pairs, compared = self.phase.find_pairs(self.boxes, n_static, n_dynamic, moved_rows)
        self._phase_rows = n_dynamic
        if len(loose.rows):
            pairs, loose_compared = self._loose_buffer.fill(
                _with_loose_statics, pairs, loose.flags, loose.rows, self.boxes.aabbs,
                n_static, n_static + n_dynamic)
            compared += loose_compared
        return pairs, compared

    def _checked_pairs(self, pairs):
        """Return ``pairs`` oriented, then those the filters let through (filters.py)."""
        pairs = self._oriented(pairs)
        if self._scene.filtering:
            static = self._scene.rows
            pairs = pairs[:self._scene.filter.keep_checked(
                pairs, static.count, static.ids, static.categories, static.masks,
                static.ignorable, self.dynamic.ids)]
        return pairs

    def _contacts(self, pairs, moved, changed, mode):
        """Return (contacts, SAT tests, (swept pairs, advance steps, unresolved)) of ``pairs``.

        With ``moved``, only pairs with a moved body or collider are tested; the others keep
        the last step's contacts.
        """
        if moved is not None:
            pairs = pairs[:_front_pairs_with_a_moved_body(pairs, self._scene.count,
                                                          self.dynamic.ids, moved, changed)]
        if mode == SWEPT:
            contacts, sat_tests, sweep = self._collide_swept(pairs)
        else:
            sweep = (0, 0, 0)
            status, depth, normal, point, sat_tests = self._collide(pairs)
            _check_valid(status)
            contacts = assemble_contacts(pairs, status, depth, normal, point,
                                         self._scene.count, len(self.dynamic.ids),
                                         self._scene.rows.ids, self.dynamic.ids,
                                         workers=self._workers)
        if moved is not None:
            contacts = merge_contacts(_contacts_of_still_bodies(
                self._last.result.contacts, moved,
                self._scene.rows.ids[changed[:self._scene.count]]), contacts)
        return contacts, sat_tests, sweep

    def _oriented(self, pairs):
        """Return ``pairs`` oriented (contacts.orient_pairs), by row from SORT_PAIRS_ROWS rows.

        Sorted pairs are written to a buffer of the World's, the others oriented in place.
        """
        n_static = self._scene.count
        rows = n_static + len(self.dynamic.ids)
        if rows < SORT_PAIRS_ROWS:
            orient_pairs(pairs, n_static, self.dynamic.ids, None, pairs)
            return pairs
        if len(self._pairs_by_row) < len(pairs):
            self._pairs_by_row = np.empty((int(SAT_OUTPUT_GROWTH * len(pairs)), 2), np.int64)
        if len(self._row_starts) != rows + 1:
            self._row_starts = np.empty(rows + 1, np.int64)
        out = self._pairs_by_row[:len(pairs)]
        orient_pairs(pairs, n_static, self.dynamic.ids, self._row_starts, out)
        return out

    def _continuous_mode(self, n_dynamic):
        """Return how this step is checked: OFF, SWEPT, or why it falls back to discrete."""
        if not (self._scene.options.continuous and self._may_sweep):
            return OFF
        if self._previous is None:
            return 'discrete (no previous input)'
        if len(self._previous) != n_dynamic:
            return 'discrete (pose count changed from %d to %d)' % (len(self._previous),
                                                                    n_dynamic)
        return SWEPT

    def _sweep_bounds(self, poses, half_extents):
        """Set the motion since the previous input and grow the dynamic bounds to hold it."""
        n_static, n_dynamic = self._scene.count, len(poses)
        if self._sweep.start.capacity < n_dynamic:
            capacity = 2 * n_dynamic
            self._sweep = _Sweep(Boxes(capacity), np.zeros((capacity, 3)),
                                 np.zeros((capacity, 4)))
        start, velocity, spin = self._sweep
        set_boxes(start, 0, self._previous, half_extents, self.dynamic.rows)
        motion(self._previous, poses, self.dynamic.rows, velocity, spin)
        boxes = self.boxes
        sweep_bounds(boxes.aabbs, boxes.radii, boxes.half_extents, start.aabbs, velocity, spin,
                     n_static, n_static + n_dynamic)

    def _collide_swept(self, pairs):
        """Return the contacts of ``pairs`` over the motion, the SAT tests at t = 1, the sweep's.

        (The sweep's counts: swept pairs, advance steps, unresolved pairs.)

        Conservative advancement finds each pair's toi; the pairs that touch at t = 1 get the
        contacts of the discrete SAT there, the others (touching only in between) those of
        the boxes at their toi, with depth 0.
        """
        boxes, n_static = self.boxes, self._scene.count
        n_dynamic = len(self.dynamic.ids)
        static_ids, dynamic_ids = self._scene.rows.ids, self.dynamic.ids
        start, velocity, spin = self._sweep
        options = self._scene.options
        margins = boxes.margins if self._scene.has_margins else None
        toi = np.empty(len(pairs))

        def chunk(_, first, stop):
            return advance_pairs(pairs[first:stop], n_static, boxes.centers, boxes.rotations,
                                 boxes.half_extents, start.centers, start.rotations, velocity,
                                 spin, options.margin, margins, options.tolerance,
                                 toi[first:stop])

        counts = self._workers.map_ranges(chunk, len(pairs), MIN_PAIRS_PER_CHUNK)
        hit = toi != NO_CONTACT
        pairs, toi = pairs[hit], toi[hit]
        status, depth, normal, point, sat_tests = self._collide(pairs)
        _check_valid(status)
        contacts = assemble_contacts(pairs, status, depth, normal, point, n_static, n_dynamic,
                                     static_ids, dynamic_ids, toi, self._workers)
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
                                      static_ids, dynamic_ids, toi, self._workers)
            swept['depth'] = 0.0
            contacts = merge_contacts(contacts, swept)
        return contacts, sat_tests, (int(between.sum()), sum(steps for steps, _ in counts),
                                     sum(unresolved for _, unresolved in counts))

    def _collide(self, pairs):
        """Run the SAT on ``pairs`` over the World's threads; as sat.collide_pairs returns."""
        if len(self._sat_output[0]) < len(pairs):
            self._sat_output = empty_output(int(SAT_OUTPUT_GROWTH * len(pairs)))
        boxes, options = self.boxes, self._scene.options
        margins = boxes.margins if self._scene.has_margins else None

        def chunk(_, start, stop):
            return collide_pairs(boxes.centers, boxes.rotations, boxes.half_extents,
                                 boxes.radii, pairs[start:stop], options.sphere_prefilter,
                                 [array[start:stop] for array in self._sat_output],
                                 options.margin, margins)[-1]

        sat_tests = sum(self._workers.map_ranges(chunk, len(pairs), MIN_PAIRS_PER_CHUNK))
        return tuple(array[:len(pairs)] for array in self._sat_output) + (sat_tests,)


class _Sweep(NamedTuple):
    """Each dynamic row's motion since the previous input (continuous.py)."""

    start: Boxes           # the boxes at the previous input's poses (centres, rotations, AABBs)
    velocity: np.ndarray   # (D, 3) Δc
    spin: np.ndarray       # (D, 4) unit axis and angle of the rotation


class _Loose:
    """Static rows moved since the broad phase built its structure, and not kept by it."""

    def __init__(self, count):
        self.flags = np.zeros(max(count, 1), np.bool_)  # per row (at least one, for kernels)
        self.rows = np.zeros(0, np.int64)
        self.work = 0  # AABB comparisons of loose rows since the structure was built

    def mark(self, rows, kept):
        """Record which of ``rows`` the phase kept in its structure as they are now."""
        self.flags[rows] = ~kept
        self.rows = np.flatnonzero(self.flags)


class _DynamicRows:
    """The dynamic bodies' rows: body ``ids[r]`` in dynamic row r, in Z-order of positions."""

    def __init__(self):
        self.ids = np.zeros(0, np.int64)   # body in each dynamic row
        self.rows = np.zeros(0, np.int64)  # its inverse: the row of each body
        self._sampled = np.zeros(0, np.int64)  # bodies whose travel tells when to sort again
        self._sampled_at = np.zeros((0, 3))    # their positions at the sort
        self.ticks_since_sort = 0

    def sort(self, poses):
        """Give the bodies rows in Z-order of their positions.

        The broad phase keeps what it knew of each row; a row now holding another body is to
        it a body that moved, which every phase handles (one slower tick).
        """
        self.ids = z_order(poses[:, :3])
        self.rows = inverse(self.ids)
        self._sampled = np.linspace(0, len(poses) - 1, min(Z_ORDER_SAMPLE, len(poses))
                                    ).astype(np.int64)
        self._sampled_at = poses[self._sampled, :3].copy()
        self.ticks_since_sort = 0

    def stale(self, poses, half_extents):
        """Whether the sampled bodies moved far, on average, since the rows were sorted."""
        if self.ticks_since_sort < Z_ORDER_MIN_TICKS or not len(self._sampled):
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


def _moved_bodies(last, poses, half_extents):
    """Return which bodies changed pose or size since the ``last`` step, bool (D,).

    None when there is nothing to compare with: another body count, or another size for all.
    NaN differs from everything, so a body with a NaN always counts as moved.
    """
    if last.poses.shape != poses.shape or last.half_extents.shape != half_extents.shape:
        return None
    moved = np.zeros(len(poses), np.bool_)
    _mark_changed_rows(last.poses, poses, moved)
    if half_extents.ndim == 2:
        _mark_changed_rows(last.half_extents, np.ascontiguousarray(half_extents), moved)
    elif not np.array_equal(last.half_extents, half_extents):
        return None
    return moved


def _contacts_of_still_bodies(last, moved, changed_static_ids):
    """Return the ``last`` step's contacts between bodies that did not move or change.

    Their boxes are bit for bit those of the last step, so the broad phase pairs them as then
    and the SAT would give the same bits. ``changed_static_ids``: the colliders moved or
    resized since then.
    """
    still = ~moved
    is_static = last['type_b'] == STATIC
    b_still = np.where(is_static, True, still[np.minimum(last['id_b'], len(still) - 1)])
    if len(changed_static_ids):
        b_still &= ~(is_static & np.isin(last['id_b'], changed_static_ids))
    return last[still[last['id_a']] & b_still]


def _read_only(array):
    """Return a read-only view of ``array`` (the array itself stays writeable)."""
    view = array.view()
    view.flags.writeable = False
    return view


def _check_valid(status):
    if np.any(status == INVALID):  # bounded, finite input cannot get here; never guess
        raise RuntimeError('the SAT met NaN, Inf or overflow on validated input')


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
