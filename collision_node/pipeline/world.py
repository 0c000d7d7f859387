"""The collision pipeline without ROS: boxes in, sorted contacts out.

    world = World(broad_phase='auto', sphere_prefilter=True)
    world.set_static(static_poses, static_half_extents)        # (S, 7), (S, 3); ids 0..S-1
    result = world.step(dynamic_poses, dynamic_half_extents)   # (D, 7), (D, 3) or (3,)
    world.move_static(ids, static_poses)                       # colliders by their ids

The static scene. The World owns it (static_scene.py), and changes it only through its verbs,
keyed by the colliders' stable ids: ``set_static`` (replace all), ``add_static``,
``move_static``, ``remove_static``, ``enable_static`` and ``update_static``. Each checks its
whole input first and changes nothing when it raises ValueError. From the scene the World
derives its static rows (the enabled colliders) and the broad phase's static structure.

Boxes live in one preallocated :class:`~collision_node.pipeline.obb.Boxes`: static rows first,
dynamic rows after them, both in spatial order (z_order.py). Static rows are written when the
scene's set of enabled colliders changes, and row by row when colliders move; dynamic rows each
tick, only those of the bodies that moved (the others hold last step's boxes bit for bit).
Contacts are reported by input index and collider id, and each pair is computed in the frame
of its smaller id (contacts.orient_pairs), so no bit of a result depends on the row order.

Cached state. Every change to the World draws a number from one counter, ``_version``: a
change that can alter any answer (the enabled colliders, their settings, a setting of the
World) records it as ``_rebuilt_at``; a static collider that moves stamps its row with it
(``moved_at``). The last result records the version it was computed at, and a step derives
from these numbers alone what it may keep: the whole last answer when nothing moved and no
static row was stamped since; the contacts between bodies that kept their pose (and static rows
unstamped since) otherwise; nothing when a change came after it. No change has to remember
to drop a cache.

Static boxes that move. :meth:`move_static` rewrites only their rows and tells the broad phase,
which keeps in its static structure those it can update in place (the grid and the octree a box
still in its cells, the k-d tree by a refit, sweep and prune by re-sorting its nearly sorted
lists). The others are "loose": the structure still holds them where they were, so the World
drops every pair the phase finds with a loose box and pairs each loose box with every dynamic
box itself (an AABB test per pair, :func:`_with_loose_statics`). A phase never answers for a
box it did not keep, so no structure is silently stale. Once the loose boxes cost more than
rebuilding the structure (``LOOSE_REBUILD_WORK``), the World rebuilds it and nothing is loose.
"""
import math
import time
from typing import NamedTuple

import numpy as np

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.broadphase import make_broad_phase, Settings
from collision_node.pipeline.broadphase.pair_buffer import emit, emit_if, PairBuffer
from collision_node.pipeline.contacts import (  # noqa: F401 (DYNAMIC re-exported)
    assemble_contacts, closest_contact, CONTACT_DTYPE, DYNAMIC, merge_contacts, orient_pairs,
    STATIC)
from collision_node.pipeline.continuous import (advance_pairs, boxes_at, CONTINUOUS_TOLERANCE,
                                                motion, NO_CONTACT, sweep_bounds)
from collision_node.pipeline.filters import (ALL_CATEGORIES, DEFAULT_CATEGORY, filters_nothing,
                                             PairFilter)
from collision_node.pipeline.obb import (Boxes, InvalidBox, MAX_COORDINATE, overlap_across,
                                         pad_bounds, REASONS, set_boxes)
from collision_node.pipeline.robot_bodies import (check_joint_states, DEFAULT_RESOLUTION,
                                                  first_uncleared_pieces, RobotBodies,
                                                  segment_contacts)
from collision_node.pipeline.sat import (collide_pairs, COLLIDING, empty_output, INVALID,
                                         NEAR)
from collision_node.pipeline.small_scene import (CANDIDATES, check_scene, check_states,
                                                 checked_pairs, COMPARED, FILTERED, SAT_TESTS,
                                                 STATE_CONTACT_DTYPE, statics_table)
from collision_node.pipeline.small_scene import ID as STATICS_ID, ROW as STATICS_ROW
from collision_node.pipeline.static_scene import StaticScene
from collision_node.pipeline.workers import Workers
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
# Least bodies in a chunk when their boxes are written over threads: ~35 ns a body, so ~0.3 ms
# a chunk.
MIN_BODIES_PER_CHUNK = 8192
# The broad phase's static structure is rebuilt once the loose static boxes (moved since it was
# built, and not kept by the phase) have cost, summed over the ticks since it was built, as many
# AABB comparisons (loose x dynamic boxes per tick) as its rebuild costs: this many per static
# box (a rebuild takes ~100 ns a box, a loose comparison ~1 ns). Paying for the rebuild once the
# overlay has cost as much is at most twice the cost of the better choice in hindsight (ski
# rental), whether few boxes move for many ticks or many at once.
LOOSE_REBUILD_WORK = 100


# Small scenes are checked in one compiled pass (small_scene.py) when the broad phase is one of
# these (the pass is brute force) and a tick has at most this many pairs to test, about 25 µs
# of AABB tests: the general path's stages cost ~60 µs of calls however few the bodies, and
# its broad phases catch up with testing every pair at about 4x this many (doc/benchmarks.md).
ONE_PASS_PHASES = ('auto', 'brute_force')
ONE_PASS_PAIRS = 16384
# Least states in a chunk when check_states spreads them over threads (~1 µs a state).
MIN_STATES_PER_CHUNK = 256


class Result:
    """Contacts sorted by (id_a, type_b, id_b), and the step's statistics (a dict).

    A one-pass step (small_scene.py) keeps only its counters: ``stats`` is built when it is
    first read, so a caller that never reads it never pays for it. Unpacks as (contacts, stats).
    """

    __slots__ = ('contacts', '_stats', '_counters')

    def __init__(self, contacts, stats=None, counters=None):
        self.contacts = contacts
        self._stats = stats
        # While stats is None: _one_pass_stats' arguments after the contacts, a plain tuple
        # (n_dynamic, n_static, counters, total_ms, states, reused); a NamedTuple's creation
        # cost the arm's step 0.2-0.5 µs.
        self._counters = counters

    @property
    def stats(self):
        if self._stats is None:
            self._stats = _one_pass_stats(self.contacts, *self._counters)
        return self._stats

    @property
    def continuous(self):
        """Return ``stats["continuous"]`` without building them (a one pass is never swept)."""
        return OFF if self._stats is None else self._stats['continuous']

    @property
    def phase_ms(self):
        """Return (prepare + broad, narrow) ms without building the stats; None if reused."""
        if self._stats is None:
            *_, total_ms, _, reused = self._counters
            return None if reused else (0.0, total_ms)
        stats = self._stats
        if stats['reused']:
            return None
        return stats['prepare_ms'] + stats['broad_ms'], stats['narrow_ms']

    def __iter__(self):
        return iter((self.contacts, self.stats))

    def _replace(self, stats):
        return Result(self.contacts, stats)


class Description(NamedTuple):
    """What builds a World again elsewhere (another process): plain, picklable values.

    :meth:`World.describe` gives it, :meth:`World.from_description` builds from it; the new
    World answers ``check_states``, ``check_joints`` and ``step`` as this one does, bit for bit
    (its first step has no last input to sweep from or reuse).
    """

    settings: dict     # the constructor's keyword arguments
    colliders: tuple   # static_scene.Colliders, every collider in slot order, enabled or not
    filters: tuple     # set_filters' (categories, masks, ignored_pairs) as given
    robot: object      # the Robot of set_robot, or None
    base_pose: object  # its base pose (7,), or None


class _StaticRows(NamedTuple):
    """What the World derives from the scene: one entry per static row (enabled collider)."""

    slots: np.ndarray        # the collider's slot in the scene
    ids: np.ndarray          # its id, as the cloud reports it
    categories: np.ndarray   # its collision bits
    masks: np.ndarray
    ignorable: np.ndarray    # named in an ignored pair (filters.py)
    moved_at: np.ndarray     # the version of its last move (at least one entry, for kernels)
    row_of_slot: np.ndarray  # per scene slot: its row, -1 when disabled
    own_margins: bool        # whether any collider has a margin of its own
    by_id: np.ndarray        # small_scene.statics_table: rows, ids, bits and flags by id

    @property
    def count(self):
        return len(self.ids)


class _Last(NamedTuple):
    """The last step's input and result, and the version it was computed at."""

    poses: np.ndarray
    half_extents: np.ndarray
    result: Result
    version: int


class _StatesPass:
    """What batches of states read besides their input, for one version and body count."""

    __slots__ = ('version', 'bodies', 'scene', 'own_margins', 'chunk_rows')

    def __init__(self, version, bodies, scene, own_margins, chunks):
        self.version = version
        self.bodies = bodies
        self.scene = scene  # (n_static, statics, margin, pad, sphere prefilter, filter table)
        self.own_margins = own_margins
        self.chunk_rows = [None] * chunks  # per chunk: Boxes with the static rows, then scratch


class _OnePass:
    """What one-pass steps read besides their input, for one version of the World."""

    __slots__ = ('version', 'n_static', 'arguments', 'last_poses', 'last_half_extents',
                 'half_extents_shape', 'last_valid', 'result')

    def __init__(self, version, n_static, arguments, last_poses, last_half_extents,
                 half_extents_shape):
        self.version = version
        self.n_static = n_static
        self.arguments = arguments  # check_scene's, after the input's
        self.last_poses = last_poses  # the last input checked, while last_valid[0] is 1
        self.last_half_extents = last_half_extents  # (1, 3) or (D, 3)
        self.half_extents_shape = half_extents_shape  # as the caller gives them
        self.last_valid = np.zeros(1, np.int64)
        self.result = None  # its answer


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


class World:
    """Static and dynamic oriented boxes and the broad phase that pairs them."""

    def __init__(self, broad_phase='auto', sphere_prefilter=True, octree_max_depth=0,
                 octree_leaf_cooldown_ticks=15, threads=1, margin=0.0, continuous=False,
                 continuous_tolerance=CONTINUOUS_TOLERANCE):
        """Raise ValueError on an unknown broad phase or an invalid setting."""
        self._version = 0     # the one counter every change draws from (module docstring)
        self._rebuilt_at = 0  # the last change no earlier result survives
        self._scene = StaticScene()
        self._margin = _checked_margin('margin', margin)
        self._sphere_prefilter = bool(sphere_prefilter)
        self._continuous = bool(continuous)
        self._tolerance = _checked_tolerance(continuous_tolerance)
        self._filter = PairFilter()
        self._filters_given = (DEFAULT_CATEGORY, ALL_CATEGORIES, np.zeros((0, 4), np.int64))
        self._robot = None  # robot_bodies.RobotBodies once set_robot gave one
        self._segment_pairs = (-1, None, None)  # version, robot, _robot_pairs of them
        self._workers = Workers(threads)
        self._settings = Settings(octree_max_depth, octree_leaf_cooldown_ticks)
        self._phase = make_broad_phase(broad_phase, self._settings, self._workers)
        self._phase_name = broad_phase
        self._boxes = Boxes(1024)
        self._dynamic = _DynamicRows()
        self._last = None      # _Last of the last step
        self._previous = None  # the poses of the last accepted input (the motion's start)
        self._sweep = _Sweep(Boxes(0), np.zeros((0, 3)), np.zeros((0, 4)))
        self._sat_output = empty_output(0)  # reused from tick to tick, grown as needed
        self._pairs_by_row = np.zeros((0, 2), np.int64)  # the candidate pairs, as the SAT reads
        self._row_starts = np.zeros(1, np.int64)  # their counting sort's scratch
        self._loose_buffer = PairBuffer()
        self._phase_rows = 0  # dynamic rows the phase's structure holds as they are (validate)
        self._one_pass = None  # _OnePass of the current version
        self._states_pass = None  # _StatesPass of the last batch
        self._rebuild_static()

    # ------------------------------------------------------------------ settings

    @property
    def broad_phase(self):
        return self._phase_name

    @property
    def sphere_prefilter(self):
        return self._sphere_prefilter

    @sphere_prefilter.setter
    def sphere_prefilter(self, value):
        if bool(value) != self._sphere_prefilter:
            self._sphere_prefilter = bool(value)
            self._changed()

    @property
    def margin(self):
        """Pairs whose boxes are at most this far apart (m, exact distance) are reported."""
        return self._margin

    @margin.setter
    def margin(self, value):
        margin = _checked_margin('margin', value)
        if margin != self._margin:
            self._margin = margin
            self._rebuild_static()  # the static bounds are padded by half the margin

    @property
    def continuous(self):
        """Whether pairs are checked over the motion since the last input (continuous.py)."""
        return self._continuous

    @continuous.setter
    def continuous(self, value):
        if bool(value) != self._continuous:
            self._continuous = bool(value)
            self._changed()

    @property
    def continuous_tolerance(self):
        """Metres: a continuous pair's boxes are within margin + this at its ``toi``."""
        return self._tolerance

    @continuous_tolerance.setter
    def continuous_tolerance(self, value):
        tolerance = _checked_tolerance(value)
        if tolerance != self._tolerance:
            self._tolerance = tolerance
            self._changed()

    def configure(self, broad_phase=None, octree_max_depth=None,
                  octree_leaf_cooldown_ticks=None):
        """Change the broad phase or its settings; raises ValueError on invalid values."""
        name = self._phase_name if broad_phase is None else broad_phase
        settings = self._settings._replace(**{
            key: value for key, value in (
                ('octree_max_depth', octree_max_depth),
                ('octree_leaf_cooldown_ticks', octree_leaf_cooldown_ticks))
            if value is not None})
        if name != self._phase_name or settings != self._settings:
            phase = make_broad_phase(name, settings, self._workers)  # checks name and settings
            self._phase_name, self._settings, self._phase = name, settings, phase
            self._build_static_structure()
            self._changed()

    def set_filters(self, categories=DEFAULT_CATEGORY, masks=ALL_CATEGORIES, ignored_pairs=()):
        """Set the dynamic bodies' collision bits and the pairs never to check.

        ``categories`` and ``masks``: one integer for every dynamic body, or one per body in
        input order; ``ignored_pairs``: rows ``(id_a, type_a, id_b, type_b)`` as in the cloud.
        A pair is checked only if ``category_a & mask_b`` and ``category_b & mask_a`` are both
        non-zero and it is not ignored (filters.py). Raises ValueError on invalid values.
        """
        given = (categories, masks, np.asarray(ignored_pairs, np.int64).reshape(-1, 4))
        self._set_filter(*given)
        self._filters_given = given

    def _set_filter(self, categories, masks, ignored_pairs):
        """Filter with the given settings plus the robot's self-collision pairs, if any."""
        if self._robot is not None:
            ignored_pairs = np.concatenate([ignored_pairs, self._robot.ignored_pairs])
        self._filter = PairFilter(categories, masks, ignored_pairs)
        self._set_static_rows(self._static)
        self._changed()

    # ------------------------------------------------------------------ a robot

    def set_robot(self, robot, base_pose=None):
        """Make the boxes of ``robot`` (a Robot) the dynamic bodies, its root at ``base_pose``.

        Body i is box i (``robot.box_links[i]`` its link). The robot's self-collision filter
        joins the filters of :meth:`set_filters`; ``base_pose`` (x y z qx qy qz qw, default
        the identity) may change at any time with another call. Raises ValueError on a bad
        base pose, and then nothing changes.
        """
        bodies = RobotBodies(robot, base_pose)
        previous, self._robot = self._robot, bodies
        try:
            self._set_filter(*self._filters_given)
        except ValueError:
            self._robot = previous
            raise

    def check_joints(self, q):
        """Check the robot at joint values q (dof,) or (K, dof), as :meth:`check_states`.

        State k's contacts are those :meth:`step` gives for ``robot.box_poses(q[k])`` at the
        base pose. Raises ValueError for a q of the wrong shape or with NaN or Inf (naming
        the state and joint), or without a robot (:meth:`set_robot`).
        """
        start = time.perf_counter()
        bodies = self._robot_bodies()
        states = bodies.robot._states(q)
        count = bodies.count
        if count * (count - 1) // 2 + count * self._static.count > ONE_PASS_PAIRS:
            return self.check_states(bodies.poses(states), bodies.robot.half_extents)
        model, base_pose = bodies.model_fields, bodies.base_pose
        contacts, counters = self._states_in_one_pass(
            len(states), count,
            lambda *scene: check_joint_states(model, base_pose, states, *scene))
        contacts.flags.writeable = False
        return Result(contacts, counters=(count, self._static.count, counters,
                                          1e3 * (time.perf_counter() - start), len(states),
                                          False))

    def robot_poses(self, q):
        """Return the robot's box poses at joint values q (dof,) or (K, dof): (K, B, 7).

        In the World's frame (the base pose applied): ``step(robot_poses(q)[0],
        robot.half_extents)`` checks one state as a tick, with what a step keeps between
        ticks (an unchanged state's answer reused, still boxes not tested again). Raises
        ValueError as :meth:`check_joints`.
        """
        return self._robot_bodies().poses(q)

    def check_trajectory(self, waypoints, resolution=DEFAULT_RESOLUTION):
        """Check a joint-space path: its W waypoints exactly, the segments between them safely.

        ``waypoints`` (W, dof). The contacts of waypoint k have ``state`` k and ``toi`` 0; a
        pair that is not proven free on segment k -> k + 1 (robot_bodies.py: nothing
        between waypoints is missed; a report is a collision or within ``resolution`` metres
        of motion of one) has ``state`` k and ``toi`` the fraction of the segment where its
        first piece not proven free starts, with the contact at that configuration if the
        pair collides there (else depth 0, a zero normal and ``distance`` NaN). Sorted by
        (state, id_a, type_b, id_b, toi).
        """
        bodies = self._robot_bodies()
        waypoints = bodies.robot._states(waypoints)
        resolution = _checked_margin('resolution', resolution)
        exact = self.check_joints(waypoints).contacts
        if len(waypoints) < 2:
            return Result(exact)
        version, pairs_of, arguments = self._segment_pairs
        if version != self._version or pairs_of is not bodies:  # kept while nothing changes
            arguments = self._robot_pairs(bodies)
            self._segment_pairs = (self._version, bodies, arguments)
        pairs, keys, margins, boxes = arguments
        found = first_uncleared_pieces(bodies.model_fields, bodies.base_pose, waypoints, pairs,
                                       margins, boxes, max(resolution, 1e-12))
        return Result(segment_contacts(self, bodies, waypoints, exact, found, keys))

    def _robot_bodies(self):
        if self._robot is None:
            raise ValueError('no robot: call set_robot(robot) first')
        return self._robot

    def _robot_pairs(self, bodies):
        """Return the robot's pairs the filters let through, for the segment check.

        (pairs (P, 2) rows of the boxes below, keys (P, 3) id_a, type_b, id_b, margins (P,),
        boxes (centers, rotations, half extents): B rows for the robot, then the static rows).
        """
        count, statics = bodies.count, self._static.by_id
        checked = self._filter_table(count)
        a, j = np.nonzero(np.triu(checked, 1))  # the pass's order: a, then its b's
        static = j >= count
        rows, types, ids = j.copy(), np.full(len(j), DYNAMIC, np.int64), j.copy()
        rows[static] = count + statics[j[static] - count, STATICS_ROW]
        ids[static] = statics[j[static] - count, STATICS_ID]
        types[static] = STATIC
        margins = np.full(len(j), self._margin)
        if self._static.own_margins:
            margins[static] += self._boxes.margins[rows[static] - count]
        n_static = self._static.count
        boxes = tuple(np.concatenate([np.zeros((count,) + part.shape[1:]), part[:n_static]])
                      for part in (self._boxes.centers, self._boxes.rotations,
                                   self._boxes.half_extents))
        return np.column_stack([a, rows]), np.column_stack([a, types, ids]), margins, boxes

    # ------------------------------------------------------------------ the static scene

    def set_static(self, poses, half_extents, ids=None, margins=0.0,
                   categories=DEFAULT_CATEGORY, masks=ALL_CATEGORIES):
        """Replace every static collider; ``ids`` (default 0..S-1) are reported as their id_b.

        ``poses`` (S, 7), ``half_extents`` (S, 3) or (3,); ``margins`` (m, one for all or one
        per collider) are added to the World's margin for pairs with that collider;
        ``categories`` and ``masks`` (one for all or one per collider) are its collision bits.
        """
        self._scene.replace(poses, half_extents, ids, margins, categories, masks)
        self._rebuild_static()

    def add_static(self, ids, poses, half_extents, margins=0.0, categories=DEFAULT_CATEGORY,
                   masks=ALL_CATEGORIES, enabled=True):
        """Add colliders with new ``ids`` (the others as in set_static; ``enabled`` too)."""
        self._after_scene_change(self._scene.add, ids, poses, half_extents, margins,
                                 categories, masks, enabled)

    def move_static(self, ids, poses=None, half_extents=None):
        """Give colliders ``ids`` new poses (K, 7) and/or half extents (K, 3); None: unchanged.

        They take effect from the next step; a disabled collider keeps them for when it is
        enabled. Only the rows of colliders whose pose or size differs are rewritten and
        re-tested (module docstring). Returns how many colliders changed.
        """
        slots = self._scene.move(ids, poses, half_extents)
        rows = self._static.row_of_slot[slots]
        rows = np.sort(rows[rows >= 0])  # in memory order
        if len(rows):
            self._move_static_rows(rows)
        return len(slots)

    def remove_static(self, ids):
        """Remove colliders ``ids``; their ids are free again."""
        self._after_scene_change(self._scene.remove, ids)

    def enable_static(self, ids, enabled):
        """Enable or disable colliders ``ids``: a disabled collider is kept but never checked."""
        self._after_scene_change(self._scene.enable, ids, enabled)

    def update_static(self, ids, margins=None, categories=None, masks=None):
        """Change the margins, categories or masks of colliders ``ids`` (None: unchanged)."""
        self._after_scene_change(self._scene.update, ids, margins, categories, masks)

    @property
    def static_count(self):
        """Return the number of static rows: the enabled colliders."""
        return self._static.count

    @property
    def static_colliders(self):
        """Return every collider, enabled or not, as read-only arrays (static_scene.Colliders)."""
        return self._scene.colliders

    def _after_scene_change(self, verb, *arguments):
        version = self._scene.version
        verb(*arguments)
        if self._scene.version != version:
            self._rebuild_static()

    def _rebuild_static(self):
        """Derive the static rows from the scene: the enabled colliders, in spatial order."""
        colliders = self._scene.colliders
        slots = np.flatnonzero(colliders.enabled)
        count = len(slots)
        poses = colliders.poses[slots]
        order = z_order(poses[:, :3])
        rows = inverse(order)
        # New storage: the dynamic rows are written again by the next step (a change).
        boxes = Boxes(count + self._boxes.capacity)
        set_boxes(boxes, 0, poses, colliders.half_extents[slots], rows)
        margins = colliders.margins[slots]
        boxes.margins[:count] = margins[order]
        own_margins = bool(np.any(margins > 0.0))
        if self._margin > 0.0 or own_margins:  # padding with 0 changes no bit
            pad_bounds(boxes.aabbs, boxes.radii, boxes.margins, rows, 0, self._margin / 2)
        row_of_slot = np.full(len(colliders.ids), -1, np.int64)
        row_of_slot[slots] = rows
        in_rows = slots[order]
        self._boxes = boxes
        self._set_static_rows(_StaticRows(
            in_rows, colliders.ids[in_rows], colliders.categories[in_rows],
            colliders.masks[in_rows], np.zeros(count, np.bool_),
            np.zeros(max(count, 1), np.int64), row_of_slot, own_margins, None))
        self._build_static_structure()
        self._changed()

    def _set_static_rows(self, static):
        """Take ``static`` as the static rows, with its ignorable flags for the filter."""
        flags = self._filter.static_ignorable
        ignorable = np.zeros(static.count, np.bool_) if not len(flags) else \
            flags[np.minimum(static.ids, len(flags) - 1)] & (static.ids < len(flags))
        self._static = static._replace(ignorable=ignorable, by_id=statics_table(
            static.ids, static.categories, static.masks, ignorable))
        self._filtering = not (self._filter.is_default
                               and filters_nothing(static.categories, static.masks))

    def _move_static_rows(self, rows):
        """Write the moved static ``rows`` from the scene and tell the broad phase."""
        colliders = self._scene.colliders
        slots = self._static.slots[rows]
        _write_bodies(self._boxes, 0, colliders.poses[slots], colliders.half_extents[slots],
                      rows, slice(None), self._workers)
        if self._margin > 0.0 or self._static.own_margins:
            pad_bounds(self._boxes.aabbs, self._boxes.radii, self._boxes.margins, rows, 0,
                       self._margin / 2)
        self._loose.mark(rows, self._phase.move_static(self._boxes, rows))
        self._version += 1
        self._static.moved_at[rows] = self._version

    def _build_static_structure(self):
        """Let the broad phase build its static structure from the current boxes."""
        self._phase.set_static(self._boxes, self._static.count)
        self._loose = _Loose(self._static.count)
        self._phase_rows = 0

    def _changed(self):
        """Record a change after which no earlier result holds (module docstring)."""
        self._version += 1
        self._rebuilt_at = self._version

    # ------------------------------------------------------------------ a step

    def step(self, poses, half_extents):
        """Collide the dynamic boxes (poses (D, 7), half extents (D, 3) or (3,)).

        Raises ValueError naming the first invalid dynamic body; then nothing is reported.
        An input identical to the previous one returns the previous result again; pairs of
        bodies that kept their pose and size since the previous step keep their contacts
        without a SAT. The result's contacts are read-only: later steps reuse them.
        """
        start = time.perf_counter()
        one_pass = self._one_pass
        # The one pass as last time (a robot's tick): the input as it was, gathered arguments.
        if one_pass is not None and one_pass.version == self._version \
                and type(poses) is np.ndarray and poses.shape == one_pass.last_poses.shape \
                and type(half_extents) is np.ndarray \
                and half_extents.shape == one_pass.half_extents_shape \
                and poses.dtype == half_extents.dtype == np.float64 \
                and poses.flags.c_contiguous and half_extents.flags.c_contiguous \
                and poses.flags.writeable and half_extents.flags.writeable:
            return self._one_pass_step(poses, half_extents, one_pass, start)
        poses = _as_poses(poses)
        half_extents = np.asarray(half_extents, dtype=np.float64)
        n = len(poses)
        if not self._continuous and self._phase_name in ONE_PASS_PHASES \
                and n * (n - 1) // 2 + n * self._static.count <= ONE_PASS_PAIRS:
            extents = _per_body_extents(half_extents, n)
            if one_pass is None or one_pass.version != self._version \
                    or one_pass.last_poses.shape != poses.shape \
                    or one_pass.half_extents_shape != half_extents.shape:
                one_pass = self._one_pass = self._new_one_pass(n, extents, half_extents.shape)
            return self._one_pass_step(poses, extents, one_pass, start)
        self._filter.check_count(len(poses))
        last = self._last if self._last is not None \
            and self._last.version >= self._rebuilt_at else None
        # Continuous: every pair is swept over its motion, so no contact is kept from the
        # last step (its toi belonged to that step's motion).
        moved = None if self._continuous or last is None else \
            _moved_bodies(last, poses, half_extents)
        # Static rows moved since the last step (bool per row, at least one; None: no step).
        changed = None if last is None else self._static.moved_at > last.version
        if moved is not None and not moved.any() and not changed.any():
            return last.result._replace(stats=dict(last.result.stats, reused=True))
        if moved is not None and moved.all():
            moved = None  # nothing to keep: the plain path
        n_dynamic = len(poses)
        mode = self._continuous_mode(n_dynamic)
        self._write_dynamic_rows(poses, half_extents, moved, mode)
        prepared = time.perf_counter()

        stats = {'broad_phase': self._phase.name, 'dynamic_bodies': n_dynamic,
                 'static_bodies': self._static.count, 'compared': 0, 'candidate_pairs': 0,
                 'filtered_pairs': 0, 'sat_tests': 0, 'colliding_pairs': 0, 'near_pairs': 0,
                 'min_distance': math.nan, 'min_distance_pair': None, 'reused': False,
                 'still_bodies': 0 if moved is None else int(n_dynamic - moved.sum()),
                 'continuous': mode, 'swept_pairs': 0, 'advance_steps': 0,
                 'unresolved_pairs': 0, 'broad_phase_stats': {}}
        if n_dynamic == 0:  # nothing moves: nothing to pair
            contacts = np.zeros(0, CONTACT_DTYPE)
            broad_done = narrow_done = prepared
        else:
            pairs, compared = self._candidate_pairs(n_dynamic, moved, changed)
            stats['broad_phase'] = self._phase.name
            stats['broad_phase_stats'] = dict(self._phase.stats)
            broad_done = time.perf_counter()
            candidates = len(pairs)
            pairs = self._checked_pairs(pairs)
            checked = len(pairs)
            contacts, sat_tests = self._contacts(pairs, moved, changed, mode, stats)
            narrow_done = time.perf_counter()
            stats.update(compared=int(compared), candidate_pairs=candidates,
                         filtered_pairs=candidates - checked, sat_tests=int(sat_tests),
                         **_distance_stats(contacts))
        stats.update(prepare_ms=1e3 * (prepared - start), broad_ms=1e3 * (broad_done - prepared),
                     narrow_ms=1e3 * (narrow_done - broad_done),
                     total_ms=1e3 * (time.perf_counter() - start))
        contacts.flags.writeable = False
        result = Result(contacts, stats)
        self._last = _Last(poses.copy(), half_extents.copy(), result, self._version)
        self._previous = self._last.poses
        return result

    def _one_pass_step(self, poses, half_extents, one_pass, start):
        """Check a small scene in one compiled pass (small_scene.py): step's answer, to the bit.

        What the pass reads besides the input was gathered for this version of the World
        (:class:`_OnePass`); an input identical to the last one returns its answer again. The
        general path keeps nothing of a one-pass step: the rows it writes are its to rewrite.
        """
        if half_extents.ndim == 1:
            half_extents = half_extents.reshape(1, 3)
        contacts, counters, bad, code, invalid, same = check_scene(
            poses, half_extents,
            one_pass.last_poses, one_pass.last_half_extents, one_pass.last_valid,
            *one_pass.arguments)
        if same:
            last = one_pass.result
            return Result(last.contacts, counters=last._counters[:-1] + (True,))
        self._last = None  # the general path's coherence: its rows were overwritten
        self._phase_rows = 0
        if bad >= 0:
            raise InvalidBox(int(bad), REASONS[code])
        if invalid:
            raise RuntimeError('the SAT met NaN, Inf or overflow on validated input')
        contacts.flags.writeable = False
        one_pass.result = Result(contacts, counters=(
            len(poses), one_pass.n_static, counters, 1e3 * (time.perf_counter() - start), None,
            False))
        self._previous = one_pass.last_poses  # where a continuous step would sweep from
        return one_pass.result

    def _new_one_pass(self, count, extents, given_shape):
        """Gather what one-pass steps of ``count`` bodies read besides their input."""
        self._filter.check_count(count)
        n_static = self._static.count
        if n_static + count > self._boxes.capacity:
            self._boxes = self._boxes.grown(2 * (n_static + count), n_static)
            self._build_static_structure()
        boxes = self._boxes
        arguments = (n_static, self._static.by_id, boxes.centers, boxes.rotations,
                     boxes.half_extents, boxes.aabbs, boxes.radii, *self._margin_arguments(),
                     self._sphere_prefilter, self._filter_table(count))
        return _OnePass(self._version, n_static, arguments, np.empty((count, 7)),
                        np.empty(extents.shape), given_shape)

    def _filter_table(self, count):
        """Return small_scene.checked_pairs for ``count`` bodies (all True: no filter at all).

        A table even without filters, not None: the one pass then compiles one variant
        fewer (half a first start's compile of it), for a load per candidate pair.
        """
        if not self._filtering:
            return np.ones((count, count + len(self._static.by_id)), np.bool_)
        filters = self._filter
        return checked_pairs(count, self._static.by_id, filters.categories, filters.masks,
                             filters.ignored_keys, filters.dynamic_ignorable)

    def _margin_arguments(self):
        """Return (box margins or None, margin or None, bound padding) for the SAT kernels.

        No margin at all: (None, None, 0). Any margin: the box margins too, as the general
        path passes them, even when no collider has one of its own (it adds 0.0: no bit
        changes): one compiled variant of the one pass fewer.
        """
        if self._margin == 0.0 and not self._static.own_margins:
            return None, None, 0.0
        return self._boxes.margins, self._margin, self._margin / 2

    def check_states(self, states, half_extents):
        """Check K independent states of the D dynamic bodies against the static scene.

        ``states`` (K, D, 7) poses, ``half_extents`` (D, 3) or (3,). Each state is checked as
        a step of that state alone would check it, with the filters and margins (at its poses:
        a state has no motion to sweep), and its contacts carry its index in the field
        ``state``; they are sorted by (state, id_a, type_b, id_b). No step's state is read or
        changed. Raises ValueError naming the state and body of the first invalid pose; then
        nothing is reported. Small scenes are checked in one compiled pass spread over the
        World's threads, larger ones state after state by a World of their own.
        """
        start = time.perf_counter()
        states = np.require(states, np.float64, ['C', 'A', 'W'])
        if states.ndim != 3 or states.shape[2] != 7:
            raise ValueError('states must have shape (K, D, 7): K states of D poses '
                             'x y z qx qy qz qw, got %s' % (states.shape,))
        count, bodies = states.shape[:2]
        extents = _per_body_extents(np.asarray(half_extents, np.float64), bodies)
        self._filter.check_count(bodies)
        if bodies * (bodies - 1) // 2 + bodies * self._static.count > ONE_PASS_PAIRS:
            contacts, counters = self._states_one_by_one(states, extents)
        else:
            poses = states.reshape(-1, 7)
            contacts, counters = self._states_in_one_pass(
                count, bodies, lambda *scene: check_states(poses, bodies, extents, *scene))
        contacts.flags.writeable = False
        return Result(contacts, counters=(bodies, self._static.count, counters,
                                          1e3 * (time.perf_counter() - start), count, False))

    def _states_in_one_pass(self, count, bodies, check):
        """Return the contacts and counters of ``count`` small states, chunks over threads.

        ``check(*arguments)`` runs small_scene.check_states (or a kernel that ends in it) on
        its static arguments, a chunk's box rows and the chunk's range of states.
        """
        states_pass = self._states_pass
        if states_pass is None or states_pass.version != self._version \
                or states_pass.bodies != bodies:
            box_margins, margin, pad = self._margin_arguments()
            scene = (self._static.count, self._static.by_id, margin, pad, self._sphere_prefilter,
                     self._filter_table(bodies))
            states_pass = self._states_pass = _StatesPass(
                self._version, bodies, scene, box_margins is not None, self._workers.max_chunks)

        def chunk(index, first, stop):
            # Each chunk writes its states' boxes to rows of its own, after a copy of the
            # static rows (kept for the next batch of this version).
            n_static, statics, margin, pad, prefilter, checked = states_pass.scene
            rows = states_pass.chunk_rows[index]
            if rows is None:
                rows = states_pass.chunk_rows[index] = self._boxes.grown(n_static + bodies,
                                                                         n_static)
            return check(n_static, statics, rows.centers, rows.rotations, rows.half_extents,
                         rows.aabbs, rows.radii, rows.margins if states_pass.own_margins
                         else None, margin, pad, prefilter, checked, first, stop)

        parts = self._workers.map_ranges(chunk, count, MIN_STATES_PER_CHUNK)
        for contacts, _, state, body, code, invalid in parts:
            if state >= 0 and body >= 0:
                raise ValueError('state %d: dynamic body %d: %s' % (state, body, REASONS[code]))
            if invalid:
                raise RuntimeError('the SAT met NaN, Inf or overflow on validated input')
        contacts = parts[0][0] if len(parts) == 1 else np.concatenate([p[0] for p in parts])
        return contacts, sum(part[1] for part in parts)

    def _states_one_by_one(self, states, extents):
        """Return the contacts and counters of large ``states``, stepped by a World of its own.

        Consecutive states keep what did not change between them, as ticks do; the World's
        own steps are not touched. That World is built from this one's description (no private
        field set from outside), discrete: a state has no motion to sweep.
        """
        world = World.from_description(self.describe(), continuous=False)
        try:
            found, counters = [], np.zeros(4, np.int64)
            for state, poses in enumerate(states):
                try:
                    result = world.step(poses, extents if len(extents) > 1 else extents[0])
                except InvalidBox as error:
                    raise ValueError('state %d: dynamic body %d: %s'
                                     % (state, error.body, error.reason)) from None
                rows = np.empty(len(result.contacts), STATE_CONTACT_DTYPE)
                for name in CONTACT_DTYPE.names:
                    rows[name] = result.contacts[name]
                rows['state'] = state
                found.append(rows)
                stats = result.stats
                counters += (stats['compared'], stats['candidate_pairs'],
                             stats['filtered_pairs'], stats['sat_tests'])
        finally:
            world.close()
        contacts = np.concatenate(found) if found else np.zeros(0, STATE_CONTACT_DTYPE)
        return contacts, counters

    def _write_dynamic_rows(self, poses, half_extents, moved, mode):
        """Write the rows of the bodies that ``moved`` (None: all), their sweep and padding."""
        n_static, n_dynamic = self._static.count, len(poses)
        written = moved  # the bodies whose rows are written (None: all)
        if n_static + n_dynamic > self._boxes.capacity:
            self._boxes = self._boxes.grown(2 * (n_static + n_dynamic), n_static)
            self._build_static_structure()
            self._version += 1  # new storage: a one-pass step gathers it again
            written = None  # the dynamic rows were not copied
        self._dynamic.ticks_since_sort += 1
        if len(self._dynamic.ids) != n_dynamic or self._dynamic.stale(poses, half_extents):
            self._dynamic.sort(poses)
            written = None  # rows now hold other bodies
        bodies = slice(None) if written is None else np.flatnonzero(written)
        try:
            rows = _write_bodies(self._boxes, n_static, poses, half_extents, self._dynamic.rows,
                                 bodies, self._workers)
        except InvalidBox:
            self._changed()  # rows before the refused body hold its input: rewrite them all
            self._phase_rows = 0
            raise
        if mode == SWEPT:
            self._sweep_bounds(poses, half_extents)
        if self._margin > 0.0:
            pad_bounds(self._boxes.aabbs, self._boxes.radii, self._boxes.margins, rows,
                       n_static, self._margin / 2)

    def _candidate_pairs(self, n_dynamic, moved, changed):
        """Return the broad phase's pairs (with the loose statics' own) and the comparisons."""
        n_static = self._static.count
        loose = self._loose
        if len(loose.rows):
            loose.work += len(loose.rows) * n_dynamic
            if loose.work > LOOSE_REBUILD_WORK * n_static:
                self._build_static_structure()
                loose = self._loose
        moved_rows = None if moved is None else moved[self._dynamic.ids]
        if changed is not None and not loose.flags[changed].all():
            # A collider moved and the phase holds it (kept in place, or rebuilt): it must
            # pair it with the bodies that kept their pose too.
            moved_rows = None
        pairs, compared = self._phase.find_pairs(self._boxes, n_static, n_dynamic, moved_rows)
        self._phase_rows = n_dynamic
        if len(loose.rows):
            pairs, loose_compared = self._loose_buffer.fill(
                _with_loose_statics, pairs, loose.flags, loose.rows, self._boxes.aabbs,
                n_static, n_static + n_dynamic)
            compared += loose_compared
        return pairs, compared

    def _checked_pairs(self, pairs):
        """Return ``pairs`` oriented, then those the filters let through (filters.py)."""
        pairs = self._oriented(pairs)
        if self._filtering:
            static = self._static
            pairs = pairs[:self._filter.keep_checked(
                pairs, static.count, static.ids, static.categories, static.masks,
                static.ignorable, self._dynamic.ids)]
        return pairs

    def _contacts(self, pairs, moved, changed, mode, stats):
        """Return (contacts, SAT tests) of the checked ``pairs``.

        With ``moved``, only pairs with a moved body or collider are tested; the others keep
        the last step's contacts.
        """
        if moved is not None:
            pairs = pairs[:_front_pairs_with_a_moved_body(pairs, self._static.count,
                                                          self._dynamic.ids, moved, changed)]
        if mode == SWEPT:
            contacts, sat_tests = self._collide_swept(pairs, stats)
        else:
            status, depth, normal, point, sat_tests = self._collide(pairs)
            _check_valid(status)
            contacts = assemble_contacts(pairs, status, depth, normal, point,
                                         self._static.count, len(self._dynamic.ids),
                                         self._static.ids, self._dynamic.ids,
                                         workers=self._workers)
        if moved is not None:
            contacts = merge_contacts(_contacts_of_still_bodies(
                self._last.result.contacts, moved,
                self._static.ids[changed[:self._static.count]]), contacts)
        return contacts, sat_tests

    def _oriented(self, pairs):
        """Return ``pairs`` oriented (contacts.orient_pairs), by row from SORT_PAIRS_ROWS rows.

        Sorted pairs are written to a buffer of the World's, the others oriented in place.
        """
        n_static = self._static.count
        rows = n_static + len(self._dynamic.ids)
        if rows < SORT_PAIRS_ROWS:
            orient_pairs(pairs, n_static, self._dynamic.ids, None, pairs)
            return pairs
        if len(self._pairs_by_row) < len(pairs):
            self._pairs_by_row = np.empty((int(SAT_OUTPUT_GROWTH * len(pairs)), 2), np.int64)
        if len(self._row_starts) != rows + 1:
            self._row_starts = np.empty(rows + 1, np.int64)
        out = self._pairs_by_row[:len(pairs)]
        orient_pairs(pairs, n_static, self._dynamic.ids, self._row_starts, out)
        return out

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
        n_static, n_dynamic = self._static.count, len(poses)
        if self._sweep.start.capacity < n_dynamic:
            capacity = 2 * n_dynamic
            self._sweep = _Sweep(Boxes(capacity), np.zeros((capacity, 3)),
                                 np.zeros((capacity, 4)))
        start, velocity, spin = self._sweep
        set_boxes(start, 0, self._previous, half_extents, self._dynamic.rows)
        motion(self._previous, poses, self._dynamic.rows, velocity, spin)
        boxes = self._boxes
        sweep_bounds(boxes.aabbs, boxes.radii, boxes.half_extents, start.aabbs, velocity, spin,
                     n_static, n_static + n_dynamic)

    def _collide_swept(self, pairs, stats):
        """Return the contacts of ``pairs`` over the motion, and the SAT tests at t = 1.

        Conservative advancement finds each pair's toi; the pairs that touch at t = 1 get the
        contacts of the discrete SAT there, the others (touching only in between) those of
        the boxes at their toi, with depth 0.
        """
        boxes, n_static = self._boxes, self._static.count
        n_dynamic = len(self._dynamic.ids)
        static_ids, dynamic_ids = self._static.ids, self._dynamic.ids
        start, velocity, spin = self._sweep
        margins = boxes.margins if self._margin > 0.0 or self._static.own_margins else None
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
        stats.update(swept_pairs=int(between.sum()),
                     advance_steps=sum(steps for steps, _ in counts),
                     unresolved_pairs=sum(unresolved for _, unresolved in counts))
        return contacts, sat_tests

    def _collide(self, pairs):
        """Run the SAT on ``pairs`` over the World's threads; as sat.collide_pairs returns."""
        if len(self._sat_output[0]) < len(pairs):
            self._sat_output = empty_output(int(SAT_OUTPUT_GROWTH * len(pairs)))
        boxes = self._boxes
        margins = boxes.margins if self._margin > 0.0 or self._static.own_margins else None

        def chunk(_, start, stop):
            return collide_pairs(boxes.centers, boxes.rotations, boxes.half_extents,
                                 boxes.radii, pairs[start:stop], self._sphere_prefilter,
                                 [array[start:stop] for array in self._sat_output],
                                 self._margin, margins)[-1]

        sat_tests = sum(self._workers.map_ranges(chunk, len(pairs), MIN_PAIRS_PER_CHUNK))
        return tuple(array[:len(pairs)] for array in self._sat_output) + (sat_tests,)

    # ------------------------------------------------------------------ checks and cleanup

    def validate(self):
        """Check the whole World (for testing): raise AssertionError naming what is wrong.

        The scene itself, the static rows derived from it (the enabled colliders, each row's
        box written from its collider's pose and size), the loose rows, and the broad phase's
        own structure (its static part; its dynamic part as of its last pairs, unless rows
        were written since without it).
        """
        self._scene.validate()
        colliders = self._scene.colliders
        static = self._static
        enabled = np.flatnonzero(colliders.enabled)
        assert np.array_equal(np.sort(static.slots), enabled), \
            'the static rows are not the enabled colliders'
        assert np.array_equal(static.row_of_slot[static.slots], np.arange(static.count)), \
            'row_of_slot does not invert the rows'
        assert np.all(static.row_of_slot[~colliders.enabled] == -1), 'a disabled row'
        assert np.array_equal(static.ids, colliders.ids[static.slots]), 'a row has another id'
        assert np.array_equal(static.categories, colliders.categories[static.slots]) and \
            np.array_equal(static.masks, colliders.masks[static.slots]), 'stale filter bits'
        expected = Boxes(static.count)
        set_boxes(expected, 0, colliders.poses[static.slots],
                  colliders.half_extents[static.slots])
        for name in ('centers', 'rotations', 'half_extents'):
            assert np.array_equal(getattr(expected, name),
                                  getattr(self._boxes, name)[:static.count]), \
                'a static row holds another %s than its collider' % name
        assert np.array_equal(self._boxes.margins[:static.count],
                              colliders.margins[static.slots]), 'a static row has another margin'
        assert np.array_equal(self._loose.rows, np.flatnonzero(self._loose.flags)), \
            'loose rows and flags disagree'
        self._phase.validate(self._boxes, static.count, self._phase_rows, self._loose.flags)

    def describe(self):
        """Return a :class:`Description` of this World: settings, colliders, filters, robot."""
        settings = {
            'broad_phase': self._phase_name, 'sphere_prefilter': self._sphere_prefilter,
            'octree_max_depth': self._settings.octree_max_depth,
            'octree_leaf_cooldown_ticks': self._settings.octree_leaf_cooldown_ticks,
            'threads': self._workers.threads, 'margin': self._margin,
            'continuous': self._continuous, 'continuous_tolerance': self._tolerance}
        robot = self._robot
        return Description(settings, tuple(np.array(part) for part in self._scene.colliders),
                           self._filters_given, robot and robot.robot,
                           robot and np.array(robot.base_pose))

    @classmethod
    def from_description(cls, description, **settings):
        """Build a World from :meth:`describe`'s answer; ``settings`` override its settings."""
        world = cls(**{**description.settings, **settings})
        ids, poses, half_extents, margins, categories, masks, enabled = description.colliders
        world.add_static(ids, poses, half_extents, margins, categories, masks, enabled)
        world.set_filters(*description.filters)
        if description.robot is not None:
            world.set_robot(description.robot, description.base_pose)
        return world

    def close(self):
        """Stop the World's helper threads (none with ``threads=1``)."""
        self._workers.close()


def _as_poses(poses):
    """Return ``poses`` as a writable C-contiguous float64 (N, 7) array (no copy if it is)."""
    if type(poses) is not np.ndarray or poses.dtype != np.float64 or poses.ndim != 2 \
            or not poses.flags.c_contiguous or not poses.flags.writeable:
        # Writable too: numba compiles a read-only array (a message's bytes) apart.
        poses = np.require(poses, np.float64, ['C', 'A', 'W']).reshape(-1, 7)
    if poses.shape[1] != 7:
        raise ValueError('poses must have shape (N, 7) as x y z qx qy qz qw, got %s'
                         % (poses.shape,))
    return poses


def _per_body_extents(half_extents, count):
    """Return half extents (3,) as one row (1, 3), or (count, 3) as they are; else refuse."""
    if half_extents.shape == (3,):
        return np.require(half_extents, np.float64, ['C', 'A', 'W']).reshape(1, 3)
    if half_extents.shape != (count, 3):
        raise ValueError('half extents must have shape (3,) or (%d, 3), got %s'
                         % (count, half_extents.shape))
    return np.require(half_extents, np.float64, ['C', 'A', 'W'])


def _one_pass_stats(contacts, n_dynamic, n_static, counters, total_ms, states, reused):
    """Return the stats dict of a one-pass step (or check_states), as step's stats read."""
    stats = {'broad_phase': 'brute_force', 'dynamic_bodies': n_dynamic,
             'static_bodies': n_static, 'compared': int(counters[COMPARED]),
             'candidate_pairs': int(counters[CANDIDATES]),
             'filtered_pairs': int(counters[FILTERED]), 'sat_tests': int(counters[SAT_TESTS]),
             'reused': reused, 'still_bodies': 0, 'continuous': OFF, 'swept_pairs': 0,
             'advance_steps': 0, 'unresolved_pairs': 0, 'broad_phase_stats': {},
             'prepare_ms': 0.0, 'broad_ms': 0.0, 'narrow_ms': total_ms,
             'total_ms': total_ms}
    stats.update(_distance_stats(contacts))
    if states is not None:
        stats['states'] = states
    return stats


def _checked_tolerance(value):
    tolerance = float(value)
    if not 0.0 < tolerance <= MAX_COORDINATE:  # also refuses NaN
        raise ValueError('continuous tolerance must be in (0, %g] m, got %r'
                         % (MAX_COORDINATE, value))
    return tolerance


def _checked_margin(name, value):
    margin = float(value)
    if not 0.0 <= margin <= MAX_COORDINATE:  # also refuses NaN
        raise ValueError('%s must be in [0, %g] m, got %r' % (name, MAX_COORDINATE, value))
    return margin


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
