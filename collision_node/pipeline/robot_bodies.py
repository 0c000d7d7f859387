"""A robot's boxes as a World's dynamic bodies: joint values in, and whole trajectories.

:class:`RobotBodies` holds a :class:`~collision_node.pipeline.robot.Robot` at a base pose.
Body i of the World is box i of the robot; the robot's self-collision filter (its boxes'
pairs outside ``allowed_box_pairs``) is added to the World's ignored pairs, so a state checked
through the joints is checked exactly as ``World.step`` checks its box poses.

Trajectories. Waypoints are checked exactly (``World.check_states``). Between waypoints k and
k + 1 the joints move on the straight segment q(s) = q_k + s (q_k+1 - q_k), s in [0, 1].
Over a part of length ds of it, the distance between the two boxes of a pair changes by at
most ds * motion, motion = sum_j |q_k+1,j - q_k,j| radii[j] (robot.py derives the radii,
Robot.pair_motion_radii; joint limits assumed; for two boxes of the robot only the joints
below their links' common ancestor count: the joints above it move both as one). So a
configuration where the pair is ``clearance`` farther apart than its margin proves the pair
free on every configuration within clearance / motion of it on the segment.

The proof is conservative advancement, with a second bound for the pairs that pass near. The
waypoints' exact check keeps their boxes and each pair's separation (robot_pass, as vectors over
the waypoints; :func:`separation`: its bounding spheres' gap, squared), and a segment's
ends are placed (copied from what was kept) only for a pair whose gap there is not enough; a
pair whose clearance at the start covers the whole segment, or whose clearances at the two ends
meet, is free. For the pairs left, a piece of the segment from s0 (where all of them are proven
so far) to s is proven at once when, for each pair, one fixed plane keeps its two boxes farther
apart than its margin plus the boxes' bends at both s0 and s: each point of a box strays from
the chord between its two places by at most its bend, h² / 8 times a bound on its second
derivative along the segment (robot.py, Chord bound). That bound shrinks with the square of the
piece, where the motion's shrinks with the piece alone: a box that passes a wall 4 mm away is
proven in a few pieces, where advancement by clearance over motion takes a step per 4 mm of its
motion bound (doc/robot.md has a count). The piece tried first reaches the segment's end, then
halves; when it is no longer than conservative advancement's step, the boxes are placed where
the least proven pair stops being proven, which needs no plane. At every place taken, each
waiting pair's proof grows: bounding spheres, then the separating axis test's widest gap, then
for a pair stopped there with a gap within ``resolution`` of its margin the exact distance. A
stopped pair whose exact clearance is at most ``resolution`` is reported, with ``toi`` that
configuration. So a segment is reported only when a configuration on it comes within
``resolution`` of the pair's margin (colliding, with margin 0, or within ``resolution`` of it),
and every segment with a colliding configuration is reported: nothing between waypoints is
missed. A sampled check (MoveIt's, at its waypoints or at a fixed step) promises neither.
"""
import math

import numpy as np

from collision_node.pipeline._jit import inlined_kernel, kernel
from collision_node.pipeline.contacts import DYNAMIC, STATE_CONTACT_DTYPE
from collision_node.pipeline.distance import box_distance
from collision_node.pipeline.flat_views import copy_into
from collision_node.pipeline.frames import (dot, matrix, projection_gap, relative_pose,
                                            squared_distance_outside, sum_abs,
                                            transposed_times)
from collision_node.pipeline.obb import check_boxes, EPS, TIE_ULPS
from collision_node.pipeline.robot import (box_frame, box_poses_of_states, IDENTITY_POSE,
                                           link_frames, link_transforms, pack_model,
                                           unpack_model, write_box)
from collision_node.pipeline.sat import COLLIDING, SEPARATED, separating_axis_test

# What a segment's row takes from the exact contact at its toi, when its pair collides there.
GEOMETRY = ('x', 'y', 'z', 'normal_x', 'normal_y', 'normal_z', 'depth', 'distance')
DEFAULT_RESOLUTION = 1e-3  # m of motion: a reported segment is within this of a collision
# A proof reaches a hair short of where clearance / motion says: the division and the sum
# with s round, and a rounding up must never claim a configuration not proven.
SHRINK = 1.0 - 1e-12
# A pair's motion over a segment, rounded up likewise: the credit carried from waypoint to
# waypoint subtracts it every segment.
MOTION_SAFETY = 1.0 + 1e-12
# A box's bend, rounded up likewise (the sums and squares of its bound round).
CHORD_SAFETY = 1.0 + 1e-12


class RobotBodies:
    """A robot at a base pose; the World's dynamic bodies are its boxes."""

    def __init__(self, robot, base_pose=None):
        """Raise ValueError on a base pose that is not a finite pose with a unit quaternion."""
        pose = IDENTITY_POSE if base_pose is None else np.asarray(base_pose, np.float64)
        if pose.shape != (7,):
            raise ValueError('base_pose must be x y z qx qy qz qw, got shape %s'
                             % (pose.shape,))
        check_boxes(pose.reshape(1, 7), np.ones((1, 3)))  # finite, unit quaternion
        self.robot = robot
        # The model as two flat arrays for the kernels called from Python (robot.pack_model).
        self.packed_model = pack_model(robot.model)
        self.base_pose = np.array(pose)
        self.base_pose[3:] /= np.linalg.norm(pose[3:])
        allowed = np.zeros((len(robot.box_links),) * 2, np.bool_)
        allowed[robot.allowed_box_pairs[:, 0], robot.allowed_box_pairs[:, 1]] = True
        first, second = np.nonzero(np.triu(~allowed, 1))
        self.ignored_pairs = np.column_stack([first, np.full_like(first, DYNAMIC), second,
                                              np.full_like(first, DYNAMIC)])

    @property
    def count(self):
        """Return the number of boxes, the World's dynamic bodies."""
        return len(self.robot.box_links)

    def poses(self, q):
        """Return every box's pose in the World's frame, (K, B, 7): a state per row of ``q``."""
        states = self.robot._states(q)
        out = np.empty((len(states), self.count, 7))
        box_poses_of_states(self.robot.model, self.base_pose, states, out)
        return out


def segment_contacts(world, bodies, waypoints, exact, found, reports, keys):
    """Return the trajectory's contacts: the waypoints' ``exact`` ones and the segments'.

    ``found`` (W - 1, P) and its count of ``reports`` from :func:`first_uncleared_pieces`,
    ``keys`` (P, 3) each pair's (id_a, type_b, id_b). A segment's row carries the contact of
    its pair at q(toi) when the pair collides there; a pair reported at toi 0 that waypoint k
    reports already is left out.
    """
    if len(exact):  # (an empty one is returned as it is: a copy costs 3 us)
        exact = exact.copy()
        exact['toi'] = 0.0  # check_states marks a discrete contact at the step's end, 1
    if not reports:  # a free path's: sorted, as check_states sorts
        return exact
    segment, pair = np.nonzero(found >= 0)
    toi = found[segment, pair]
    reported = {(row['state'], row['id_a'], row['type_b'], row['id_b']) for row in exact}
    new = [i for i in range(len(segment))
           if not (toi[i] == 0.0 and (segment[i], *keys[pair[i]]) in reported)]
    segment, pair, toi = segment[new], pair[new], toi[new]
    rows = np.zeros(len(new), STATE_CONTACT_DTYPE)
    rows['state'], rows['toi'], rows['type_a'] = segment, toi, DYNAMIC
    rows['id_a'], rows['type_b'], rows['id_b'] = keys[pair].T
    rows['distance'] = np.nan
    if len(new):
        starts = waypoints[segment] + toi[:, None] * (waypoints[segment + 1] - waypoints[segment])
        at = {(row['state'], row['id_a'], row['type_b'], row['id_b']): row
              for row in world.check_joints(starts).contacts}
        for i in range(len(new)):
            contact = at.get((i, *keys[pair[i]]))
            if contact is not None:
                for name in GEOMETRY:
                    rows[i][name] = contact[name]
    contacts = np.concatenate([exact, rows])
    order = np.lexsort((contacts['toi'], contacts['id_b'], contacts['type_b'], contacts['id_a'],
                        contacts['state']))
    return contacts[order]


@kernel
def first_uncleared_pieces(model_ints, model_floats, base_pose, waypoints, kept, pairs,
                           pair_radii, margins, boxes, chord_turns, chord_reach, resolution):
    """Return, per segment and pair, where the first configuration not proven free lies.

    ``boxes`` (centers, rotations, extents): rows 0..B-1 for the robot's boxes (placed in
    copies: ``boxes`` is not written), the static boxes after them. ``pairs``
    (P, 2) rows of ``boxes``, the first one a robot box, ``pair_radii`` (P, dof) their
    Robot.pair_motion_radii, ``margins`` (P,) the distance within which each pair counts
    (robot_pass.RobotRows holds all four). ``kept`` the waypoints' robot boxes (centres
    (B, 3, W), rotations (B, 9, W) row-major) and each pair's :func:`separation` there
    (P, W), as the waypoints' check kept them (robot_pass.check_robot_states), or none
    (empty): then they are computed here.
    ``chord_turns`` (B, dof) and ``chord_reach`` (B,): Robot's, the Chord bound. Returns
    (found, reports): found (W - 1, P) s in [0, 1) where the pair comes within
    ``resolution`` of its margin, or -1 (the whole segment is proven free), and how many are
    not -1. The model as robot.pack_model packs it.
    """
    model = unpack_model(model_ints, model_floats)
    dof = waypoints.shape[1]
    found = np.full((waypoints.shape[0] - 1, len(pairs)), -1.0)
    reports = 0
    scratch = (np.empty(dof),) + link_frames(model)  # q and the link frames
    # The boxes at the segment's start (its first waypoint), end and current configuration,
    # each placed when a pair needs it: the end's placement is the next segment's start.
    start = (boxes[0].copy(), boxes[1].copy(), boxes[2].copy())  # ``boxes`` stays unwritten
    end = (boxes[0].copy(), boxes[1].copy(), boxes[2].copy())
    at = (boxes[0].copy(), boxes[1].copy(), boxes[2].copy())
    count = model.half_extents.shape[0]
    for placed in (start, end, at):  # the robot's extents, which no placement changes
        copy_into(placed[2][:count], model.half_extents)
    radii = np.empty(len(start[2]))  # half diagonals: the boxes' spheres
    for row in range(len(radii)):
        radii[row] = half_diagonal(start[2], row)
    if kept[0].shape[2] == 0:  # none kept: states last
        kept = _kept_here(model, base_pose, waypoints, pairs, scratch, start)
    # Each pair's separation at each waypoint, kept: only a pair whose gap there is not
    # enough has the waypoint's boxes placed (copied from the kept ones) for a closer look.
    separations = kept[2]
    scale, offset = gap_terms(pairs, radii, count)
    start_placed = False
    # A lower bound on each pair's distance at the segment's start: what a test there or at
    # an earlier waypoint proved, less the motion since (the bound's own argument). A pair
    # whose credit covers its motion over the segment is free without a look: most pairs,
    # most segments (Box2D's fat AABBs rest on the same idea).
    credit = np.full(len(pairs), -np.inf)
    motions = np.empty(len(pairs))  # per pair: how far it closes in over the whole segment
    cleared = np.empty(len(pairs))  # the pair is proven free on [0, cleared]
    from_end = np.empty(len(pairs))  # and on [from_end, 1]
    pending = np.empty(len(pairs), np.int64)
    untested = np.empty(len(pairs), np.bool_)  # the pairs whose credit falls short
    measured = np.zeros(len(pairs), np.bool_)  # credit measured at the segment's start
    # Joint by joint, each over every pair: the sums vectorise across pairs (each pair's
    # sum still adds its joints in order).
    radii_by_joint = np.ascontiguousarray(pair_radii.T)
    robot_boxes = chord_reach.shape[0]
    bends = np.empty(robot_boxes)  # per box, this segment: the Chord bound's |p''|
    for k in range(waypoints.shape[0] - 1):
        end_placed = False
        waiting = 0
        motions[:] = 0.0
        for j in range(dof):
            step = abs(waypoints[k + 1, j] - waypoints[k, j])
            for p in range(len(pairs)):
                motions[p] += step * radii_by_joint[j, p]
        # The credit first, without a branch (it vectorises too); the pairs it leaves are
        # tested below.
        for p in range(len(pairs)):
            motion = motions[p] * MOTION_SAFETY
            motions[p] = motion
            covered = credit[p] - margins[p] > motion
            untested[p] = not covered
            credit[p] = credit[p] - motion if covered else credit[p]
            measured[p] = measured[p] and not covered
        for p in range(len(pairs)):
            if not untested[p]:
                continue
            a, b = pairs[p, 0], pairs[p, 1]
            motion = motions[p]
            if measured[p]:  # its exact clearance here, as the segment before ended
                bound = credit[p]
            else:
                enough = margins[p] + max(motion, resolution)
                bound = separation_gap(separations[p, k], scale[p], offset[p])
                if bound <= enough:
                    if not start_placed:
                        _place_waypoint(model, kept, k, start)
                        start_placed = True
                    bound = _clearance(start, radii, a, b, bound, enough,
                                       margins[p] + resolution)
            measured[p] = False
            free = bound - margins[p]
            if free > motion:
                credit[p] = bound - motion
                continue
            credit[p] = -np.inf  # unknown at the end until a test there
            if free <= resolution:
                found[k, p] = 0.0
                reports += 1
                continue
            cleared[p] = free / motion * SHRINK
            enough = margins[p] + motion * (1.0 - cleared[p])
            bound = separation_gap(separations[p, k + 1], scale[p], offset[p])
            if bound <= enough:
                if not end_placed:
                    _place_waypoint(model, kept, k + 1, end)
                    end_placed = True
                bound = _clearance(end, radii, a, b, bound, enough, margins[p] + resolution)
            free = bound - margins[p]
            # The next segment starts here: a pair its credit leaves untested takes this
            # bound as its test.
            credit[p] = bound
            measured[p] = True
            from_end[p] = 1.0 - free / motion * SHRINK if free > 0.0 else 1.0
            if from_end[p] > cleared[p]:
                pending[waiting] = p
                waiting += 1
        # The pairs left (module docstring): from s0, where every one is proven so far, a
        # step to s is tried first where the boxes' chords prove it (each pair on one side of
        # a fixed plane at s0 and at s, by more than its margin and the boxes' bends), from
        # the segment's end down by halves; a step no longer than conservative advancement's
        # (to the least proven pair's end of proof) needs no proof. A step taken tests every
        # waiting pair there: cheap bounds, the exact distance for a stopped pair not farther
        # than ``resolution``, which is reported. Every step reaches at least that far, and a
        # stopped pair's proof then grows by at least resolution / motion: it ends.
        if waiting:
            for box in range(robot_boxes):
                turned = 0.0
                for j in range(dof):
                    turned += abs(waypoints[k + 1, j] - waypoints[k, j]) * chord_turns[box, j]
                bends[box] = chord_reach[box] * turned * turned * CHORD_SAFETY
            if not start_placed:
                _place_waypoint(model, kept, k, start)
                start_placed = True
            if not end_placed:  # the pieces' last reaches it
                _place_waypoint(model, kept, k + 1, end)
                end_placed = True
        s0, near, step = 0.0, start, 1.0
        while waiting:
            s = 1.0
            for i in range(waiting):
                s = min(s, cleared[pending[i]])
            if s0 + step > s:
                s = min(s0 + step, 1.0)
                if s < 1.0:
                    _place(model, base_pose, waypoints[k], waypoints[k + 1], s, scratch, at)
                if not _chords_apart(near, end if s == 1.0 else at, pairs, margins, bends,
                                     (s - s0) * (s - s0), pending[:waiting], cleared, s):
                    step = 0.5 * (s - s0)
                    continue
                if s == 1.0:
                    break
            else:
                _place(model, base_pose, waypoints[k], waypoints[k + 1], s, scratch, at)
            step = 2.0 * (s - s0)
            left = 0
            for i in range(waiting):
                p = pending[i]
                a, b = pairs[p, 0], pairs[p, 1]
                motion = motions[p]
                stopped = cleared[p] <= s
                cleared[p] = max(cleared[p], s)
                enough = margins[p] + max(motion * (from_end[p] - s), resolution)
                bound = separation_gap(separation(at, a, b, robot_boxes), scale[p], offset[p])
                if bound <= enough:
                    bound = _clearance(at, radii, a, b, bound, enough,
                                       margins[p] + resolution if stopped else -np.inf)
                free = bound - margins[p]
                if stopped and free <= resolution:
                    found[k, p] = s
                    reports += 1
                    continue
                if free > 0.0:
                    cleared[p] = max(cleared[p], s + free / motion * SHRINK)
                if stopped and cleared[p] <= s:  # no progress left in float64: report
                    found[k, p] = s
                    reports += 1
                    continue
                if from_end[p] > cleared[p]:
                    pending[left] = p
                    left += 1
            waiting = left
            s0, near, at = s, at, near
        # The end is the next segment's start; near and at, the two others, its end and at.
        start, end, at = end, near, at
        start_placed = end_placed
    return found, reports


@kernel
def _chords_apart(near, far, pairs, margins, bends, squared_step, pending, cleared, s):
    """Return whether every pending pair not proven up to ``s`` is proven from near to far.

    ``near`` and ``far``: the boxes placed at the two ends of a piece ``squared_step`` long
    squared; ``bends`` each robot box's bound on its points' second derivative along the
    segment (robot.py, Chord bound): over the piece they stray from their chords by at most
    squared_step / 8 times it.
    """
    robot_boxes = bends.shape[0]
    for p in pending:
        if cleared[p] >= s:
            continue
        a, b = pairs[p, 0], pairs[p, 1]
        bend = bends[a] + (bends[b] if b < robot_boxes else 0.0)
        if not _apart_at_both(near, far, a, b, margins[p] + 0.125 * squared_step * bend):
            return False
    return True


@kernel
def _apart_at_both(near, far, a, b, needed):
    """Return whether one fixed plane has boxes a and b more than ``needed`` apart in both.

    ``near`` and ``far``: two placements of the boxes (centers, rotations, extents). Every
    point of either box between them lies within its bend of the chord between its two
    places, so a plane that keeps the boxes apart at both by more than their bends and margin
    keeps them apart all the way. The planes tried are the separating axis test's face axes,
    which part most pairs: normal to b's faces at near first (a static box's stay, and a wall's
    or a table's is the plane that parts a robot box passing along it: trying it first took
    the segment kernel to 0.88x on the Panda's path past a wall), then to a's at either end.
    Rounding is counted against the answer.
    """
    ra_near, rb_near, rel_near, t_near, scale_near = _seen_from_a(near, a, b)
    ra_far, _, rel_far, t_far, scale_far = _seen_from_a(far, a, b)
    extents = near[2]
    ea = (extents[a, 0], extents[a, 1], extents[a, 2])
    eb = (extents[b, 0], extents[b, 1], extents[b, 2])
    tie = TIE_ULPS * EPS * (scale_near + scale_far + sum_abs(ea) + sum_abs(eb) + abs(needed))
    for axis in range(9):
        basis = ra_far if axis >= 6 else (rb_near if axis < 3 else ra_near)
        i = axis % 3
        normal = (basis[i], basis[3 + i], basis[6 + i])  # column i: a face's normal
        if dot(t_near, transposed_times(ra_near, normal)) < 0.0:  # b on its far side
            normal = (-normal[0], -normal[1], -normal[2])
        if projection_gap(rel_near, t_near, ea, eb, transposed_times(ra_near, normal)) \
                - tie > needed and \
                projection_gap(rel_far, t_far, ea, eb, transposed_times(ra_far, normal)) \
                - tie > needed:
            return True
    return False


@inlined_kernel
def _seen_from_a(boxes, a, b):
    """Return boxes a's and b's rotations, b's pose in a's frame, and the rounding's scale.

    (ra, rb, rel, t, scale): row-major rotations, rel = AᵀB and t = Aᵀ(c_B − c_A) as
    frames.relative_pose gives them, and the sum of the centres' |coordinates|.
    """
    centers, rotations, _ = boxes
    ca = (centers[a, 0], centers[a, 1], centers[a, 2])
    cb = (centers[b, 0], centers[b, 1], centers[b, 2])
    ra, rb = matrix(rotations, a), matrix(rotations, b)
    rel, t = relative_pose(ra, rb, (cb[0] - ca[0], cb[1] - ca[1], cb[2] - ca[2]))
    return ra, rb, rel, t, sum_abs(ca) + sum_abs(cb)


@kernel
def _place_waypoint(model, kept, k, boxes):
    """Write the robot's boxes at waypoint k into rows 0..B-1 of boxes, from the kept ones."""
    kept_centers, kept_rotations, _ = kept
    centers, rotations, _ = boxes
    for b in range(model.half_extents.shape[0]):
        for i in range(3):
            centers[b, i] = kept_centers[b, i, k]
            for j in range(3):
                rotations[b, i, j] = kept_rotations[b, 3 * i + j, k]


@kernel
def _kept_here(model, base_pose, waypoints, pairs, scratch, boxes):
    """Return what a waypoints' check keeps (first_uncleared_pieces' ``kept``), placed here.

    For the scenes past the robot's pass, whose check keeps nothing: each waypoint's boxes
    placed in ``boxes`` (its rows 0..B-1 written) and copied out, and each pair's gap.
    """
    count = model.half_extents.shape[0]
    centers = np.empty((count, 3, waypoints.shape[0]))
    rotations = np.empty((count, 9, waypoints.shape[0]))
    separations = np.empty((pairs.shape[0], waypoints.shape[0]))
    for k in range(waypoints.shape[0]):
        _place(model, base_pose, waypoints[k], waypoints[k], 0.0, scratch, boxes)
        for b in range(count):
            for i in range(3):
                centers[b, i, k] = boxes[0][b, i]
                for j in range(3):
                    rotations[b, 3 * i + j, k] = boxes[1][b, i, j]
        for p in range(pairs.shape[0]):
            separations[p, k] = separation(boxes, pairs[p, 0], pairs[p, 1], count)
    return centers, rotations, separations


@kernel
def _place(model, base_pose, start, end, s, scratch, boxes):
    """Write the robot's boxes at q(s) = start + s (end - start) into rows 0..B-1 of boxes."""
    q, link_rotations, link_translations, link_quaternions = scratch
    for j in range(q.shape[0]):
        q[j] = start[j] + s * (end[j] - start[j])
    link_transforms(model, base_pose, q, link_rotations, link_translations, link_quaternions)
    _write_robot_boxes(model, link_rotations, link_translations, boxes)


@kernel
def _write_robot_boxes(model, link_rotations, link_translations, boxes):
    """Write the robot's boxes from the link frames into rows 0..B-1 of boxes.

    Straight from the link frames: a proof needs the boxes where they are, not the pose
    a step would be handed, so the rotation skips the quaternion a pose holds.
    """
    centers, rotations, extents = boxes
    for b in range(model.half_extents.shape[0]):
        center, r = box_frame(model, link_rotations, link_translations, b)
        write_box(b, center, r, model.half_extents[b], centers, rotations, extents)


@kernel
def separation(boxes, a, b, robot_boxes):
    """Return boxes a's and b's separation, the square of the distance their gap starts from.

    For two robot boxes, the squared distance between their centres; for a static box b (row
    ``robot_boxes`` or later), the squared distance from a's centre to the box itself: the
    static colliders of a robot's cell (a table, a wall) are large, and their spheres would
    say nothing. Its :func:`separation_gap` less the margin bounds the boxes' distance from
    below. Squared, so that the waypoints' check takes no square root (robot_pass keeps one
    for every listed pair at each waypoint, as vectors over the states): a segment takes one
    only for the pairs its credit leaves.
    """
    centers, rotations, extents = boxes
    d = (centers[a, 0] - centers[b, 0], centers[a, 1] - centers[b, 1],
         centers[a, 2] - centers[b, 2])
    if b < robot_boxes:
        return dot(d, d)
    return squared_distance_outside(d, matrix(rotations, b),
                                    (extents[b, 0], extents[b, 1], extents[b, 2]))


@inlined_kernel
def separation_gap(separation, scale, offset):
    """Return the gap a pair's :func:`separation` proves: its root times scale, less offset.

    ``scale`` and ``offset`` the pair's :func:`gap_terms`.
    """
    return math.sqrt(separation) * scale - offset


@kernel
def gap_terms(pairs, radii, robot_boxes):
    """Return (scale, offset) (P,): each pair's gap, sqrt(separation) * scale - offset.

    The seed paper's sphere prefilter, as a lower bound on the boxes' distance: x, the root
    of the separation, less the robot boxes' half diagonals ``radii`` (for a static box,
    a's alone), rounding counted against it: TIE_ULPS ulps of x + the radii for two robot
    boxes; for a static box, of x + the sum of |d| (d: a's centre from b's, |d| <= x + b's
    half diagonal) + the sum of b's half extents + a's radius, at most 3 x + 4 b's half
    diagonal + a's radius.
    """
    tie = TIE_ULPS * EPS
    scale, offset = np.empty(len(pairs)), np.empty(len(pairs))
    for p in range(len(pairs)):
        a, b = pairs[p, 0], pairs[p, 1]
        if b < robot_boxes:
            scale[p] = 1.0 - tie
            offset[p] = (radii[a] + radii[b]) * (1.0 + tie)
        else:
            scale[p] = 1.0 - 3.0 * tie
            offset[p] = radii[a] * (1.0 + tie) + 4.0 * tie * radii[b]
    return scale, offset


@inlined_kernel
def half_diagonal(extents, row):
    """Return a box's half diagonal, the radius of its bounding sphere."""
    e0, e1, e2 = extents[row, 0], extents[row, 1], extents[row, 2]
    return math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)


@kernel
def _clearance(boxes, radii, a, b, gap, enough, exact_within):
    """Return a lower bound on the distance between boxes a and b, rounding counted against it.

    For a pair whose spheres' ``gap`` falls short of ``enough``: each box's sphere against the
    other box, then the SAT's widest separating gap (with ``enough`` as its margin; the first
    gap past it ends the test); the first that reaches ``enough`` answers. Then, if that gap is
    at most ``exact_within``, the exact distance: a weaker bound only shortens a proof's step,
    but a pair is reported on its exact distance. An overlap gives 0. ``radii``: each box's
    half diagonal.
    """
    centers, rotations, extents = boxes
    ea = (extents[a, 0], extents[a, 1], extents[a, 2])
    eb = (extents[b, 0], extents[b, 1], extents[b, 2])
    d = (centers[b, 0] - centers[a, 0], centers[b, 1] - centers[a, 1],
         centers[b, 2] - centers[a, 2])
    tie = TIE_ULPS * EPS * (sum_abs(ea) + sum_abs(eb) + sum_abs(d) + abs(enough))
    ra, rb = matrix(rotations, a), matrix(rotations, b)
    # Each box's sphere against the other box (every point of a box lies within its half
    # diagonal of its centre): a few flops that prove most pairs the spheres alone do not.
    spheres = max(math.sqrt(squared_distance_outside(d, ra, ea)) - radii[b],
                  math.sqrt(squared_distance_outside(d, rb, eb)) - radii[a])
    if spheres - tie > enough:
        return max(gap, spheres - tie)
    rel, t = relative_pose(ra, rb, d)
    status, overlap, _ = separating_axis_test(rel, t, ea, eb, tie, max(enough, 0.0) + tie)
    if status == COLLIDING:
        return 0.0
    if status == SEPARATED or -overlap - tie > exact_within:
        return max(gap, -overlap - tie)
    return box_distance(rel, t, ea, eb)[0] - tie
