"""Oriented bounding boxes as flat arrays, built from poses.

A pose is ``x y z qx qy qz qw`` (ROS order). Each box is stored as a center (3,), a rotation
matrix (3, 3) whose columns are the box axes in world coordinates, half extents (3,), an
axis-aligned bounding box (2, 3) = (min corner, max corner) and the radius of its bounding
sphere. Everything is float64.

The rules of a valid box, margin and tolerance are written here once (:func:`check_boxes`,
:func:`check_margin`, :func:`check_tolerance`): the World, the static scene and the node's
parameters call them, so each refuses exactly what the others refuse.
"""
import math
from typing import NamedTuple

import numpy as np

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.frames import rotation_from_quaternion

# A quaternion whose norm is within this of 1 is normalised; farther off it is rejected.
# 1e-3 accepts quaternions printed with 4+ significant digits or stored as float32, and
# rejects the zero quaternion and anything that is clearly not a rotation.
QUATERNION_NORM_TOLERANCE = 1e-3

# The AABB is grown by this fraction of (extent + |center|) per axis so that it always contains
# the box despite rounding in R·e and at large offsets: a pair the SAT finds touching is never
# lost by the broad phase.
AABB_RELATIVE_MARGIN = 1e-12

EPS = float(np.finfo(np.float64).eps)
# Rounding in a pair's relative pose and projections is a few ulps of the magnitudes involved
# (centres, extents); this many ulps of that scale is the touching tolerance: closer to
# touching than that, a verdict may go either way (doc/accuracy.md).
TIE_ULPS = 64.0

# Positions and half extents beyond this many metres are rejected: no robot needs them (Earth's
# radius is 6.4e6 m), float64 keeps only ~0.1 mm there, and bounding them keeps every product
# in the broad phases and the SAT far from overflow, so a finite input never yields Inf/NaN.
MAX_COORDINATE = 1e9

# Codes returned by the validating kernel; REASONS turns them into words.
VALID = 0
NON_FINITE_POSE = 1
BAD_QUATERNION = 2
BAD_HALF_EXTENTS = 3
OUT_OF_RANGE = 4
REASONS = {
    NON_FINITE_POSE: 'pose has a NaN or Inf value',
    BAD_QUATERNION: 'quaternion norm is not within %g of 1: not a unit quaternion (zero or not '
                    'a rotation)' % QUATERNION_NORM_TOLERANCE,
    BAD_HALF_EXTENTS: 'half extents must be finite, >= 0 and <= %g m' % MAX_COORDINATE,
    OUT_OF_RANGE: 'position beyond +-%g m' % MAX_COORDINATE,
}


class InvalidBox(ValueError):
    """A box that set_boxes refuses: ``body`` is its index in the input, ``reason`` why."""

    def __init__(self, body, reason):
        super().__init__('body %d: %s' % (body, reason))
        self.body = body
        self.reason = reason


class InvalidDistance(ValueError):
    """A margin or tolerance :func:`check_margin` or :func:`check_tolerance` refuses.

    ``index`` is the first bad value's in the input, flattened (0 for a number); ``problem``
    says what is wrong without naming the setting, for a caller that names it its own way.
    """

    def __init__(self, what, index, problem):
        super().__init__('%s %s' % (what, problem))
        self.index = index
        self.problem = problem


class _BoxArrays(NamedTuple):
    centers: np.ndarray       # (N, 3)
    rotations: np.ndarray     # (N, 3, 3), columns are the box axes
    half_extents: np.ndarray  # (N, 3)
    aabbs: np.ndarray         # (N, 2, 3) min and max corner
    radii: np.ndarray         # (N,) bounding sphere radius
    # A box's own safety margin (a static collider's ``margin``; 0 for dynamic bodies): the
    # SAT adds both boxes' to the World's margin.
    margins: np.ndarray       # (N,)


class Boxes(_BoxArrays):
    """Preallocated structure-of-arrays storage for ``capacity`` boxes.

    A named tuple of flat arrays, so that kernels take the boxes as one argument.
    """

    __slots__ = ()

    def __new__(cls, capacity):
        return super().__new__(cls, np.zeros((capacity, 3)), np.zeros((capacity, 3, 3)),
                               np.zeros((capacity, 3)), np.zeros((capacity, 2, 3)),
                               np.zeros(capacity), np.zeros(capacity))

    @property
    def capacity(self):
        return len(self.radii)

    def grown(self, capacity, keep):
        """Return storage for ``capacity`` boxes holding a copy of the first ``keep``."""
        bigger = Boxes(capacity)
        for mine, theirs in zip(self, bigger):
            theirs[:keep] = mine[:keep]
        return bigger


def set_boxes(boxes, start, poses, half_extents, rows=None):
    """Write boxes from ``poses`` (N, 7) and ``half_extents`` (N, 3) or (3,) at ``start``.

    Body i goes to row ``start + rows[i]`` (default: ``start + i``); ``rows`` is a permutation
    of range(N). Raises InvalidBox (a ValueError) naming the first invalid body (index within
    ``poses``) and why.
    """
    poses, half_extents = _as_inputs(poses, half_extents)
    if start + len(poses) > boxes.capacity:
        raise ValueError('storage holds %d boxes, %d needed' % (boxes.capacity,
                                                                start + len(poses)))
    bad, code = write_boxes(poses, half_extents, start, rows, boxes.centers, boxes.rotations,
                            boxes.half_extents, boxes.aabbs, boxes.radii)
    if bad >= 0:
        raise InvalidBox(bad, REASONS[code])


def check_boxes(poses, half_extents):
    """Raise InvalidBox naming the first body of ``poses`` that set_boxes would refuse.

    Returns the inputs as set_boxes reads them: poses (N, 7), half extents (N, 3) or (1, 3).
    """
    poses, half_extents = _as_inputs(poses, half_extents)
    bad, code = _first_problem(poses, half_extents)
    if bad >= 0:
        raise InvalidBox(bad, REASONS[code])
    return poses, half_extents


def check_margin(value, what='margin'):
    """Return a margin in metres, a number or an array of them, as float64.

    A margin pads every box it applies to, so it has a box's bound: in [0, MAX_COORDINATE].
    Raises InvalidDistance naming ``what`` and the first value out of range (NaN included).
    """
    return _checked_distance(value, what, positive=False)


def check_tolerance(value, what='continuous tolerance'):
    """Return a tolerance in metres, a number or an array of them, as float64.

    A tolerance ends a search when the boxes are that close, so it must be more than 0 (a
    search to 0 would not end) and at most MAX_COORDINATE. Raises InvalidDistance as
    :func:`check_margin` does.
    """
    return _checked_distance(value, what, positive=True)


def _checked_distance(value, what, positive):
    if type(value) is float and (value > 0.0 if positive else value >= 0.0) \
            and value <= MAX_COORDINATE:  # the common case, without numpy's calls
        return value
    values = np.asarray(value, dtype=np.float64)
    above_low = values > 0.0 if positive else values >= 0.0
    bad = np.flatnonzero(~(above_low & (values <= MAX_COORDINATE)))  # NaN is never in range
    if len(bad):
        raise InvalidDistance(what, int(bad[0]), 'must be a distance in %s0, %g] m, got %r' % (
            '(' if positive else '[', MAX_COORDINATE, float(values.flat[bad[0]])))
    return float(values) if values.ndim == 0 else values


def _as_inputs(poses, half_extents):
    """Return poses (N, 7) and half extents (N, 3) as float64 C arrays; ValueError on shapes."""
    poses = np.require(poses, np.float64, ['C', 'A', 'W'])
    if poses.ndim != 2 or poses.shape[1] != 7:
        raise ValueError('poses must have shape (N, 7) as x y z qx qy qz qw, got %s'
                         % (poses.shape,))
    half_extents = np.asarray(half_extents, dtype=np.float64)
    if half_extents.shape == (3,):
        half_extents = half_extents.reshape(1, 3)  # one row for all: the kernels' convention
    elif half_extents.shape != (len(poses), 3):
        raise ValueError('half extents must have shape (3,) or (%d, 3), got %s'
                         % (len(poses), half_extents.shape))
    # Writable and contiguous, the one type the kernels are compiled for.
    return poses, np.require(half_extents, np.float64, ['C', 'A', 'W'])


@kernel
def _problem(pose, half):
    """Return why ``pose`` and ``half`` (tuples) cannot be a box (a REASONS code), or VALID."""
    for k in range(7):
        if not math.isfinite(pose[k]):
            return NON_FINITE_POSE
    for k in range(3):
        if abs(pose[k]) > MAX_COORDINATE:
            return OUT_OF_RANGE
    x, y, z, w = pose[3], pose[4], pose[5], pose[6]
    if not abs(math.sqrt(x * x + y * y + z * z + w * w) - 1.0) <= QUATERNION_NORM_TOLERANCE:
        return BAD_QUATERNION
    for k in range(3):
        if not (math.isfinite(half[k]) and 0.0 <= half[k] <= MAX_COORDINATE):
            return BAD_HALF_EXTENTS
    return VALID


@kernel
def _first_problem(poses, half_extents):
    """Return (first body that cannot be a box, its REASONS code), or (-1, VALID)."""
    for i in range(poses.shape[0]):
        code = _problem(_pose(poses, i), _half(half_extents, i))
        if code != VALID:
            return i, code
    return -1, VALID


@kernel
def _pose(poses, i):
    return (poses[i, 0], poses[i, 1], poses[i, 2], poses[i, 3], poses[i, 4], poses[i, 5],
            poses[i, 6])


@kernel
def _half(half_extents, i):
    """Return body i's half extents (row i, or the one row for all) as a 3-tuple."""
    e = i if half_extents.shape[0] > 1 else 0
    return half_extents[e, 0], half_extents[e, 1], half_extents[e, 2]


@kernel
def write_boxes(poses, half_extents, start, rows, centers, rotations, extents, aabbs, radii):
    """Write body i to row ``start + rows[i]``; return (first bad body, reason) or (-1, 0).

    ``half_extents``: one row per body, or one row for all; ``rows`` None: row start + i.
    The bodies before a bad one are written.
    """
    for i in range(poses.shape[0]):
        pose = _pose(poses, i)
        half = _half(half_extents, i)
        code = _problem(pose, half)
        if code != VALID:
            return i, code
        # Written here, not by a helper handed the arrays: a call numba does not inline
        # reference-counts each array it is given, twice the cost of the box itself.
        if rows is None:
            b = start + i
        else:
            b = start + rows[i]
        r, reach = box_axes(pose, half)
        rotations[b, 0, 0], rotations[b, 0, 1], rotations[b, 0, 2] = r[0], r[1], r[2]
        rotations[b, 1, 0], rotations[b, 1, 1], rotations[b, 1, 2] = r[3], r[4], r[5]
        rotations[b, 2, 0], rotations[b, 2, 1], rotations[b, 2, 2] = r[6], r[7], r[8]
        radii[b] = math.sqrt(half[0] * half[0] + half[1] * half[1] + half[2] * half[2])
        for k in range(3):
            centers[b, k] = pose[k]
            extents[b, k] = half[k]
            aabbs[b, 0, k] = pose[k] - reach[k]
            aabbs[b, 1, k] = pose[k] + reach[k]
    return -1, VALID


@kernel
def box_axes(pose, half):
    """Return the rotation (row-major 9-tuple) of a valid ``pose`` and its AABB's half widths.

    The one place a pose's quaternion becomes the box a check tests (write_boxes, and the
    robot's pass, which places its boxes without writing their poses): scalars in and out,
    so that a caller's arrays are not handed to a call.
    """
    x, y, z, w = pose[3], pose[4], pose[5], pose[6]
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    r = rotation_from_quaternion(x / norm, y / norm, z / norm, w / norm)
    reach = (abs(r[0]) * half[0] + abs(r[1]) * half[1] + abs(r[2]) * half[2],
             abs(r[3]) * half[0] + abs(r[4]) * half[1] + abs(r[5]) * half[2],
             abs(r[6]) * half[0] + abs(r[7]) * half[1] + abs(r[8]) * half[2])
    return r, (reach[0] + AABB_RELATIVE_MARGIN * (reach[0] + abs(pose[0])),
               reach[1] + AABB_RELATIVE_MARGIN * (reach[1] + abs(pose[1])),
               reach[2] + AABB_RELATIVE_MARGIN * (reach[2] + abs(pose[2])))


@kernel
def pad_bounds(aabbs, radii, margins, rows, first, pad):
    """Grow the AABB and bounding radius of rows ``first + rows[k]`` by ``pad`` + its margin.

    Boxes within distance m of each other have AABBs within m of each other on every axis
    (and bounding spheres within m): padding both boxes of a pair by half its margin lets the
    broad phase and the sphere test keep every pair the margin may report. ``rows`` may be
    any subset (moved static boxes) or a permutation (all the dynamic rows, no range built).
    """
    for k in range(len(rows)):
        row = first + rows[k]
        grow = pad + margins[row]
        for m in range(3):
            aabbs[row, 0, m] -= grow
            aabbs[row, 1, m] += grow
        radii[row] += grow


@kernel
def aabbs_overlap(aabbs, a, b):
    """Return True when the (closed) AABBs of boxes a and b overlap or touch."""
    for k in range(3):
        if aabbs[a, 0, k] > aabbs[b, 1, k] or aabbs[b, 0, k] > aabbs[a, 1, k]:
            return False
    return True


@kernel
def overlap_across(aabbs_a, a, aabbs_b, b):
    """:func:`aabbs_overlap` for boxes in two arrays (closed intervals).

    Computed without branches: in a cell the outcome is a coin flip, and six unpredictable
    branches cost more than six comparisons (measured 3x slower with branches).
    """
    apart = (aabbs_a[a, 0, 0] > aabbs_b[b, 1, 0]) | (aabbs_b[b, 0, 0] > aabbs_a[a, 1, 0]) \
        | (aabbs_a[a, 0, 1] > aabbs_b[b, 1, 1]) | (aabbs_b[b, 0, 1] > aabbs_a[a, 1, 1]) \
        | (aabbs_a[a, 0, 2] > aabbs_b[b, 1, 2]) | (aabbs_b[b, 0, 2] > aabbs_a[a, 1, 2])
    return not apart


@kernel
def spheres_apart(centers, radii, a, b):
    """Return True when the bounding spheres are apart by more than the touching tolerance.

    Compares squared distances (the paper's "no square roots"); the radii are stored.
    """
    dist_sq = 0.0
    scale = radii[a] + radii[b]
    for i in range(3):
        d = centers[b, i] - centers[a, i]
        dist_sq += d * d
        scale += abs(centers[a, i]) + abs(centers[b, i])
    reach = radii[a] + radii[b] + TIE_ULPS * EPS * scale
    return dist_sq > reach * reach
