"""An exact referee for the oriented-box SAT, for tests only.

The 15-axis separating axis test evaluated in exact rational arithmetic
(:class:`fractions.Fraction`) on the float64 inputs, so that a test can label every hard case
(touching, near-parallel, huge offsets) with the true answer instead of another float64 guess.

Which rotation: the referee uses the pose's quaternion **as given**, not the float64-normalised
one that ``obb.set_boxes`` stores. With the homogeneous formula R = M(q) / |q|² the rotation
of a non-unit quaternion is exactly rational and exactly orthogonal, and it is the rotation
that the input means (q and q/|q| denote the same rotation). The kernel instead normalises q
and builds R in float64: its box axes differ from the referee's by a few ulps per entry. That
difference is part of the rounding that the touching tolerance (``sat.py``) has to cover, and
the stress tests check that it does, also for quaternions off unit norm by up to 1e-3.

No square roots are taken on the exact path: a separating axis L need not be unit length,
because the sign of |t·L| − r_A(L) − r_B(L) does not depend on |L|. Separations along
different axes are compared exactly through their signed squares g²/|L|². Only the final
values (depth, separation) are turned into :class:`decimal.Decimal` with 60 significant
digits, far below any tolerance used in the tests.

Everything is computed in the world frame: exact arithmetic needs no relative frame.
"""
from decimal import Decimal, localcontext
from fractions import Fraction
from typing import NamedTuple

DIGITS = 60  # significant digits of the reported Decimal values

FACE_A = 'face_a'
FACE_B = 'face_b'
EDGE = 'edge'


class Axis(NamedTuple):
    """One of the (up to) 15 axes, with its exact separation.

    ``separation`` > 0: the boxes are apart along this axis by that distance; ≤ 0: their
    projections overlap by ``-separation``. ``normal`` is the unit axis in float64, pointing
    from A to B (any sign when B's centre projects onto A's, i.e. t·L = 0).
    """

    kind: str          # FACE_A (i = A's axis), FACE_B (j = B's axis), EDGE (A's i × B's j)
    i: int
    j: int
    separation: Decimal
    normal: tuple
    key: Fraction      # sign(g) · g² / |L|²: exactly ordered like ``separation``
    sine: float        # edge axes: sine of the angle between the two edges; faces: 1


class Verdict(NamedTuple):
    """The exact SAT answer for one pair."""

    colliding: bool     # exact: no axis separates (touching counts as colliding)
    separation: Decimal  # max over the axes of Axis.separation; the depth is its negation
    best: Axis          # an axis attaining ``separation`` (face axes before edge axes)
    axes: list          # every non-degenerate axis

    @property
    def depth(self):
        return -self.separation


def rotation(quaternion):
    """Return (M, n): M(q) (3 × 3 Fractions, rows) and n = |q|², so that R = M / n exactly.

    ``quaternion`` is (x, y, z, w), the ROS order; any non-zero q works and q, -q give the
    same M. The columns of M are the box axes scaled by n.
    """
    x, y, z, w = (Fraction(v) for v in quaternion)
    n = x * x + y * y + z * z + w * w
    if n == 0:
        raise ValueError('the zero quaternion is not a rotation')
    m = [[w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
         [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
         [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z]]
    return m, n


class ExactBox(NamedTuple):
    """A box in exact arithmetic: centre, scaled axes (columns of M), |q|², half extents."""

    center: tuple
    axes: tuple         # axes[k] = column k of M = n · (unit axis k)
    norm_sq: Fraction
    half_extents: tuple


def exact_box(pose, half_extents):
    """Build an :class:`ExactBox` from a pose ``x y z qx qy qz qw`` and 3 half extents."""
    m, n = rotation(pose[3:7])
    axes = tuple(tuple(m[r][k] for r in range(3)) for k in range(3))
    return ExactBox(tuple(Fraction(v) for v in pose[:3]), axes, n,
                    tuple(Fraction(e) for e in half_extents))


def _dot(u, v):
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _cross(u, v):
    return (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])


def _radius(box, axis):
    """Return n · (projection radius of ``box`` on ``axis``), exactly."""
    return sum(e * abs(_dot(k, axis)) for e, k in zip(box.half_extents, box.axes))


def _gap_times_norms(box_a, box_b, t, axis):
    """Return n_A · n_B · (|t·L| − r_A(L) − r_B(L)): the sign of the separation along L."""
    return (box_a.norm_sq * box_b.norm_sq * abs(_dot(t, axis))
            - box_b.norm_sq * _radius(box_a, axis) - box_a.norm_sq * _radius(box_b, axis))


def _to_decimal(fraction):
    with localcontext() as context:
        context.prec = DIGITS
        return Decimal(fraction.numerator) / Decimal(fraction.denominator)


def _signed_sqrt(key):
    with localcontext() as context:
        context.prec = DIGITS
        magnitude = _to_decimal(abs(key)).sqrt()
        return magnitude if key >= 0 else -magnitude


def _unit(axis, t):
    """Return the float64 unit vector along ``axis``, turned to point from A to B."""
    length = _signed_sqrt(_dot(axis, axis))
    sign = -1 if _dot(t, axis) < 0 else 1
    return tuple(float(sign * _to_decimal(c) / length) for c in axis)


def _axis(box_a, box_b, t, kind, i, j, direction):
    norms_sq = box_a.norm_sq ** 2 * box_b.norm_sq ** 2
    g = _gap_times_norms(box_a, box_b, t, direction)
    key = g * abs(g) / (norms_sq * _dot(direction, direction))
    sine = float(_signed_sqrt(_dot(direction, direction) / norms_sq)) if kind == EDGE else 1.0
    return Axis(kind, i, j, _signed_sqrt(key), _unit(direction, t), key, sine)


def exact_sat(pose_a, half_extents_a, pose_b, half_extents_b):
    """Return the exact :class:`Verdict` for boxes A and B (poses x y z qx qy qz qw)."""
    box_a = exact_box(pose_a, half_extents_a)
    box_b = exact_box(pose_b, half_extents_b)
    t = tuple(cb - ca for ca, cb in zip(box_a.center, box_b.center))
    axes = [_axis(box_a, box_b, t, FACE_A, i, -1, box_a.axes[i]) for i in range(3)]
    axes += [_axis(box_a, box_b, t, FACE_B, -1, j, box_b.axes[j]) for j in range(3)]
    for i in range(3):
        for j in range(3):
            direction = _cross(box_a.axes[i], box_b.axes[j])
            if any(direction):  # exactly parallel edges give no axis (faces decide)
                axes.append(_axis(box_a, box_b, t, EDGE, i, j, direction))
    best = max(axes, key=lambda axis: axis.key)  # max() keeps the first: faces win ties
    return Verdict(best.key <= 0, best.separation, best, axes)


def separation_along(pose_a, half_extents_a, pose_b, half_extents_b, direction):
    """Exact separation (Decimal) of the boxes along any non-zero float ``direction``.

    Negative: the projections overlap by that much. Used to check that a reported normal
    really is a direction along which the boxes overlap by the reported depth.
    """
    box_a = exact_box(pose_a, half_extents_a)
    box_b = exact_box(pose_b, half_extents_b)
    t = tuple(cb - ca for ca, cb in zip(box_a.center, box_b.center))
    axis = tuple(Fraction(float(c)) for c in direction)
    return _axis(box_a, box_b, t, 'direction', -1, -1, axis).separation


def signed_offset_along(pose_a, pose_b, direction):
    """Exact (c_B − c_A)·direction as a Decimal: > 0 when ``direction`` points from A to B."""
    t = [Fraction(b) - Fraction(a) for a, b in zip(pose_a[:3], pose_b[:3])]
    return _to_decimal(_dot(t, [Fraction(float(c)) for c in direction]))


def distance_outside(point, pose, half_extents):
    """How far (Decimal, ≥ 0) ``point`` lies outside the box, as max over its axes.

    0 when the point is inside or on the box; measured along the box's own axes, exactly.
    """
    box = exact_box(pose, half_extents)
    d = [Fraction(float(p)) - c for p, c in zip(point, box.center)]
    worst = Fraction(0)
    for axis, e in zip(box.axes, box.half_extents):
        worst = max(worst, abs(_dot(axis, d)) / box.norm_sq - e)
    return _to_decimal(worst)
