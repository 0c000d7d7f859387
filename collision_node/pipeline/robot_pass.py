"""The robot's pass: joint values to contacts in one compiled call, forward kinematics included.

A robot's boxes are few, and which of their pairs are tested is known before any state: its
self-collision filter and the World's filters leave a fixed list of pairs (:class:`RobotRows`,
in the cloud's order), less the pairs the robot's reach keeps apart at any joint values
(:func:`_may_come_near`). So this pass does not pair the boxes as the one pass does (every pair's
AABBs, then the filter table). LANES states at a time, it

1. runs their forward kinematics to the link frames (robot.lane_transforms: the states
   innermost, as vectors) and places each box's centre;
2. visits the listed pairs with culls that read only centres, every lane at once: the
   bounding spheres of two robot boxes, or a robot box's sphere against a static box, first
   its AABB, then the box itself (the distance from the centre to the box: a large table's
   bounding sphere would reach every box of the robot above it, the table itself few);
3. then, state by state, orients a box (the quaternion of its pose, then the rotation and
   AABB a step makes of it: obb.box_axes) only when a pair of it passed, once per state,
   compares the pair's AABBs, hands the pairs left to the one pass's SAT loop
   (sat.collide_pair_rows) and writes the reported ones as the state's contacts, in the
   list's order.

Exactness. A cull drops a pair only when its boxes are apart by more than the margin and the SAT's
touching tolerance, so it never drops a pair the SAT would report; and the SAT tests the boxes a
step builds from robot.box_poses (the same centre, quaternion and rotation, bit for bit:
robot.lane_transforms is link_transforms' arithmetic, in the same order). So each state's contacts
are World.step's on its box poses, to the bit. The counters differ: ``compared`` counts every pair
of a state, ``filtered_pairs`` those the filters leave out, ``candidate_pairs`` the listed pairs
the culls left and ``sat_tests`` the SATs run on them.

Cost (the Panda over a table, a wall and a shelf: 86 listed pairs, about 6 left by the culls; AMD
EPYC VM, 4,000 states in one call, each part measured by stopping the kernel after it): 0.87 µs a
state, of which the forward kinematics 0.14, the centres 0.02, the culls 0.18, the orienting, AABBs
and SAT the rest. One state at a time, with libm's sine and cosine, the forward kinematics and
centres took 0.43-0.48 and the culls 0.34-0.37. For one state per call, entering and setting up the
call cost as much as the state, so the kernel takes one workspace of two flat arrays
(:func:`_workspace`, made once per scene version): the packed model (robot.pack_model), the base
pose, the pairs and settings, the rows and the scratch. numba unboxes each array argument on every
call (15 model arrays cost 2 µs, the workspace's two 0.3 µs), a call that allocated its rows and
scratch spent more setting up than checking, and its parts are views (flat_views.view) made without
numba's reshape.
"""
import math
import time

import numpy as np

from collision_node.pipeline._jit import inlined_kernel, kernel
from collision_node.pipeline.contacts import DYNAMIC, STATE_CONTACT_DTYPE, STATIC, write_contact
from collision_node.pipeline.flat_views import copy_into, view
from collision_node.pipeline.frames import (dot, matrix, placed, quaternion_product,
                                            squared_distance_outside, turned)
from collision_node.pipeline.obb import (aabbs_overlap, box_axes, EPS, MAX_COORDINATE,
                                         NON_FINITE_POSE, OUT_OF_RANGE, TIE_ULPS, VALID)
from collision_node.pipeline.robot import (lane_quaternion, lane_rotation, lane_transforms,
                                           lane_vector, NO_INDEX, packed_sizes, unpack_model)
from collision_node.pipeline.sat import collide_pair_rows, COLLIDING, INVALID, NEAR
from collision_node.pipeline.small_scene import ID as STATICS_ID, ROW as STATICS_ROW
from collision_node.pipeline.stats import one_pass_stats, Result

# Columns of RobotRows.static_boxes: a static row's box as the scene rows hold it.
CENTER, ROTATION, EXTENTS, LOW, HIGH, RADIUS, OWN_MARGIN = 0, 3, 12, 15, 18, 21, 22
STATIC_COLUMNS = 23
# Floats of one row in a workspace: centre, rotation, half extents, AABB, radius, margin.
ROW_FLOATS = 3 + 9 + 3 + 6 + 1 + 1
# Entries of RobotRows.settings.
MARGIN, PAD, HAS_MARGIN = range(3)
# Floats of a workspace between the model and the rows: the base pose, the settings and the
# culls' rounding bounds (the largest radius with a static margin and half extents, the
# largest sum of a static centre's |coordinates|).
BASE_POSE, SETTINGS, WIDEST, FARTHEST_STATIC, ROWS = 0, 7, 10, 11, 12
# The "body" of a failed state whose q holds a NaN or Inf.
NON_FINITE_JOINT = -2
# States whose forward kinematics and culls run together (robot.lane_transforms): 8 float64
# are one AVX-512 register, two AVX2 ones.
LANES = 8
# A lane's failure before its SAT: its q holds a NaN or Inf; a box centre is not finite or
# beyond MAX_COORDINATE.
BAD_JOINT, BAD_CENTER = 1, 2
# check_robot_states' boxes when they are not kept.
NOT_KEPT = (np.empty((0, 3, 0)), np.empty((0, 9, 0)), np.empty((0, 0)))


class RobotRows:
    """The robot's listed pairs and the static boxes, for one scene version and robot.

    ``pairs`` (P, 2): rows of the pass's boxes (robot box a, then row b: a robot box, or
    B + the static row), in the cloud's order; ``keys`` (P, 3) each pair's (id_a, type_b,
    id_b); ``margins`` (P,) the distance within which each pair counts; ``motion_radii``
    (P, dof) (Robot.pair_motion_radii); ``boxes`` (centers, rotations, half extents): B rows
    for the robot (written by a check), then the static rows; ``settings`` (margin, pad, margin
    given) what the pass reads of the scene besides its rows, which each workspace holds.
    """

    def __init__(self, scene, bodies):
        """Gather what ``bodies`` (robot_bodies.RobotBodies) are checked against in ``scene``."""
        count, statics = bodies.count, scene.rows.by_id
        self.version, self.bodies = scene.version, bodies
        boxes, n_static = scene.boxes, scene.count
        # The static rows padded as the one pass reads them (scene_rows.SceneRows.pass_rows).
        padded = scene.pass_rows(0)
        table = np.empty((n_static, STATIC_COLUMNS))
        table[:, CENTER:ROTATION] = padded[0][:n_static]
        table[:, ROTATION:EXTENTS] = padded[1][:n_static].reshape(-1, 9)
        table[:, EXTENTS:LOW] = padded[2][:n_static]
        table[:, LOW:RADIUS] = padded[3][:n_static].reshape(-1, 6)
        table[:, RADIUS] = padded[4][:n_static]
        table[:, OWN_MARGIN] = boxes.margins[:n_static] if scene.rows.own_margins else 0.0
        margin, pad = scene.pass_options(count)[:2]
        self.settings = np.array([0.0 if margin is None else margin, pad,
                                  0.0 if margin is None else 1.0])
        a, j = np.nonzero(np.triu(scene.filter_table(count), 1))  # the pass's order
        self.filtered = count * (count - 1) // 2 + count * n_static - len(j)  # filters' pairs
        static = j >= count
        rows, types, ids = j.copy(), np.full(len(j), DYNAMIC, np.int64), j.copy()
        rows[static] = count + statics[j[static] - count, STATICS_ROW]
        ids[static] = statics[j[static] - count, STATICS_ID]
        types[static] = STATIC
        near = _may_come_near(bodies, a, rows, table, pad)
        a, j, rows, types, ids, static = a[near], j[near], rows[near], types[near], ids[near], \
            static[near]
        self.pairs = np.column_stack([a, rows]).astype(np.int64)
        self.keys = np.column_stack([a, types, ids]).astype(np.int64)
        self.margins = np.full(len(j), scene.options.margin)
        if scene.rows.own_margins:
            self.margins[static] += boxes.margins[rows[static] - count]
        self.motion_radii = bodies.robot.pair_motion_radii(a, np.where(static, -1, j))
        self.boxes = tuple(np.concatenate([np.zeros((count,) + part.shape[1:]), part[:n_static]])
                           for part in (boxes.centers, boxes.rotations, boxes.half_extents))
        self.n_static = n_static
        self.all_pairs = count * (count - 1) // 2 + count * n_static
        self.one_state = (bodies.robot.dof,)  # the shape of one state's q
        # The pass's arguments, rows and scratch in two arrays, one pair per chunk of states
        # (Workers.map_ranges): made once per scene version, all but the scratch filled.
        self._workspaces = [_workspace(*bodies.packed_model, bodies.base_pose, self.pairs,
                                       self.keys, self.settings, table)]

    def result(self, contacts, passed, sat_tests, ms, states):
        """Return the Result of ``states`` states checked (``passed`` pairs, ``sat_tests``)."""
        contacts.setflags(write=False)
        return Result(contacts, one_pass_stats(
            self.bodies.count, self.n_static,
            (states * self.all_pairs, passed, states * self.filtered, sat_tests), ms, states))

    def reserve(self, chunks):
        """Make workspaces for ``chunks`` chunks of states checked at once (one per thread)."""
        while len(self._workspaces) < chunks:
            floats, ints = self._workspaces[0]
            self._workspaces.append((floats.copy(), ints.copy()))

    def check_one(self, q, start):
        """Return the Result of one state ``q`` (dof,), or None if it failed (:meth:`check`).

        ``start``: the time.perf_counter() at which the check began, for its stats.
        """
        contacts, (passed, sat_tests), state, _, _, invalid = check_robot_state(
            q, *self.state_workspace)
        if state >= 0 or invalid:
            return None
        return self.result(contacts, passed, sat_tests, 1e3 * (time.perf_counter() - start), 1)

    @property
    def state_workspace(self):
        """Return check_robot_state's arguments after ``q``: for a kernel that calls it."""
        return self._workspaces[0]

    def check(self, states, first_state, stop_state, kept=None, chunk=0):
        """Return check_robot_states' answer for states ``[first_state, stop_state)``.

        ``kept`` (box centres (B, 3, K), rotations (B, 9, K) row-major, each listed pair's
        robot_bodies.separation (P, K)): where to keep each state's robot boxes (a
        trajectory's segments start from them: robot_bodies.first_uncleared_pieces); None: not
        kept.
        ``chunk``: the workspace to use (:meth:`reserve`), one per chunk checked at once.
        """
        floats, ints = self._workspaces[chunk]
        return check_robot_states(states, floats, ints, first_state, stop_state,
                                  *(NOT_KEPT if kept is None else kept))


def _may_come_near(bodies, a, rows, table, pad):
    """Return which pairs (box a, row: a robot box, or B + a static row) the culls may pass.

    A pair the robot's reach keeps apart for every q (robot.Robot.center_spheres) is culled
    in every state: it is left out of the list. Kept: a pair whose bound is within the
    culls' reach (the robot's radii padded as :func:`_workspace` pads them; for a static
    box, the padded row of ``table`` and its own margin) and a slack far above the rounding
    of either computation.
    """
    robot, count = bodies.robot, bodies.count
    radii = np.linalg.norm(robot.half_extents, axis=1) + pad
    near = np.ones(len(a), np.bool_)
    mutual = np.flatnonzero(rows < count)
    if len(mutual):
        gaps = robot.center_gaps(a[mutual], rows[mutual])
        near[mutual] = gaps <= radii[a[mutual]] + radii[rows[mutual]] + _slack(gaps)
    static = np.flatnonzero(rows >= count)
    if len(static):
        centres, reaches = robot.center_spheres(np.arange(count), np.full(count, NO_INDEX),
                                                bodies.base_pose)
        centres, reaches = centres[a[static]], reaches[a[static]]
        boxes = table[rows[static] - count]
        rotations = boxes[:, ROTATION:EXTENTS].reshape(-1, 3, 3)
        offsets = centres - boxes[:, CENTER:ROTATION]
        local = np.einsum('pji,pj->pi', rotations, offsets)  # in the static box's frame
        outside = np.maximum(np.abs(local) - boxes[:, EXTENTS:LOW], 0.0)
        gaps = np.linalg.norm(outside, axis=1) - reaches
        scale = np.abs(centres).sum(axis=1) + np.abs(offsets).sum(axis=1) + np.abs(gaps)
        near[static] = gaps <= radii[a[static]] + pad + boxes[:, OWN_MARGIN] + _slack(scale)
    return near


def _slack(scale):
    """Return the allowance for rounding of a bound of magnitude ``scale``: far above it."""
    return 1e-9 * (1.0 + np.abs(scale))


@kernel
def check_robot_states(states, floats, ints, first_state, stop_state, kept_centers,
                       kept_rotations, kept_separations):
    """Check joint states ``[first_state, stop_state)`` of ``states`` (K, dof) (module docstring).

    ``floats`` and ``ints`` a workspace of :func:`_workspace` (the model, the pairs and
    settings, the rows and scratch); each state's robot boxes are written to ``kept_centers``
    and ``kept_rotations`` (RobotRows.check: the state last) unless they are empty, each
    rotation straight from its link's (robot.box_rotation), not through the quaternion a pose
    holds, and each listed pair's robot_bodies.separation to ``kept_separations``. Returns
    (contacts with their state, (pairs the culls passed, SAT tests), first failed state
    or -1, its box (NON_FINITE_JOINT: its q), obb reason code, 1 if the SAT met NaN).

    The lanes' floats in arrays of their own, not in the workspace: LLVM runs the loops over
    lanes as vectors only when it knows that no two of their arrays share memory (with views
    of the workspace, robot.lane_transforms took 1.5 times as long).
    """
    links, count = ints[0], ints[1]
    lanes = (np.zeros(LANES), np.zeros((links, 4, LANES)), np.zeros((links, 9, LANES)),
             np.zeros((links, 3, LANES)), np.zeros((count, 3, LANES)), np.zeros(LANES))
    return _checked(states, floats, ints, first_state, stop_state,
                    (kept_centers, kept_rotations, kept_separations), LANES, lanes)


@kernel
def check_robot_state(q, floats, ints):
    """Return :func:`check_robot_states`' answer for one state ``q`` (dof,), boxes not kept.

    Entered with three arguments, not seven: numba unboxes each argument on every call, and
    for one state that is a tenth of the call. It runs one lane, in the workspace's scratch:
    six allocations would cost a tenth of the state. (The state range as int64 values, not
    constants: _jit, "Constant arguments".)
    """
    return _checked(view(q, 0, (1, q.shape[0])), floats, ints, np.int64(0), np.int64(1),
                    (np.empty((0, 3, 0)), np.empty((0, 9, 0)), np.empty((0, 0))), 1,
                    _views(floats, ints)[-2])


@inlined_kernel
def _checked(states, floats, ints, first_state, stop_state, kept, lanes, lane_floats):
    """:func:`check_robot_states`, run ``lanes`` lanes at a time in ``lane_floats``.

    ``lanes`` states at a time: their forward kinematics, centres and culls with the state
    innermost (robot.lane_transforms), then each state's survivors in turn. A state fails
    where a state checked alone would: its q, then its boxes' centres, then its SAT, and a
    state's failure returns before any later state's SAT runs. ``lane_floats``: (half angles
    (LANES,), the link frames (quaternions, rotations, translations), the box centres
    (B, 3, LANES), the rounding allowances (LANES,)). ``kept``: check_robot_states'.
    """
    model = unpack_model(ints, floats)
    count = model.half_extents.shape[0]
    (base_pose, settings, bounds, pairs, keys, centers, rotations, extents, aabbs, radii,
     margins, depth, normal, point, oriented, candidates, _,
     (listed, listed_counts, failures)) = _views(floats, ints)
    halves, lane_quaternions, lane_rotations, lane_translations, lane_centers, ties = lane_floats
    oriented[:] = -1  # the state each box was last oriented for
    most = len(pairs)
    status = np.empty(most, np.int8)
    out = np.empty(max(most, 1), STATE_CONTACT_DTYPE)  # grown when full
    reported = passed = sat_tests = 0
    # The culls test the spheres: the SAT's prefilter is off (not the literal False: _jit,
    # "Constant arguments").
    no_prefilter = np.bool_(False)
    for first in range(first_state, stop_state, lanes):
        width = min(lanes, stop_state - first)
        for w in range(width):
            failures[w] = 0
            for j in range(states.shape[1]):
                if not math.isfinite(states[first + w, j]):
                    failures[w] = BAD_JOINT
        lane_transforms(model, base_pose, states, first, width, halves,
                        lane_quaternions, lane_rotations, lane_translations)
        _place_lanes(model, width, lane_rotations, lane_translations, lane_centers, ties,
                     failures, bounds)
        if kept[0].shape[2]:  # states kept (the state last)
            _keep_lanes(model, first, width, pairs, (centers, rotations, extents),
                        lane_rotations, lane_centers, kept)
        _cull_lanes(count, lanes, width, pairs, centers, rotations, extents, aabbs, radii,
                    margins, settings[PAD], lane_centers, ties, listed, listed_counts)
        for w in range(width):
            state = first + w
            if failures[w] == BAD_JOINT:
                return _failed(state, NON_FINITE_JOINT, NON_FINITE_POSE, 0)
            if failures[w] == BAD_CENTER:
                box, code = _bad_center(count, lane_centers, w)
                return _failed(state, box, code, 0)
            n = 0
            for i in range(listed_counts[w]):
                p = listed[w, i]
                a, b = pairs[p, 0], pairs[p, 1]
                for box in (a, b):
                    if box < count and oriented[box] != state:
                        oriented[box] = state
                        _orient(model, box, w, lane_quaternions, lane_centers, centers,
                                rotations, aabbs, settings[PAD])
                if not aabbs_overlap(aabbs, a, b):
                    continue
                candidates[n, 0], candidates[n, 1], candidates[n, 2] = a, b, p
                n += 1
            passed += n
            if settings[HAS_MARGIN] != 0.0:
                sat_tests += collide_pair_rows(centers, rotations, extents, radii,
                                               candidates[:n], no_prefilter, settings[MARGIN],
                                               margins, status, depth, normal, point)
            else:
                sat_tests += collide_pair_rows(centers, rotations, extents, radii,
                                               candidates[:n], no_prefilter, None, None, status,
                                               depth, normal, point)
            if len(out) - reported < n:
                out = _grown(out, reported + n)
            for k in range(n):
                if status[k] == INVALID:
                    return _failed(state, -1, VALID, 1)
                if status[k] == COLLIDING or status[k] == NEAR:
                    p = candidates[k, 2]
                    write_contact(out[reported], (point[k, 0], point[k, 1], point[k, 2]),
                                  (normal[k, 0], normal[k, 1], normal[k, 2]), depth[k], 1.0,
                                  keys[p, 0], keys[p, 2], keys[p, 1])
                    out[reported].state = state
                    reported += 1
    return out[:reported], (passed, sat_tests), -1, -1, VALID, 0


@inlined_kernel
def _place_lanes(model, lanes, lane_rotations, lane_translations, lane_centers, ties,
                 failures, bounds):
    """Place each box's centre in every lane, and each lane's rounding allowance.

    A lane whose centres are not all finite and within MAX_COORDINATE is marked BAD_CENTER
    (unless its q already failed). ``ties``: what the culls allow for rounding, one bound per
    state on what obb.spheres_apart allows each pair (64 ulps of the radii, extents and
    coordinates: the widest row and the farthest centre), so that a cull is a few flops.
    """
    widest, farthest_static = bounds[0], bounds[1]
    for w in range(lanes):
        ties[w] = farthest_static
    for b in range(model.box_links.shape[0]):
        link = model.box_links[b]
        offset = (model.box_translations[b, 0], model.box_translations[b, 1],
                  model.box_translations[b, 2])
        for w in range(lanes):
            c = placed(lane_rotation(lane_rotations, link, w),
                       lane_vector(lane_translations, link, w), offset)
            lane_centers[b, 0, w], lane_centers[b, 1, w], lane_centers[b, 2, w] = c
            ties[w] = max(ties[w], abs(c[0]) + abs(c[1]) + abs(c[2]))
            within = (abs(c[0]) <= MAX_COORDINATE) & (abs(c[1]) <= MAX_COORDINATE) \
                & (abs(c[2]) <= MAX_COORDINATE)  # False for NaN
            failures[w] = BAD_CENTER if failures[w] == 0 and not within else failures[w]
    for w in range(lanes):
        ties[w] = TIE_ULPS * EPS * 2.0 * (widest + ties[w])


@inlined_kernel
def _cull_lanes(count, lanes, width, pairs, centers, rotations, extents, aabbs, radii, margins,
                pad, lane_centers, ties, listed, listed_counts):
    """List, per lane, the pairs its culls pass (module docstring, step 2), in the list's order.

    A cull drops a pair only when its test says apart: a NaN keeps it (the lane fails on its
    centres before its pairs are read). Each pair's lanes are one loop that stores nothing
    (the lanes that keep it are bits of one integer) and reads the pair's rows before it:
    a store in the loop, or a read LLVM cannot prove untouched by it, keeps the loop from
    running the lanes at once. It runs all ``lanes`` lanes, past ``width`` too, whose bits
    are dropped: LLVM runs a loop of a length known when it compiles as one vector, and one of
    a length known only at run time as a vector only when it spans two (the culls took 0.26
    µs a state, and 0.18 with all lanes).
    """
    for w in range(width):
        listed_counts[w] = 0
    for p in range(pairs.shape[0]):
        a, b = pairs[p, 0], pairs[p, 1]
        passing = 0
        if b < count:  # two robot boxes: their bounding spheres
            spheres = radii[a] + radii[b]
            for w in range(lanes):
                d = _lane_gap(lane_centers, a, w, lane_centers[b, 0, w], lane_centers[b, 1, w],
                              lane_centers[b, 2, w])
                reach = spheres + ties[w]
                apart = d[0] * d[0] + d[1] * d[1] + d[2] * d[2] > reach * reach
                passing |= np.int64(not apart) << w
        else:  # a robot box's sphere against the static box's AABB, then the box itself
            r, e = matrix(rotations, b), (extents[b, 0], extents[b, 1], extents[b, 2])
            low = (aabbs[b, 0, 0], aabbs[b, 0, 1], aabbs[b, 0, 2])
            high = (aabbs[b, 1, 0], aabbs[b, 1, 1], aabbs[b, 1, 2])
            center, radius, padding = (centers[b, 0], centers[b, 1], centers[b, 2]), radii[a], \
                pad + margins[b]
            for w in range(lanes):
                reach = radius + ties[w]
                x, y, z = lane_centers[a, 0, w], lane_centers[a, 1, w], lane_centers[a, 2, w]
                near_box = ((low[0] - reach <= x) & (x <= high[0] + reach)
                            & (low[1] - reach <= y) & (y <= high[1] + reach)
                            & (low[2] - reach <= z) & (z <= high[2] + reach))
                # The robot box's centre farther outside the static box than its radius
                # (padded by half the margin), the other half, the static box's own margin
                # and the rounding allowed.
                beyond = reach + padding
                d = _lane_gap(lane_centers, a, w, center[0], center[1], center[2])
                apart = squared_distance_outside(d, r, e) > beyond * beyond
                passing |= np.int64(near_box & (not apart)) << w
        passing &= (1 << width) - 1  # the lanes past the last state hold an earlier block's
        if passing != 0:
            for w in range(width):
                if (passing >> w) & 1:
                    listed[w, listed_counts[w]] = p
                    listed_counts[w] += 1


@inlined_kernel
def _lane_gap(lane_centers, a, w, x, y, z):
    """Return box a's centre in lane ``w`` less the point (x, y, z)."""
    return lane_centers[a, 0, w] - x, lane_centers[a, 1, w] - y, lane_centers[a, 2, w] - z


@kernel
def _bad_center(count, lane_centers, w):
    """Return (box, obb reason code) of the first box of lane ``w`` placed out of bounds."""
    for b in range(count):
        for m in range(3):
            if not math.isfinite(lane_centers[b, m, w]):
                return b, NON_FINITE_POSE
            if abs(lane_centers[b, m, w]) > MAX_COORDINATE:
                return b, OUT_OF_RANGE
    return -1, VALID


@inlined_kernel
def _keep_lanes(model, first, width, pairs, boxes, lane_rotations, lane_centers, kept):
    """Write the lanes' robot boxes and pairs' separations to ``kept`` (check_robot_states').

    States ``first`` on, the state last in each kept array: each box's centre, its rotation
    straight from its link's (robot.box_rotation, not through the quaternion a pose holds),
    and each listed pair's robot_bodies.separation (``boxes`` the rows' centers, rotations
    and extents), the same numbers that function gives from the placed boxes.
    """
    centers, rotations, extents = boxes
    kept_centers, kept_rotations, kept_separations = kept
    count = model.box_links.shape[0]
    for b in range(count):
        link, own = model.box_links[b], matrix(model.box_rotations, b)
        for w in range(width):
            r = turned(lane_rotation(lane_rotations, link, w), own)
            kept_rotations[b, 0, first + w], kept_rotations[b, 1, first + w] = r[0], r[1]
            kept_rotations[b, 2, first + w], kept_rotations[b, 3, first + w] = r[2], r[3]
            kept_rotations[b, 4, first + w], kept_rotations[b, 5, first + w] = r[4], r[5]
            kept_rotations[b, 6, first + w], kept_rotations[b, 7, first + w] = r[6], r[7]
            kept_rotations[b, 8, first + w] = r[8]
            for i in range(3):
                kept_centers[b, i, first + w] = lane_centers[b, i, w]
    for p in range(pairs.shape[0]):
        a, b = pairs[p, 0], pairs[p, 1]
        if b < count:
            for w in range(width):
                d = _lane_gap(lane_centers, a, w, lane_centers[b, 0, w], lane_centers[b, 1, w],
                              lane_centers[b, 2, w])
                kept_separations[p, first + w] = dot(d, d)
        else:
            r, e = matrix(rotations, b), (extents[b, 0], extents[b, 1], extents[b, 2])
            for w in range(width):
                d = _lane_gap(lane_centers, a, w, centers[b, 0], centers[b, 1], centers[b, 2])
                kept_separations[p, first + w] = squared_distance_outside(d, r, e)


@kernel
def _failed(state, box, code, invalid):
    """Return check_robot_states' answer for a state that failed."""
    return np.empty(0, STATE_CONTACT_DTYPE), (0, 0), state, box, code, invalid


@kernel
def _workspace(model_ints, model_floats, base_pose, pairs, keys, settings, static_boxes):
    """Return a workspace (floats, ints) of the pass, laid out as :func:`_views` reads it.

    numba unboxes each array argument on every call: a state's check reads every fixed
    argument from these two. The ints: the packed model (robot.pack_model), the pair and
    static counts, the pairs and their keys, then scratch. The floats: the packed model, the
    base pose, the settings, the culls' rounding bounds, then B robot rows (placed per state)
    and the static rows as sat.collide_pair_rows reads them, filled here (the robot's radii
    padded as the one pass pads its bodies', their margins 0), then scratch: the SAT's
    outputs and the lanes' (:func:`_views`), then each row's half diagonal.
    """
    model = unpack_model(model_ints, model_floats)
    count, n_static = model.half_extents.shape[0], static_boxes.shape[0]
    links, most = model.parents.shape[0], pairs.shape[0]
    rows = count + n_static
    model_int_count, model_float_count = packed_sizes(model_ints)
    floats = np.zeros(model_float_count + ROWS + rows * ROW_FLOATS + most * 7
                      + LANES * (2 + links * 16 + count * 3))
    ints = np.zeros(model_int_count + 2 + most * 5 + count + most * 3 + LANES * (most + 2),
                    np.int64)
    copy_into(floats[:model_float_count], model_floats)
    copy_into(ints[:model_int_count], model_ints)
    ints[model_int_count], ints[model_int_count + 1] = most, n_static
    (view_pose, view_settings, bounds, view_pairs, view_keys, centers, rotations, extents,
     aabbs, radii, margins) = _views(floats, ints)[:11]
    copy_into(view_pose, base_pose)
    copy_into(view_settings, settings)
    copy_into(view_pairs, pairs)
    copy_into(view_keys, keys)
    pad = settings[PAD]
    for b in range(count):
        h = model.half_extents[b]
        copy_into(extents[b], h)
        radii[b] = math.sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2]) + pad
    for s in range(n_static):
        row, box = count + s, static_boxes[s]
        for m in range(3):
            centers[row, m] = box[CENTER + m]
            extents[row, m] = box[EXTENTS + m]
            aabbs[row, 0, m] = box[LOW + m]
            aabbs[row, 1, m] = box[HIGH + m]
            for n in range(3):
                rotations[row, m, n] = box[ROTATION + 3 * m + n]
        radii[row] = box[RADIUS]
        margins[row] = box[OWN_MARGIN]
    for row in range(rows):
        bounds[0] = max(bounds[0], radii[row] + margins[row] + extents[row, 0]
                        + extents[row, 1] + extents[row, 2])
        if row >= count:
            bounds[1] = max(bounds[1], abs(centers[row, 0]) + abs(centers[row, 1])
                            + abs(centers[row, 2]))
    return floats, ints


@inlined_kernel
def _views(floats, ints):
    """Return the parts of a workspace (:func:`_workspace`), views of its two arrays.

    The base pose, the settings, the culls' bounds (widest, farthest static), the pairs and
    their keys; (centers, rotations, extents, aabbs, radii, margins) of every row, the SAT's
    (depth, normal, point) per candidate, the state each robot box was last oriented for and
    the candidates (their rows, their pair); then the lanes' scratch (check_robot_states):
    the half angles, the link frames (robot.lane_transforms), the box centres and rounding
    allowances, the pairs each lane's culls pass and their count, and each lane's failure.
    """
    at_int, at = packed_sizes(ints)
    count, links = ints[1], ints[0]
    most, n_static = ints[at_int], ints[at_int + 1]
    rows = count + n_static
    at_int += 2
    pairs = view(ints, at_int, (most, 2))
    at_int += most * 2
    keys = view(ints, at_int, (most, 3))
    at_int += most * 3
    oriented = view(ints, at_int, (count,))
    candidates = view(ints, at_int + count, (most, 3))
    base_pose = view(floats, at + BASE_POSE, (SETTINGS - BASE_POSE,))
    settings = view(floats, at + SETTINGS, (WIDEST - SETTINGS,))
    bounds = view(floats, at + WIDEST, (ROWS - WIDEST,))
    at += ROWS
    centers = view(floats, at, (rows, 3))
    at += rows * 3
    rotations = view(floats, at, (rows, 3, 3))
    at += rows * 9
    extents = view(floats, at, (rows, 3))
    at += rows * 3
    aabbs = view(floats, at, (rows, 2, 3))
    at += rows * 6
    radii, margins = view(floats, at, (rows,)), view(floats, at + rows, (rows,))
    at += 2 * rows
    depth = view(floats, at, (most,))
    at += most
    normal = view(floats, at, (most, 3))
    at += most * 3
    point = view(floats, at, (most, 3))
    at += most * 3
    halves, ties = view(floats, at, (LANES,)), view(floats, at + LANES, (LANES,))
    at += 2 * LANES
    lane_quaternions = view(floats, at, (links, 4, LANES))
    at += links * 4 * LANES
    lane_rotations = view(floats, at, (links, 9, LANES))
    at += links * 9 * LANES
    lane_translations = view(floats, at, (links, 3, LANES))
    at += links * 3 * LANES
    lane_centers = view(floats, at, (count, 3, LANES))
    at_int += count + most * 3
    listed = view(ints, at_int, (LANES, most))
    at_int += LANES * most
    listed_counts = view(ints, at_int, (LANES,))
    failures = view(ints, at_int + LANES, (LANES,))
    return (base_pose, settings, bounds, pairs, keys, centers, rotations, extents, aabbs,
            radii, margins, depth, normal, point, oriented, candidates,
            (halves, lane_quaternions, lane_rotations, lane_translations, lane_centers, ties),
            (listed, listed_counts, failures))


@inlined_kernel
def _orient(model, b, w, lane_quaternions, lane_centers, centers, rotations, aabbs, pad):
    """Write robot box b's centre, rotation and AABB in lane ``w`` as a step makes them.

    Its pose's quaternion (robot.box_quaternion's, as robot.forward_kinematics writes it): a
    step turns it into the rotation the SAT tests (obb.box_axes); the AABB padded as the one
    pass pads a body's. Only the boxes of the pairs a state's culls pass, about a third:
    every box in every lane, as one vector over the lanes, took as long.
    """
    c = (lane_centers[b, 0, w], lane_centers[b, 1, w], lane_centers[b, 2, w])
    quaternion = quaternion_product(
        lane_quaternion(lane_quaternions, model.box_links[b], w),
        (model.box_quaternions[b, 0], model.box_quaternions[b, 1], model.box_quaternions[b, 2],
         model.box_quaternions[b, 3]))
    h = (model.half_extents[b, 0], model.half_extents[b, 1], model.half_extents[b, 2])
    axes, reach = box_axes(c + quaternion, h)
    for m in range(3):
        centers[b, m] = c[m]
        for n in range(3):
            rotations[b, m, n] = axes[3 * m + n]
        aabbs[b, 0, m] = c[m] - reach[m] - pad
        aabbs[b, 1, m] = c[m] + reach[m] + pad


@kernel
def _grown(out, needed):
    more = np.empty(max(2 * len(out), needed), STATE_CONTACT_DTYPE)
    copy_into(more[:len(out)], out)
    return more
