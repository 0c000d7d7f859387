"""An exact referee for the distance between two solid oriented boxes, for tests only.

Everything in rational arithmetic (:class:`fractions.Fraction`) on the inputs as given, in the
world frame. As in exact_sat.py, a box's rotation is M(q) / |q|² of its quaternion, not
normalised: exactly rational and exactly orthonormal, so the unit axes, the vertices, the
edges and every closest point below are rational. Integer quaternions give the simplest
numbers; float quaternions work as well (their exact binary values are used).

The squared distance is the least of

* the 8 vertices of A against solid B and the 8 vertices of B against solid A (the vertex's
  coordinates in the box's orthonormal frame, clamped to the half extents), and
* all 12 × 12 edge–edge segment distances: the crossing of the two lines when it lies on both
  segments, else the best of the 4 end points against the other segment,

with no pruning by support sets (the kernel's shortcut is what this is meant to check). That
this least value is the distance rests on the vertex / edge–edge argument of
collision_node/pipeline/distance.py, so the answer is also certified on its own: with
n = q − p, A must lie in the half space n·x ≤ n·p and B in n·x ≥ n·q (checked exactly through
the support functions); then no pair of points is closer than |n|, whatever the argument.

Overlap is told by exact_sat.py; touching counts as colliding there, with distance 0.
"""
from decimal import Decimal, localcontext
from fractions import Fraction
from typing import NamedTuple

from exact_sat import exact_box, exact_sat

DIGITS = 60  # significant digits of the Decimal distance


class ExactDistance(NamedTuple):
    """The exact answer for one pair (points None when the boxes overlap or touch)."""

    colliding: bool        # exact SAT: the boxes overlap or touch
    distance_sq: Fraction  # 0 when colliding
    distance: Decimal      # its square root to DIGITS digits
    point_a: tuple         # a closest point of A (Fractions, world frame)
    point_b: tuple         # a closest point of B


class UnitBox(NamedTuple):
    center: tuple
    axes: tuple            # three exact unit vectors (Fractions)
    half_extents: tuple


def unit_box(pose, half_extents):
    """Return the box of a pose ``x y z qx qy qz qw`` with its exact unit axes."""
    box = exact_box(pose, half_extents)
    axes = tuple(tuple(c / box.norm_sq for c in axis) for axis in box.axes)
    return UnitBox(box.center, axes, box.half_extents)


def _dot(u, v):
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _sub(u, v):
    return (u[0] - v[0], u[1] - v[1], u[2] - v[2])


def _add_scaled(u, s, v):
    return (u[0] + s * v[0], u[1] + s * v[1], u[2] + s * v[2])


def _clamp(x, e):
    return min(max(x, -e), e)


def _point(box, coordinates):
    """Return centre + Σ coordinates[k] · axis k."""
    p = box.center
    for x, axis in zip(coordinates, box.axes):
        p = _add_scaled(p, x, axis)
    return p


def vertices(box):
    return [_point(box, (sx * box.half_extents[0], sy * box.half_extents[1],
                         sz * box.half_extents[2]))
            for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]


def edges(box):
    """Return the 12 edges as (centre, unit direction, half length)."""
    found = []
    for i in range(3):
        others = [k for k in range(3) if k != i]
        for s1 in (-1, 1):
            for s2 in (-1, 1):
                coordinates = [0, 0, 0]
                coordinates[others[0]] = s1 * box.half_extents[others[0]]
                coordinates[others[1]] = s2 * box.half_extents[others[1]]
                found.append((_point(box, coordinates), box.axes[i], box.half_extents[i]))
    return found


def point_box(point, box):
    """Return (d², closest point of the solid box) for a point, exactly."""
    d = _sub(point, box.center)
    coordinates = [_dot(axis, d) for axis in box.axes]
    clamped = [_clamp(x, e) for x, e in zip(coordinates, box.half_extents)]
    d_sq = sum((x - c) ** 2 for x, c in zip(coordinates, clamped))  # the axes are orthonormal
    return d_sq, _point(box, clamped)


def point_segment(point, center, direction, half):
    """Return (d², closest point) of the segment center + s·direction, |s| ≤ half (unit dir)."""
    closest = _add_scaled(center, _clamp(_dot(direction, _sub(point, center)), half), direction)
    e = _sub(point, closest)
    return _dot(e, e), closest


def segment_segment(edge_a, edge_b):
    """Return (d², p, q) of two segments (centre, unit direction, half length), exactly.

    |r + s·d1 − u·d2|² is convex on the rectangle |s| ≤ h1, |u| ≤ h2: its least value is at
    the lines' crossing when that lies inside, else on a side of the rectangle, where one
    parameter is an end point and the other the clamped projection.
    """
    p0, d1, h1 = edge_a
    q0, d2, h2 = edge_b
    candidates = []
    b = _dot(d1, d2)
    denominator = 1 - b * b
    if denominator != 0:
        r = _sub(p0, q0)
        c, f = _dot(d1, r), _dot(d2, r)
        s = (b * f - c) / denominator
        u = f + s * b
        if abs(s) <= h1 and abs(u) <= h2:
            p, q = _add_scaled(p0, s, d1), _add_scaled(q0, u, d2)
            e = _sub(q, p)
            candidates.append((_dot(e, e), p, q))
    for end in (-h1, h1):
        p = _add_scaled(p0, end, d1)
        d_sq, q = point_segment(p, q0, d2, h2)
        candidates.append((d_sq, p, q))
    for end in (-h2, h2):
        q = _add_scaled(q0, end, d2)
        d_sq, p = point_segment(q, p0, d1, h1)
        candidates.append((d_sq, p, q))
    return min(candidates, key=lambda candidate: candidate[0])


def support(box, n):
    """Return max over the box of n·x, exactly."""
    return _dot(n, box.center) + sum(e * abs(_dot(n, axis))
                                     for e, axis in zip(box.half_extents, box.axes))


def certify(box_a, box_b, p, q):
    """Assert that (p, q) is a closest pair: p ∈ A, q ∈ B and the slab between them is empty."""
    for point, box in ((p, box_a), (q, box_b)):
        d = _sub(point, box.center)
        assert all(abs(_dot(axis, d)) <= e for axis, e in zip(box.axes, box.half_extents))
    n = _sub(q, p)
    assert support(box_a, n) == _dot(n, p)
    assert -support(box_b, tuple(-c for c in n)) == _dot(n, q)


def sqrt_decimal(fraction):
    with localcontext() as context:
        context.prec = DIGITS
        return (Decimal(fraction.numerator) / Decimal(fraction.denominator)).sqrt()


def exact_distance(pose_a, half_extents_a, pose_b, half_extents_b, check=True):
    """Return the :class:`ExactDistance` of boxes A and B (poses x y z qx qy qz qw).

    ``check``: certify the closest pair (module docstring); a failure raises AssertionError.
    """
    if exact_sat(pose_a, half_extents_a, pose_b, half_extents_b).colliding:
        return ExactDistance(True, Fraction(0), Decimal(0), None, None)
    box_a = unit_box(pose_a, half_extents_a)
    box_b = unit_box(pose_b, half_extents_b)
    candidates = []
    for v in vertices(box_a):
        d_sq, q = point_box(v, box_b)
        candidates.append((d_sq, v, q))
    for v in vertices(box_b):
        d_sq, p = point_box(v, box_a)
        candidates.append((d_sq, p, v))
    for edge_a in edges(box_a):
        for edge_b in edges(box_b):
            candidates.append(segment_segment(edge_a, edge_b))
    d_sq, p, q = min(candidates, key=lambda candidate: candidate[0])
    if check:
        certify(box_a, box_b, p, q)
    return ExactDistance(False, d_sq, sqrt_decimal(d_sq), p, q)
