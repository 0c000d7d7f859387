"""Separating axis test (SAT) between oriented boxes, over an array of candidate pairs.

Everything is computed in float64 in the frame of box A of each pair: R = AᵀB and
t = Aᵀ(c_B − c_A). Working relative to A keeps the numbers as small as the pair, not as
large as its distance from the world origin.

Verdict: a pair collides when none of the 15 axes (3 face axes of A, 3 of B, 9 edge×edge)
separates it; touching counts as colliding. The verdict is exact except within

    touch_tolerance(A, B) = TIE_ULPS · eps · (Σ half extents of A and B + ‖c_B − c_A‖₁)

of touching, where rounding may decide either way. "Distance from touching" is the exact
SAT separation: the largest gap between the boxes' projections over the 15 axes (normalised),
or minus the least overlap when none separates. The scale is that of the pair and of its
relative position, not of its distance from the origin: subtracting the centres is the only
operation on world coordinates, and it is exact for nearby centres (Sterbenz). The tolerance
covers the float64 rotation matrices as well (the pose's quaternion is normalised in
float64), and quaternions off unit norm by up to obb.QUATERNION_NORM_TOLERANCE. Checked
against an exact rational referee (test/exact_sat.py) on the stress classes of
test/test_sat_stress.py: every verdict that differed from it was within half an ulp of that
scale from touching, so TIE_ULPS = 64 leaves a wide margin.

Depth, normal and contact point of a colliding pair:

* normal: unit vector, world frame, along the axis of least overlap, pointing from A to B
  (t·normal ≥ 0; any sign when B's centre projects onto A's, e.g. concentric boxes);
* depth: the overlap of the two boxes' projections on that axis, i.e. how far B has to move
  along the normal until the boxes only touch; this least overlap over the 15 axes is the
  exact penetration depth of two boxes. For a box contained in another this is the distance
  to push it out through the nearest side, which is more than its own size;
* point: on the line through an anchor along the normal, the midpoint of the chord that both
  boxes cut from it. The anchor is the middle of the deepest feature of B along −normal
  (vertex, edge or face) clamped into A for A's face axes, the same with A and B swapped for
  B's face axes, and the midpoint of the closest points of the two edges for edge×edge axes;
  when that chord is empty (rounding at touching, near-parallel edges), the other anchors are
  tried. Plates and needles can be crossed by no chord along the normal at all: then the
  chord along a needle's spine, or along the line where two plates' mid-planes cross, is
  taken. So the point lies in both boxes (within the touching tolerance), halfway through
  the overlap along the normal, and inside the contained box for containment. Should every
  chord miss (never seen in the stress tests), the point is the first anchor.

Face axes win ties with edge axes: an edge×edge axis is taken only when its overlap is less
than every face axis' by more than the touching tolerance, so boxes resting face on face never
get a phantom contact along a noisy edge×edge axis. Hence the depth is the exact least overlap
to within the touching tolerance, and the normal the exact axis of that overlap (or, on a tie
within the tolerance, one of the tied axes) to a few eps, or a few eps / sin θ on the
edge×edge axis of two edges at an angle θ: float64 rotation matrices define the direction of
nearly parallel edges' cross product no better (the depth stays accurate, and the boxes
overlap along the reported normal by the reported depth).

Near pairs (apart, within a margin): the distance is exact (distance.py), the point is the
midpoint of the closest points, and the normal the direction between the closest features
(distance.box_distance, "Normal"), so that point ∓ normal · distance / 2 are the closest
points. Should rounding tilt that direction out of the features' normal cones by enough to
lose more than the touching tolerance against the SAT's widest gap, the normal is the SAT's
widest-gap axis instead (never taken in the tests). So at every gap the normal is unit and
separates the boxes within the touching tolerance. Checked against the exact referee
(test/test_distance.py, every class, gaps 1e-15 to 10 × size): the points lie on their boxes
within 1e-11 × the pair's size (near-parallel edges far apart; 1e-14 elsewhere), and the
boxes' projections on the normal are apart by the distance within 3e-14 × size. What
float64 cannot promise: if the SAT's axis is ever taken, the points are off their boxes by up
to half the distance × its angle to the features' direction.

Non-finite input: any NaN or Inf in the centres, rotations or half extents of a pair, or an
overflow of its relative pose (centres ~1e308 apart), makes its status INVALID (never
SEPARATED or COLLIDING), also when the sphere prefilter would have rejected the pair. The
radii only feed the sphere prefilter: a NaN radius makes it keep the pair.
"""
import math
from typing import NamedTuple

import numpy as np

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.distance import box_distance
from collision_node.pipeline.frames import (column, cross, dot, edge_overlap, face_a_overlap,
                                            face_b_overlap, matrix, MIN_EDGE_AXIS_LENGTH,
                                            projection_gap, relative_pose, rotate, sum_abs,
                                            zero_if_finite, zero_if_finite_matrix)
from collision_node.pipeline.obb import EPS, spheres_apart, TIE_ULPS

SEPARATED = 0
COLLIDING = 1
INVALID = 2  # a NaN or Inf reached the test: it claims neither verdict
NEAR = 3     # apart, but within the pair's margin (exact distance)

# A box axis this close to perpendicular to the normal counts as lying flat on it when the
# contact feature is picked, so a face lying on a face yields the middle of that face.
FEATURE_TOLERANCE = 1e-9

# The 15 axes by number: 0-2 A's axes (faces), 3-5 B's axes, then 6 + 3i + j for the edge
# axis A's axis i × B's axis j. Contact anchors are numbered like the kinds of axis.
_FIRST_B_FACE = 3
_FIRST_EDGE = 6
_B_FEATURE_IN_A = 0
_A_FEATURE_IN_B = 1
_EDGE_CLOSEST_POINTS = 2


def touch_tolerance(center_a, center_b, half_extents_a, half_extents_b):
    """Distance from touching within which the verdict on boxes A and B may go either way."""
    scale = (np.sum(half_extents_a) + np.sum(half_extents_b)
             + np.sum(np.abs(np.subtract(center_b, center_a))))
    return TIE_ULPS * EPS * float(scale)


def collide_pairs(centers, rotations, half_extents, radii, pairs, sphere_prefilter=False,
                  out=None, margin=0.0, box_margins=None):
    """Run the SAT on each row ``(a, b)`` of ``pairs`` (P, 2).

    Returns ``(status, depth, normal, point, sat_tests)``: status (P,) int8 SEPARATED,
    COLLIDING, NEAR or INVALID; depth (P,), normal (P, 3) and point (P, 3) valid where
    COLLIDING or NEAR; ``sat_tests`` the number of pairs that reached the SAT (the rest failed
    the sphere test). The four arrays are the first P rows of ``out`` when given (see
    :func:`empty_output`).

    Margin: a pair of boxes apart by at most ``margin`` + ``box_margins[a]`` +
    ``box_margins[b]`` (exact Euclidean distance) is NEAR; its depth is minus that distance,
    its point the midpoint of the closest points, its normal the unit direction from A's
    closest point to B's (module docstring, "Near pairs"), so that the closest points are
    point ∓ normal · distance / 2. The radii (for the sphere test) must include the margins
    (obb.pad_bounds). With no margin the result is bit for bit that of the plain SAT.
    """
    pairs = np.ascontiguousarray(pairs, dtype=np.int64).reshape(-1, 2)
    n = len(pairs)
    if n and (pairs.min() < 0 or pairs.max() >= len(centers)):
        raise ValueError('pair indices must lie in [0, %d)' % len(centers))
    if out is None or len(out[0]) < n:
        out = empty_output(n)
    status, depth, normal, point = (array[:n] for array in out)
    # No margin at all compiles a kernel without the margin's bookkeeping (None prunes its
    # branches): the plain SAT pays nothing for margins (their bookkeeping in the axis loop
    # costs about a fifth of the SAT).
    if box_margins is None:
        margin = None if margin == 0.0 else float(margin)
    else:
        margin = float(margin)
        box_margins = np.ascontiguousarray(box_margins, dtype=np.float64)
    sat_tests = collide_pair_rows(centers, rotations, half_extents, radii, pairs,
                                  bool(sphere_prefilter), margin, box_margins, status, depth,
                                  normal, point)
    return status, depth, normal, point, sat_tests


# Rotation matrices must be orthonormal to this (max |RᵀR − I|) for signed_distance: float64
# rotations built from a normalised quaternion are off by ~1e-16; one stored as float32 (1e-7)
# would move the distance by more than the accuracy the kernels promise.
ORTHONORMAL_TOLERANCE = 1e-12


class SignedDistance(NamedTuple):
    """Two boxes' signed distance, as :func:`signed_distance` returns it (world frame)."""

    distance: float         # > 0 apart, ≤ 0 touching or overlapping (minus the depth)
    point_a: np.ndarray     # closest point of A (apart), else the contact point
    point_b: np.ndarray     # closest point of B (apart), else the contact point
    normal: np.ndarray      # unit, from A to B: the cloud's normal


def signed_distance(center_a, rotation_a, half_extents_a, center_b, rotation_b,
                    half_extents_b):
    """Return the :class:`SignedDistance` of two boxes, by the World's own code path.

    Centres (3,), rotation matrices (3, 3) with the box axes as columns, half extents (3,).
    Apart: the exact distance (> 0), the closest points of A and B, which are the cloud's
    point ∓ normal · distance / 2. Touching or overlapping: minus the penetration depth
    (≤ 0), both points the contact point. This is :func:`collide_pairs` with an infinite
    margin. Raises ValueError on wrong shapes, non-finite values, negative half extents or
    rotations that are not orthonormal.
    """
    center_a = _checked(center_a, (3,), 'center_a')
    center_b = _checked(center_b, (3,), 'center_b')
    rotation_a = _checked(rotation_a, (3, 3), 'rotation_a')
    rotation_b = _checked(rotation_b, (3, 3), 'rotation_b')
    half_extents_a = _checked(half_extents_a, (3,), 'half_extents_a')
    half_extents_b = _checked(half_extents_b, (3,), 'half_extents_b')
    for name, rotation in (('rotation_a', rotation_a), ('rotation_b', rotation_b)):
        if np.abs(rotation.T @ rotation - np.eye(3)).max() > ORTHONORMAL_TOLERANCE:
            raise ValueError('%s must be orthonormal to %g (build it from a normalised '
                             'quaternion)' % (name, ORTHONORMAL_TOLERANCE))
    for name, half_extents in (('half_extents_a', half_extents_a),
                               ('half_extents_b', half_extents_b)):
        if (half_extents < 0.0).any():
            raise ValueError('%s must be >= 0' % name)
    status, depth, normal, point, _ = collide_pairs(
        np.array([center_a, center_b]), np.array([rotation_a, rotation_b]),
        np.array([half_extents_a, half_extents_b]), np.zeros(2), np.array([[0, 1]]),
        margin=math.inf)
    if status[0] == INVALID:
        raise ValueError('the centres %s and %s are too far apart for float64'
                         % (center_a, center_b))
    distance = -depth[0]
    gap = 0.5 * max(distance, 0.0) * normal[0]
    return SignedDistance(distance, point[0] - gap, point[0] + gap, normal[0].copy())


def _checked(value, shape, name):
    array = np.asarray(value, dtype=np.float64)
    if array.shape != shape:
        raise ValueError('%s must have shape %s, got %s' % (name, shape, array.shape))
    if not np.isfinite(array).all():
        raise ValueError('%s has a NaN or Inf value' % name)
    return array


def empty_output(capacity):
    """Return (status, depth, normal, point) arrays for up to ``capacity`` pairs.

    A caller that keeps them for the next call saves fresh pages every time: at 100,000
    bodies the output is ~16 MB, and its page faults cost 4 % of the SAT.
    """
    return (np.empty(capacity, np.int8), np.empty(capacity), np.empty((capacity, 3)),
            np.empty((capacity, 3)))


# Notation and speed notes: frames.py. R = AᵀB as a row-major 9-tuple (``rel``), t = B's
# centre in A's frame; ea, eb the half extents.

@kernel
def collide_pair_rows(centers, rotations, extents, radii, pairs, sphere_prefilter, margin,
                      box_margins, status, depth, normal, point):
    """Run collide_pairs' loop, unchecked: the kernel of the general path and of the one pass.

    ``margin`` None (no margin at all) or a float; ``box_margins`` None or one margin per box.
    The normal and point are written for COLLIDING and NEAR pairs only.
    """
    sat_tests = 0
    for k in range(pairs.shape[0]):
        a = pairs[k, 0]
        b = pairs[k, 1]
        ea = (extents[a, 0], extents[a, 1], extents[a, 2])
        eb = (extents[b, 0], extents[b, 1], extents[b, 2])
        ra = matrix(rotations, a)
        rb = matrix(rotations, b)
        if sphere_prefilter and spheres_apart(centers, radii, a, b):
            # NaN centres and radii never pass the sphere test; the rest is checked here.
            finite = zero_if_finite_matrix(ra) + zero_if_finite_matrix(rb) \
                + zero_if_finite(ea) + zero_if_finite(eb) == 0.0
            status[k] = SEPARATED if finite else INVALID
            continue
        sat_tests += 1
        d = (centers[b, 0] - centers[a, 0], centers[b, 1] - centers[a, 1],
             centers[b, 2] - centers[a, 2])
        rel, t = relative_pose(ra, rb, d)
        # Every input reaches ea, eb, d, R (all entries of both rotations) or t: a NaN or an
        # Inf anywhere, or an overflow, shows up here.
        scale = sum_abs(ea) + sum_abs(eb) + sum_abs(d)
        if not (math.isfinite(scale)
                and zero_if_finite_matrix(rel) + zero_if_finite(t) == 0.0):
            status[k] = INVALID
            continue
        tie = TIE_ULPS * EPS * scale
        if margin is None:
            status[k], depth[k], axis_id = separating_axis_test(rel, t, ea, eb, tie, None)
            pair_margin = 0.0
        else:
            pair_margin = margin if box_margins is None else \
                margin + box_margins[a] + box_margins[b]
            status[k], depth[k], axis_id = separating_axis_test(rel, t, ea, eb, tie,
                                                                pair_margin)
        if status[k] == COLLIDING:
            axis, local_point = _contact(rel, t, ea, eb, tie, axis_id)
        elif margin is not None and status[k] == NEAR:
            widest_gap = -depth[k]
            distance, on_a, on_b, closest = box_distance(rel, t, ea, eb)
            if not distance <= pair_margin:
                status[k] = SEPARATED
                continue
            depth[k] = -distance
            axis = _near_normal(rel, t, ea, eb, tie, closest, widest_gap, axis_id)
            local_point = (0.5 * (on_a[0] + on_b[0]), 0.5 * (on_a[1] + on_b[1]),
                           0.5 * (on_a[2] + on_b[2]))
        else:
            continue
        world_normal = rotate(ra, axis)
        world_offset = rotate(ra, local_point)
        for m in range(3):
            normal[k, m] = world_normal[m]
            point[k, m] = centers[a, m] + world_offset[m]
    return sat_tests


@kernel
def _near_normal(rel, t, ea, eb, tie, closest, widest_gap, axis_id):
    """Return the unit normal of a NEAR pair: ``closest``, or the SAT's axis if that is wider.

    ``closest`` is box_distance's direction between the closest features (zero when it has
    none). The boxes' projections on it are apart by the distance, at least ``widest_gap``
    (the SAT's widest gap, on axis ``axis_id``), as long as rounding leaves it inside the
    features' normal cones. When rounding tilts it out of them by enough to lose more than
    the touching tolerance ``tie`` against the SAT's gap, the SAT's axis is the normal (module
    docstring, "Near pairs"): the normal always separates the boxes, within ``tie``.
    """
    if (closest[0] != 0.0 or closest[1] != 0.0 or closest[2] != 0.0) and \
            projection_gap(rel, t, ea, eb, closest) >= widest_gap - tie:
        return closest
    return _unit_axis(rel, t, axis_id)


@kernel
def separating_axis_test(rel, t, ea, eb, tie, margin):
    """Return (status, overlap, axis number) of the pair, in A's frame.

    Separated: the (negative) overlap on the first axis found that separates the boxes by
    more than ``margin``. Near: no axis separates them by more than ``margin`` but some does
    (the widest gap, negated, and its axis; the exact distance is at least that gap).
    Colliding: the least overlap and its axis. With ``margin`` 0 nothing is near; with
    ``margin`` None the margin's bookkeeping is not even compiled.
    """
    faces = (face_a_overlap(rel, t, ea, eb, 0), face_a_overlap(rel, t, ea, eb, 1),
             face_a_overlap(rel, t, ea, eb, 2), face_b_overlap(rel, t, ea, eb, 0),
             face_b_overlap(rel, t, ea, eb, 1), face_b_overlap(rel, t, ea, eb, 2))
    best = np.inf
    best_id = 0
    axis_id = 0
    widest_gap = 0.0  # the widest separation within the margin, and its axis
    gap_id = 0
    for overlap in faces:
        if overlap < 0.0:
            if margin is None or overlap < -margin:
                return SEPARATED, overlap, axis_id
            if -overlap > widest_gap:
                widest_gap, gap_id = -overlap, axis_id
        elif overlap < best:
            best, best_id = overlap, axis_id
        axis_id += 1
    # Face axes win ties: an edge axis has to beat them by the touching tolerance.
    best_face = best
    edges = (edge_overlap(rel, t, ea, eb, 0, 0), edge_overlap(rel, t, ea, eb, 0, 1),
             edge_overlap(rel, t, ea, eb, 0, 2), edge_overlap(rel, t, ea, eb, 1, 0),
             edge_overlap(rel, t, ea, eb, 1, 1), edge_overlap(rel, t, ea, eb, 1, 2),
             edge_overlap(rel, t, ea, eb, 2, 0), edge_overlap(rel, t, ea, eb, 2, 1),
             edge_overlap(rel, t, ea, eb, 2, 2))
    for overlap, length_sq in edges:
        # overlap is scaled by the axis length: its sign needs no normalising, and
        # overlap / length < limit is compared squared (both sides >= 0) without a root.
        if overlap < 0.0:
            gap = -overlap / math.sqrt(length_sq)
            if margin is None or gap > margin:
                return SEPARATED, -gap, axis_id
            if gap > widest_gap:
                widest_gap, gap_id = gap, axis_id
            axis_id += 1
            continue
        limit = min(best, best_face - tie)
        if (length_sq >= MIN_EDGE_AXIS_LENGTH ** 2 and limit > 0.0
                and overlap * overlap < limit * limit * length_sq):
            best, best_id = overlap / math.sqrt(length_sq), axis_id
        axis_id += 1
    if widest_gap > 0.0:
        return NEAR, -widest_gap, gap_id
    return COLLIDING, best, best_id


@kernel
def _sign_of(x):
    if x > FEATURE_TOLERANCE:
        return 1.0
    if x < -FEATURE_TOLERANCE:
        return -1.0
    return 0.0


@kernel
def _unit_axis(rel, t, axis_id):
    """Return axis ``axis_id`` as a unit vector in A's frame, turned to point from A to B."""
    if axis_id < _FIRST_B_FACE:
        s = 1.0 if t[axis_id] >= 0.0 else -1.0
        return (s if axis_id == 0 else 0.0, s if axis_id == 1 else 0.0,
                s if axis_id == 2 else 0.0)
    if axis_id < _FIRST_EDGE:
        b_j = column(rel, axis_id - _FIRST_B_FACE)
        s = 1.0 if dot(t, b_j) >= 0.0 else -1.0
        return s * b_j[0], s * b_j[1], s * b_j[2]
    return _edge_axis(rel, t, (axis_id - _FIRST_EDGE) // 3, (axis_id - _FIRST_EDGE) % 3)


@kernel
def _contact(rel, t, ea, eb, tie, axis_id):
    """Return the unit axis (A → B) and the contact point, in A's frame."""
    axis = _unit_axis(rel, t, axis_id)
    if axis_id < _FIRST_B_FACE:
        first = _B_FEATURE_IN_A
    elif axis_id < _FIRST_EDGE:
        first = _A_FEATURE_IN_B
    else:
        first = _EDGE_CLOSEST_POINTS
    # The anchor that belongs to the axis first, then the others (the closest points of the
    # edges only exist for an edge axis).
    for attempt in range(3):
        anchor = (first + attempt) % 3
        if anchor == _EDGE_CLOSEST_POINTS and first != _EDGE_CLOSEST_POINTS:
            continue
        found, p = _chord_midpoint(rel, t, ea, eb, tie, axis,
                                   _anchor(rel, t, ea, eb, anchor, axis_id, axis))
        if found:
            return axis, p
    # Plates and needles: their intersection can be too small for any chord along the
    # normal to hit. A needle's intersection with the other box lies on its spine, two
    # plates' on the line where their mid-planes cross.
    a_axes = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    b_axes = (column(rel, 0), column(rel, 1), column(rel, 2))
    found, p = _chord_midpoint(rel, t, ea, eb, tie, a_axes[_longest(ea)], (0.0, 0.0, 0.0))
    if found:
        return axis, p
    found, p = _chord_midpoint(rel, t, ea, eb, tie, b_axes[_longest(eb)], t)
    if found:
        return axis, p
    normal_a = a_axes[_shortest(ea)]
    normal_b = b_axes[_shortest(eb)]
    cosine = dot(normal_a, normal_b)
    direction = cross(normal_a, normal_b)
    sine_sq = dot(direction, direction)
    if sine_sq > 0.0:
        # The point of both mid-planes (normal_a·p = 0, normal_b·p = normal_b·t) closest to
        # A's centre.
        scale = dot(normal_b, t) / sine_sq
        on_both = (scale * (normal_b[0] - cosine * normal_a[0]),
                   scale * (normal_b[1] - cosine * normal_a[1]),
                   scale * (normal_b[2] - cosine * normal_a[2]))
        found, p = _chord_midpoint(rel, t, ea, eb, tie, direction, on_both)
        if found:
            return axis, p
    return axis, _anchor(rel, t, ea, eb, first, axis_id, axis)  # not seen in the tests


@kernel
def _longest(extents):
    """Return the index of the largest of three half extents."""
    if extents[0] >= extents[1] and extents[0] >= extents[2]:
        return 0
    return 1 if extents[1] >= extents[2] else 2


@kernel
def _shortest(extents):
    """Return the index of the smallest of three half extents."""
    if extents[0] <= extents[1] and extents[0] <= extents[2]:
        return 0
    return 1 if extents[1] <= extents[2] else 2


@kernel
def _edge_axis(rel, t, i, j):
    """Return the unit axis e_i × b_j, turned to point from A to B."""
    i1 = (i + 1) % 3
    i2 = (i + 2) % 3
    u1 = -rel[3 * i2 + j]
    u2 = rel[3 * i1 + j]
    length = math.sqrt(u1 * u1 + u2 * u2)
    if u1 * t[i1] + u2 * t[i2] < 0.0:
        length = -length
    u1 /= length
    u2 /= length
    if i == 0:
        return 0.0, u1, u2
    if i == 1:
        return u2, 0.0, u1
    return u1, u2, 0.0


@kernel
def _anchor(rel, t, ea, eb, anchor, axis_id, axis):
    if anchor == _B_FEATURE_IN_A:
        return _b_feature_in_a(rel, t, ea, eb, axis)
    if anchor == _A_FEATURE_IN_B:
        return _a_feature_in_b(rel, t, ea, eb, axis)
    return _edge_closest_points(rel, t, ea, eb, (axis_id - _FIRST_EDGE) // 3,
                                (axis_id - _FIRST_EDGE) % 3, axis)


@kernel
def _b_feature_in_a(rel, t, ea, eb, axis):
    """Return the middle of B's deepest feature along −axis, clamped into A."""
    p = _minus_support(rel, t, eb, axis, -1)
    return (min(max(p[0], -ea[0]), ea[0]), min(max(p[1], -ea[1]), ea[1]),
            min(max(p[2], -ea[2]), ea[2]))


@kernel
def _minus_support(rel, t, eb, axis, skip):
    """Return the middle of B's deepest feature along −axis (leaving out B's axis ``skip``)."""
    p = _step_back(t, rel, eb, axis, 0, skip)
    p = _step_back(p, rel, eb, axis, 1, skip)
    return _step_back(p, rel, eb, axis, 2, skip)


@kernel
def _step_back(p, rel, eb, axis, k, skip):
    """Move ``p`` along B's axis k to B's side that faces −axis (unless k == skip)."""
    b_k = column(rel, k)
    toward = eb[k] * _sign_of(dot(axis, b_k)) if k != skip else 0.0
    return p[0] - toward * b_k[0], p[1] - toward * b_k[1], p[2] - toward * b_k[2]


@kernel
def _a_feature_in_b(rel, t, ea, eb, axis):
    """Return the middle of A's deepest feature along +axis, clamped into B (A's frame)."""
    q = (ea[0] * _sign_of(axis[0]) - t[0], ea[1] * _sign_of(axis[1]) - t[1],
         ea[2] * _sign_of(axis[2]) - t[2])
    u0 = min(max(dot(column(rel, 0), q), -eb[0]), eb[0])
    u1 = min(max(dot(column(rel, 1), q), -eb[1]), eb[1])
    u2 = min(max(dot(column(rel, 2), q), -eb[2]), eb[2])
    return (t[0] + rel[0] * u0 + rel[1] * u1 + rel[2] * u2,
            t[1] + rel[3] * u0 + rel[4] * u1 + rel[5] * u2,
            t[2] + rel[6] * u0 + rel[7] * u1 + rel[8] * u2)


@kernel
def _edge_closest_points(rel, t, ea, eb, i, j, axis):
    """Midpoint of the closest points of A's and B's edges that support the edge axis."""
    # A's edge runs along e_i through A's support point along +axis (pa);
    # B's edge runs along b_j through B's support point along -axis (pb).
    pa = (ea[0] * _sign_of(axis[0]) if i != 0 else 0.0,
          ea[1] * _sign_of(axis[1]) if i != 1 else 0.0,
          ea[2] * _sign_of(axis[2]) if i != 2 else 0.0)
    pb = _minus_support(rel, t, eb, axis, j)
    b_j = column(rel, j)
    # Closest points of P(s) = pa + s e_i, |s| <= ea_i, and Q(u) = pb + u b_j, |u| <= eb_j
    # (Ericson, Real-Time Collision Detection, 5.1.9, with centred parameters).
    r = (pa[0] - pb[0], pa[1] - pb[1], pa[2] - pb[2])
    c = r[i]
    f = dot(b_j, r)
    b_len_sq = dot(b_j, b_j)
    cos_ab = b_j[i]
    denom = b_len_sq - cos_ab * cos_ab
    s = 0.0
    if denom > 0.0:
        s = min(max((cos_ab * f - c * b_len_sq) / denom, -ea[i]), ea[i])
    u = (cos_ab * s + f) / b_len_sq
    if u < -eb[j] or u > eb[j]:
        u = min(max(u, -eb[j]), eb[j])
        s = min(max(cos_ab * u - c, -ea[i]), ea[i])
    return (0.5 * (pa[0] + (s if i == 0 else 0.0) + pb[0] + u * b_j[0]),
            0.5 * (pa[1] + (s if i == 1 else 0.0) + pb[1] + u * b_j[1]),
            0.5 * (pa[2] + (s if i == 2 else 0.0) + pb[2] + u * b_j[2]))


@kernel
def _chord_midpoint(rel, t, ea, eb, tie, axis, p):
    """Return (True, the middle of the chord both boxes cut from the line p + s·axis).

    Or (False, p) when the line misses a box by more than the touching tolerance.
    """
    # Each slab as |x + s·y| <= e: A's three in A's frame, B's three in B's frame.
    offset = (p[0] - t[0], p[1] - t[1], p[2] - t[2])
    b_0, b_1, b_2 = column(rel, 0), column(rel, 1), column(rel, 2)
    slabs = ((p[0], axis[0], ea[0]), (p[1], axis[1], ea[1]), (p[2], axis[2], ea[2]),
             (dot(b_0, offset), dot(b_0, axis), eb[0]),
             (dot(b_1, offset), dot(b_1, axis), eb[1]),
             (dot(b_2, offset), dot(b_2, axis), eb[2]))
    # (low, high, |y| of the slab that set low, |y| of the one that set high, still open)
    chord = (-np.inf, np.inf, 0.0, 0.0, True)
    for slab in slabs:
        chord = _clip(chord, slab, tie)
    low, high, low_slope, high_slope, open_ = chord
    if not open_:
        return False, p
    if low <= high:
        s = 0.5 * (low + high)
    else:
        # Empty, maybe by rounding: a slab nearly parallel to the line turns a tiny excess
        # into a large step in s. Take the s that leaves the two crossing slabs by the same
        # distance, and accept it if no slab is left by more than the touching tolerance.
        s = (low * low_slope + high * high_slope) / (low_slope + high_slope)
        for x, y, e in slabs:
            if not abs(x + s * y) <= e + tie:
                return False, p
    return True, (p[0] + s * axis[0], p[1] + s * axis[1], p[2] + s * axis[2])


@kernel
def _clip(chord, slab, tie):
    """Narrow the chord's parameter range to the slab |x + s·y| <= e."""
    low, high, low_slope, high_slope, open_ = chord
    x, y, e = slab
    if y == 0.0:
        return low, high, low_slope, high_slope, open_ and abs(x) <= e + tie
    inverse = 1.0 / y
    s0 = (-e - x) * inverse
    s1 = (e - x) * inverse
    if min(s0, s1) > low:
        low, low_slope = min(s0, s1), abs(y)
    if max(s0, s1) < high:
        high, high_slope = max(s0, s1), abs(y)
    return low, high, low_slope, high_slope, open_


# The per-pair test, for continuous.py's conservative advancement.
separating_axis_test = separating_axis_test
