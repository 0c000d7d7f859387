"""Oriented bounding boxes as flat arrays, built from poses.

A pose is ``x y z qx qy qz qw`` (ROS order). Each box is stored as a center (3,), a rotation
matrix (3, 3) whose columns are the box axes in world coordinates, half extents (3,), an
axis-aligned bounding box (2, 3) = (min corner, max corner) and the radius of its bounding
sphere. Everything is float64.
"""
import math
from typing import NamedTuple

import numpy as np

from collision_node.pipeline._jit import inlined_kernel, kernel

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
    BAD_QUATERNION: 'quaternion norm is not within %g of 1 (zero or not a rotation)'
                    % QUATERNION_NORM_TOLERANCE,
    BAD_HALF_EXTENTS: 'half extents must be finite, >= 0 and <= %g m' % MAX_COORDINATE,
    OUT_OF_RANGE: 'position beyond +-%g m' % MAX_COORDINATE,
}


class InvalidBox(ValueError):
    """A box that set_boxes refuses: ``body`` is its index in the input, ``reason`` why."""

    def __init__(self, body, reason):
        super().__init__('body %d: %s' % (body, reason))
        self.body = body
        self.reason = reason


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
    if rows is None:
        rows = np.arange(len(poses))
    bad, code = _write_boxes(poses, half_extents, start, rows, boxes)
    if bad >= 0:
        raise InvalidBox(bad, REASONS[code])


def check_boxes(poses, half_extents):
    """Raise InvalidBox naming the first body of ``poses`` that set_boxes would refuse.

    Returns the inputs as set_boxes reads them: poses (N, 7) and half extents (N, 3).
    """
    poses, half_extents = _as_inputs(poses, half_extents)
    bad, code = _first_problem(poses, half_extents)
    if bad >= 0:
        raise InvalidBox(bad, REASONS[code])
    return poses, half_extents


def _as_inputs(poses, half_extents):
    """Return poses (N, 7) and half extents (N, 3) as float64 C arrays; ValueError on shapes."""
    poses = np.require(poses, np.float64, ['C', 'A', 'W'])
    if poses.ndim != 2 or poses.shape[1] != 7:
        raise ValueError('poses must have shape (N, 7) as x y z qx qy qz qw, got %s'
                         % (poses.shape,))
    half_extents = np.asarray(half_extents, dtype=np.float64)
    if half_extents.shape == (3,):
        half_extents = np.broadcast_to(half_extents, (len(poses), 3))
    if half_extents.shape != (len(poses), 3):
        raise ValueError('half extents must have shape (3,) or (%d, 3), got %s'
                         % (len(poses), half_extents.shape))
    # A broadcast view is read-only (and, for 0 or 1 bodies, already contiguous): numba would
    # compile a separate signature for it during a tick, so make it a writable array.
    return poses, np.require(half_extents, np.float64, ['C', 'A', 'W'])


@kernel
def _rotation_from_quaternion(x, y, z, w, out):
    out[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    out[0, 1] = 2.0 * (x * y - z * w)
    out[0, 2] = 2.0 * (x * z + y * w)
    out[1, 0] = 2.0 * (x * y + z * w)
    out[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    out[1, 2] = 2.0 * (y * z - x * w)
    out[2, 0] = 2.0 * (x * z - y * w)
    out[2, 1] = 2.0 * (y * z + x * w)
    out[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@kernel
def _problem(poses, half_extents, i, e):
    """Return why body i (its half extents row e) cannot be a box (a REASONS code), or VALID."""
    for k in range(7):
        if not math.isfinite(poses[i, k]):
            return NON_FINITE_POSE
    for k in range(3):
        if abs(poses[i, k]) > MAX_COORDINATE:
            return OUT_OF_RANGE
    x, y, z, w = poses[i, 3], poses[i, 4], poses[i, 5], poses[i, 6]
    if not abs(math.sqrt(x * x + y * y + z * z + w * w) - 1.0) <= QUATERNION_NORM_TOLERANCE:
        return BAD_QUATERNION
    for k in range(3):
        e_k = half_extents[e, k]
        if not (math.isfinite(e_k) and 0.0 <= e_k <= MAX_COORDINATE):
            return BAD_HALF_EXTENTS
    return VALID


@kernel
def _first_problem(poses, half_extents):
    """Return (first body that cannot be a box, its REASONS code), or (-1, VALID)."""
    for i in range(poses.shape[0]):
        code = _problem(poses, half_extents, i, i)
        if code != VALID:
            return i, code
    return -1, VALID


@kernel
def _write_boxes(poses, half_extents, start, rows, boxes):
    """Write body i to row ``start + rows[i]``; return (first bad body, reason) or (-1, 0)."""
    for i in range(poses.shape[0]):
        code = write_box(poses, half_extents, i, i, start + rows[i], boxes.centers,
                         boxes.rotations, boxes.half_extents, boxes.aabbs, boxes.radii)
        if code != VALID:
            return i, code
    return -1, VALID


@inlined_kernel
def write_box(poses, half_extents, i, e, b, centers, rotations, extents, aabbs, radii):
    """Write body i (its pose row i, its half extents row e) to box row b; return a code.

    The code is VALID, or why the body cannot be a box (REASONS); then nothing is written.
    """
    code = _problem(poses, half_extents, i, e)
    if code != VALID:
        return code
    x, y, z, w = poses[i, 3], poses[i, 4], poses[i, 5], poses[i, 6]
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    # Scattered writes, sequential reads: measured faster than the other way round.
    _rotation_from_quaternion(x / norm, y / norm, z / norm, w / norm, rotations[b])
    radius_sq = 0.0
    for k in range(3):
        centers[b, k] = poses[i, k]
        extents[b, k] = half_extents[e, k]
        radius_sq += half_extents[e, k] * half_extents[e, k]
    radii[b] = math.sqrt(radius_sq)
    for k in range(3):
        reach = 0.0
        for j in range(3):
            reach += abs(rotations[b, k, j]) * extents[b, j]
        reach += AABB_RELATIVE_MARGIN * (reach + abs(centers[b, k]))
        aabbs[b, 0, k] = centers[b, k] - reach
        aabbs[b, 1, k] = centers[b, k] + reach
    return VALID


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

    Compares squared distances (the "Engine Algorithms" sphere test: no square roots); the
    radii are stored.
    """
    return centres_apart((centers[a, 0], centers[a, 1], centers[a, 2]),
                         (centers[b, 0], centers[b, 1], centers[b, 2]), radii[a], radii[b])


@kernel
def centres_apart(center_a, center_b, radius_a, radius_b):
    """:func:`spheres_apart` for two spheres given as tuples."""
    dist_sq = 0.0
    scale = radius_a + radius_b
    for i in range(3):
        d = center_b[i] - center_a[i]
        dist_sq += d * d
        scale += abs(center_a[i]) + abs(center_b[i])
    reach = radius_a + radius_b + TIE_ULPS * EPS * scale
    return dist_sq > reach * reach
