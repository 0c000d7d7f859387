"""A robot's boxes as a World's dynamic bodies: joint values in, and whole trajectories.

:class:`RobotBodies` holds a :class:`~collision_node.pipeline.robot.Robot` at a base pose.
Body i of the World is box i of the robot; the robot's self-collision filter (its boxes'
pairs outside ``allowed_box_pairs``) is added to the World's ignored pairs, so a state checked
through the joints is checked exactly as ``World.step`` checks its box poses.

Trajectories. Waypoints are checked exactly (``World.check_states``). Between waypoints k and
k + 1 the joints move on the straight segment q(s) = q_k + s (q_k+1 - q_k), s in [0, 1]. On a
piece [s0, s1] of it every point of box b stays within

    r_b = (s1 - s0) / 2 * sum_j |q_k+1,j - q_k,j| * motion_radii[b, j]

of where it is at the piece's middle (robot.py derives the radii; joint limits assumed). So if
box a grown by r_a (plus the margin that pair reports within) and box b grown by r_b are
apart, by the separating axis test, no configuration of the piece brings the pair together:
the piece is free for that pair. A pair the test cannot clear is split in halves, left half
first, until its pieces move less than ``resolution`` (the sum r_a + r_b); the first piece
still not cleared is reported, with ``toi`` its start. So a segment is reported only when a
configuration on it collides or comes within ``resolution`` of colliding (or of the margin),
and every segment with a colliding configuration is reported: nothing between waypoints is
missed. A sampled check (MoveIt's, at its waypoints or at a fixed step) promises neither.
"""
import math

import numpy as np

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.contacts import DYNAMIC, STATE_CONTACT_DTYPE
from collision_node.pipeline.distance import box_distance
from collision_node.pipeline.frames import matrix, relative_pose, sum_abs
from collision_node.pipeline.obb import check_boxes, EPS, TIE_ULPS, write_boxes
from collision_node.pipeline.robot import (box_poses_of_states, forward_kinematics,
                                           IDENTITY_POSE, link_frames, RobotModel)
from collision_node.pipeline.sat import NEAR, SEPARATED, separating_axis_test
from collision_node.pipeline.small_scene import check_states

# What a segment's row takes from the exact contact at its toi, when its pair collides there.
GEOMETRY = ('x', 'y', 'z', 'normal_x', 'normal_y', 'normal_z', 'depth', 'distance')
# Spheres clear a pair only when apart by this factor on the squared distance: 8 ulps of
# rounding in the sums and squares never clear a pair that touches.
SPHERE_SAFETY = 1.0 + 1e-14
DEFAULT_RESOLUTION = 1e-3  # m of motion: a reported segment is within this of a collision
# Halvings of a segment at most: 2^-40 of a segment is below any motion float64 resolves
# beside a robot's size; a pair not cleared by then is reported (conservative).
MAX_DEPTH = 40


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
        # The model as a plain tuple for the kernels called from Python: numba types a
        # NamedTuple argument in Python on every call (5.5 µs for the Panda's 15 arrays), a
        # tuple in C (1.8 µs); the kernels make it a RobotModel again, at no cost.
        self.model_fields = tuple(robot.model)
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


def segment_contacts(world, bodies, waypoints, exact, found, keys):
    """Return the trajectory's contacts: the waypoints' ``exact`` ones and the segments'.

    ``found`` (W - 1, P) from :func:`first_uncleared_pieces`, ``keys`` (P, 3) each pair's
    (id_a, type_b, id_b). A segment's row carries the contact of its pair at q(toi) when the
    pair collides there; a pair reported at toi 0 that waypoint k reports already is left out.
    """
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
    at_waypoints = exact.copy()
    at_waypoints['toi'] = 0.0  # check_states marks a discrete contact at the step's end, 1
    contacts = np.concatenate([at_waypoints, rows])
    order = np.lexsort((contacts['toi'], contacts['id_b'], contacts['type_b'], contacts['id_a'],
                        contacts['state']))
    return contacts[order]


@kernel
def check_joint_states(model_fields, base_pose, joint_states, statics, rows, options,
                       first_state, stop_state):
    """Check joint states ``[first_state, stop_state)``: their box poses, then the one pass.

    One compiled call from joint values to contacts: the forward kinematics writes each
    state's box poses, and small_scene.check_states (whose arguments follow) checks them, so
    each state's answer is the one pass's, bit for bit, on those poses. ``model_fields``:
    the RobotModel as a plain tuple (RobotBodies.model_fields).
    """
    model = RobotModel(*model_fields)
    count = model.half_extents.shape[0]
    poses = np.empty((joint_states.shape[0] * count, 7))  # only this chunk's rows are written
    link_rotations, link_translations = link_frames(model)
    for k in range(first_state, stop_state):
        forward_kinematics(model, base_pose, joint_states[k], poses[k * count:(k + 1) * count],
                           link_rotations, link_translations)
    return check_states(poses, count, model.half_extents, statics, rows, options, first_state,
                        stop_state)


@kernel
def first_uncleared_pieces(model_fields, base_pose, waypoints, pairs, margins, boxes,
                           resolution):
    """Return, per segment and pair, where its first piece the test cannot clear starts.

    ``boxes`` (centers, rotations, extents): rows 0..B-1 are written here for the robot's
    boxes, the static boxes follow them. ``pairs`` (P, 2) rows of ``boxes``, the first one a
    robot box, ``margins`` (P,) the distance within which each pair counts. Returns (W - 1, P):
    s in [0, 1) where the first piece not cleared starts, or -1 (the whole segment is free).
    ``model_fields``: the RobotModel as a plain tuple (RobotBodies.model_fields).
    """
    model = RobotModel(*model_fields)
    centers, rotations, extents = boxes
    count = model.half_extents.shape[0]
    dof = waypoints.shape[1]
    found = np.full((waypoints.shape[0] - 1, len(pairs)), -1.0)
    # q, box poses, link frames, and AABBs and radii (written by write_boxes, not read).
    link_rotations, link_translations = link_frames(model)
    scratch = (np.empty(dof), np.empty((count, 7)), link_rotations, link_translations,
               np.empty((count, 2, 3)), np.empty(count))
    reach = np.zeros(len(centers))  # per box: sum_j |dq_j| motion_radii[b, j]; statics 0
    # Depth-first over the pieces, left half first, so that a pair's first report is its
    # earliest. Row d of ``pending`` lists the pairs a piece of depth d still has to clear:
    # both halves of a piece read the row its test wrote (the left half's own pieces write
    # only deeper rows), so the boxes are placed once per piece for all its pairs.
    pending = np.empty((MAX_DEPTH + 1, len(pairs)), np.int64)
    pending_count = np.zeros(MAX_DEPTH + 1, np.int64)
    stack = np.empty((MAX_DEPTH + 2, 2))
    depths = np.empty(MAX_DEPTH + 2, np.int64)
    for k in range(waypoints.shape[0] - 1):
        for b in range(count):
            reach[b] = 0.0
            for j in range(dof):
                reach[b] += abs(waypoints[k + 1, j] - waypoints[k, j]) * model.motion_radii[b, j]
        pending[0, :] = np.arange(len(pairs))
        pending_count[0] = len(pairs)
        stack[0, 0], stack[0, 1], depths[0] = 0.0, 1.0, 0
        top = 1
        while top > 0:
            top -= 1
            s0, s1, depth = stack[top, 0], stack[top, 1], depths[top]
            half = 0.5 * (s1 - s0)
            _place(model, base_pose, waypoints[k], waypoints[k + 1], s0 + half, scratch, boxes)
            left = 0
            for i in range(pending_count[depth]):
                p = pending[depth, i]
                if found[k, p] >= 0.0:  # reported in an earlier piece
                    continue
                a, b = pairs[p, 0], pairs[p, 1]
                if _cleared(centers, rotations, extents, a, b, half * reach[a],
                            half * reach[b], margins[p]):
                    continue
                if half * (reach[a] + reach[b]) <= resolution or depth == MAX_DEPTH:
                    found[k, p] = s0
                    continue
                pending[depth + 1, left] = p
                left += 1
            if left:
                pending_count[depth + 1] = left
                stack[top, 0], stack[top, 1], depths[top] = s0 + half, s1, depth + 1
                stack[top + 1, 0], stack[top + 1, 1], depths[top + 1] = s0, s0 + half, depth + 1
                top += 2
    return found


@kernel
def _place(model, base_pose, start, end, s, scratch, boxes):
    """Write the robot's boxes at q(s) = start + s (end - start) into rows 0..B-1 of boxes."""
    q, poses, link_rotations, link_translations, aabbs, radii = scratch
    centers, rotations, extents = boxes
    for j in range(q.shape[0]):
        q[j] = start[j] + s * (end[j] - start[j])
    forward_kinematics(model, base_pose, q, poses, link_rotations, link_translations)
    write_boxes(poses, model.half_extents, 0, None, centers, rotations, extents, aabbs, radii)


@kernel
def _cleared(centers, rotations, extents, a, b, grow_a, grow_b, margin):
    """Tell whether boxes a and b stay over ``margin`` apart while moving up to ``grow_*``.

    Every point of a moves at most ``grow_a`` and of b ``grow_b``, so the pair is cleared when
    the boxes are more than ``grow_a + grow_b + margin`` apart now. Tested from cheap to exact:
    the bounding spheres; the SAT with that distance as its margin (an axis separating by
    more clears the pair, an overlap fails it); else the exact distance. The touching
    tolerance counts against clearing, so rounding never clears a pair that would touch.
    """
    ea = (extents[a, 0], extents[a, 1], extents[a, 2])
    eb = (extents[b, 0], extents[b, 1], extents[b, 2])
    d = (centers[b, 0] - centers[a, 0], centers[b, 1] - centers[a, 1],
         centers[b, 2] - centers[a, 2])
    apart = grow_a + grow_b + margin
    # The seed paper's sphere prefilter: most pairs of a free path part here, for a few flops.
    reach = math.sqrt(ea[0] * ea[0] + ea[1] * ea[1] + ea[2] * ea[2]) \
        + math.sqrt(eb[0] * eb[0] + eb[1] * eb[1] + eb[2] * eb[2]) + apart
    if d[0] * d[0] + d[1] * d[1] + d[2] * d[2] > reach * reach * SPHERE_SAFETY:
        return True
    rel, t = relative_pose(matrix(rotations, a), matrix(rotations, b), d)
    tie = TIE_ULPS * EPS * (sum_abs(ea) + sum_abs(eb) + sum_abs(d) + apart)
    status, _, _ = separating_axis_test(rel, t, ea, eb, tie, apart + tie)
    if status != NEAR:
        return status == SEPARATED
    return box_distance(rel, t, ea, eb)[0] > apart + tie
