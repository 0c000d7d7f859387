"""Continuous checking: which pairs come within their margin at any time between two inputs.

Motion. Over a tick's interval t ∈ [0, 1] each dynamic body moves from its pose in the previous
accepted input (t = 0) to its pose in this one (t = 1): its centre linearly,
c(t) = c0 + t·Δc, and its orientation at constant angular velocity along the shortest arc
(slerp), R(t) = Rot(u, θt)·R0 with Δq = q1·q0⁻¹ = (sin θ/2 · u, cos θ/2), θ ∈ [0, π]. Static
boxes stay where they are. A pair is reported when the distance of its boxes comes within the
pair's margin at some t; its ``toi`` is the first such t.

Motion bound. A point of a box at radius ρ ≤ r from its centre (r = |half extents|, the
circumradius) moves at most |Δc| + θ·ρ per unit of t (the rotation's chord is never longer
than its arc), so the distance of two boxes, a minimum of point–point distances, changes at
most at the rate L = |Δc_a − Δc_b| + θ_a r_a + θ_b r_b. Along a fixed unit direction n the
support of A grows at most at n·Δc_a + θ_a r_a and that of B shrinks at most at
−n·Δc_b + θ_b r_b: two boxes d apart along their closest direction n (a separating slab d
wide) stay more than the margin m apart until at least (d − m) / (n·(Δc_a − Δc_b) + θ_a r_a
+ θ_b r_b) later, whatever they do in between. Nothing here assumes small steps: it holds for
pure rotation (Δc = 0) and for any speed.

Conservative advancement (Mirtich 1996; FCL's CCDC_CONSERVATIVE_ADVANCEMENT with the exact
distance instead of GJK), per candidate pair, from t = 0:

1. the boxes at t; the SAT with the margin m + L·(1 − t) (sat.separating_axis_test): an axis
   that separates them by more than that proves them apart for the rest of the interval (the
   SAT's gap is a lower bound of the distance): no contact. No axis separates: touching or
   overlapping at t: ``toi`` = t;
2. else their exact distance d (distance.box_distance) and closest direction n. d ≤ m: ``toi`` =
   t. The slab cannot close before t = 1 (n·(Δc_a − Δc_b) + θ_a r_a + θ_b r_b)·(1 − t) < d − m:
   no contact. d − m ≤ the tolerance: ``toi`` = t (within the tolerance of the margin, and it
   may still come closer: reported, conservatively);
3. else t advances by (d − m) / that rate, to at most 1, where the boxes are those of this
   input exactly (not the interpolation), so a pair touching at t = 1 is never lost to
   rounding.

Every advance stays short of the next contact, so no contact is ever skipped and ``toi`` is
never later than the first contact; at ``toi`` the boxes are within the margin plus the
tolerance (CONTINUOUS_TOLERANCE, metres). Comparisons leave the SAT's touching tolerance as
slack, so rounding can only make the search stop earlier. A pair still undecided after
MAX_ADVANCE_STEPS steps (only grazing pairs whose distance hovers just above margin +
tolerance come near it) is reported at the t reached, never dropped, and counted in the
stats (``unresolved_pairs``).

Swept bounds. The broad phases see each dynamic box's swept AABB: the hull of its AABBs at
t = 0 and t = 1, padded by r·θ²/8. Why that is enough: a point x(t) = c(t) + Rot(u, θt)w of the
box (|w| ≤ r) differs from the chord y(t) = (1 − t)·x(0) + t·x(1), which lies in the hull (both
end points do, and the hull is convex), by the error of linear interpolation of a smooth curve,
|x(t) − y(t)| ≤ t(1 − t)/2 · max|x''| ≤ 1/8 · θ²·r (the translation is linear and adds no
error; |x''| = θ²·|w⊥| ≤ θ²r; the bound holds for vector-valued curves through the integral
form of the interpolation error, whose kernel is ≥ 0). Bounding spheres grow by |Δc| (a ball
of radius r + |Δc| around c1 holds every position of the box). Both are widened further like
obb.py's AABBs for rounding, then by the margins as in the discrete check.
"""
import math

import numpy as np

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.distance import box_distance
from collision_node.pipeline.frames import (dot, matrix, projection_gap, relative_pose, rotate,
                                            turned)
from collision_node.pipeline.obb import AABB_RELATIVE_MARGIN, EPS, TIE_ULPS
from collision_node.pipeline.sat import COLLIDING, SEPARATED, separating_axis_test

# Default of ``continuous_tolerance``: reported ``toi`` put the boxes within margin + this
# many metres (0.1 mm); smaller values cost more advancement steps on grazing pairs only.
CONTINUOUS_TOLERANCE = 1e-4
# Steps of conservative advancement per pair before it is reported undecided (conservatively).
# Each step advances by at least tolerance / L: only a pair whose distance hovers just above
# margin + tolerance over a long stretch of its motion needs many.
MAX_ADVANCE_STEPS = 256
# The tolerance is at least this fraction of the pair's scale (half extents + centre
# distance): closer to contact than ~sqrt(eps) of the scale, float64 closest points no longer
# define the closest direction well (an error of eps·scale in points a d apart turns it by
# eps·scale / d).
TOLERANCE_FLOOR = 1e-7
NO_CONTACT = np.inf  # the toi of a pair that never comes within its margin


@kernel
def motion(previous_poses, poses, rows, velocity, spin):
    """Fill the motion of each dynamic row from the previous and this input's poses (D, 7).

    ``rows`` maps body i to its dynamic row; ``velocity`` (D, 3) gets Δc, ``spin`` (D, 4)
    the unit axis u (world frame) and the angle θ ∈ [0, π] of the shortest rotation from the
    previous orientation to this one.
    """
    for i in range(poses.shape[0]):
        row = rows[i]
        for k in range(3):
            velocity[row, k] = poses[i, k] - previous_poses[i, k]
        x0, y0, z0, w0 = _unit_quaternion(previous_poses, i)
        x1, y1, z1, w1 = _unit_quaternion(poses, i)
        # Δq = q1 ⊗ conj(q0), Hamilton product in (x, y, z, w) order.
        dx = w0 * x1 - w1 * x0 - (y1 * z0 - z1 * y0)
        dy = w0 * y1 - w1 * y0 - (z1 * x0 - x1 * z0)
        dz = w0 * z1 - w1 * z0 - (x1 * y0 - y1 * x0)
        dw = w1 * w0 + x1 * x0 + y1 * y0 + z1 * z0
        if dw < 0.0:  # q and -q are one rotation: take the shorter way
            dx, dy, dz, dw = -dx, -dy, -dz, -dw
        sine = math.sqrt(dx * dx + dy * dy + dz * dz)
        if sine > 0.0:
            spin[row, 0] = dx / sine
            spin[row, 1] = dy / sine
            spin[row, 2] = dz / sine
            spin[row, 3] = 2.0 * math.atan2(sine, dw)
        else:
            spin[row, 0] = spin[row, 1] = spin[row, 2] = spin[row, 3] = 0.0


@kernel
def _unit_quaternion(poses, i):
    """Return pose i's quaternion normalised as obb.set_boxes normalises it."""
    x, y, z, w = poses[i, 3], poses[i, 4], poses[i, 5], poses[i, 6]
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    return x / norm, y / norm, z / norm, w / norm


@kernel
def sweep_bounds(aabbs, radii, extents, start_aabbs, velocity, spin, start, stop):
    """Grow the AABBs and radii of rows [start, stop) to hold the boxes' whole motion.

    The AABB (this input's) becomes the hull of itself and ``start_aabbs[row - start]`` (the
    previous input's), padded by r·θ²/8 for the rotation; the radius grows by |Δc|. Module
    docstring for why that holds every pose in between.
    """
    for row in range(start, stop):
        motion_row = row - start
        r = math.sqrt(extents[row, 0] ** 2 + extents[row, 1] ** 2 + extents[row, 2] ** 2)
        theta = spin[motion_row, 3]
        travel = math.sqrt(velocity[motion_row, 0] ** 2 + velocity[motion_row, 1] ** 2
                           + velocity[motion_row, 2] ** 2)
        for k in range(3):
            low = min(aabbs[row, 0, k], start_aabbs[motion_row, 0, k])
            high = max(aabbs[row, 1, k], start_aabbs[motion_row, 1, k])
            # Rounding of the interpolated poses, as obb.py grows every AABB for its own.
            pad = r * theta * theta / 8.0 + AABB_RELATIVE_MARGIN * (
                r + travel + abs(low) + abs(high))
            aabbs[row, 0, k] = low - pad
            aabbs[row, 1, k] = high + pad
        radii[row] += travel * (1.0 + AABB_RELATIVE_MARGIN)


@kernel
def _rodrigues(axis, angle):
    """Rotation by ``angle`` about the unit ``axis``, a row-major 9-tuple."""
    x, y, z = axis
    s = math.sin(angle)
    c = 1.0 - math.cos(angle)
    return (1.0 - c * (y * y + z * z), c * x * y - s * z, c * x * z + s * y,
            c * x * y + s * z, 1.0 - c * (x * x + z * z), c * y * z - s * x,
            c * x * z - s * y, c * y * z + s * x, 1.0 - c * (x * x + y * y))


# Speed notes: as in sat.py, the per-pair helpers take tuples, never arrays (numba counts the
# references of every array handed to a call it does not inline: measured 2x slower). A box's
# motion is read from the arrays once per pair, by :func:`_motion_of`, as
# (centre, rotation) at t = 1, (centre, rotation) at t = 0, velocity, (axis, angle).

@kernel
def _motion_of(box, n_static, centers, rotations, start_centers, start_rotations, velocity,
               spin):
    """Return box row ``box``'s motion as tuples; a static box's is none."""
    center = (centers[box, 0], centers[box, 1], centers[box, 2])
    rotation = matrix(rotations, box)
    if box < n_static:
        return (center, rotation, center, rotation, (0.0, 0.0, 0.0),
                ((0.0, 0.0, 0.0), 0.0))
    m = box - n_static
    return (center, rotation, (start_centers[m, 0], start_centers[m, 1], start_centers[m, 2]),
            matrix(start_rotations, m), (velocity[m, 0], velocity[m, 1], velocity[m, 2]),
            ((spin[m, 0], spin[m, 1], spin[m, 2]), spin[m, 3]))


@kernel
def _pose_at(motion, t):
    """Return (centre, rotation as a row-major 9-tuple) of a box (its motion) at time t.

    At t = 1 the box is where this input has it, bit for bit; at t = 0 where the previous one
    had it.
    """
    center1, rotation1, center0, rotation0, velocity, spin = motion
    if t == 1.0:
        return center1, rotation1
    center = (center0[0] + t * velocity[0], center0[1] + t * velocity[1],
              center0[2] + t * velocity[2])
    if spin[1] == 0.0 or t == 0.0:
        return center, rotation0
    return center, turned(_rodrigues(spin[0], t * spin[1]), rotation0)


def boxes_at(pairs, toi, n_static, boxes, start_centers, start_rotations, velocity, spin):
    """Return centres (2P, 3), rotations (2P, 3, 3), half extents (2P, 3) of pairs at ``toi``.

    Rows 2k and 2k + 1 hold the two boxes of pair k at time ``toi[k]``, for sat.collide_pairs.
    """
    count = len(pairs)
    centers = np.empty((2 * count, 3))
    rotations = np.empty((2 * count, 3, 3))
    extents = np.empty((2 * count, 3))
    _boxes_at(pairs, toi, n_static, boxes.centers, boxes.rotations, boxes.half_extents,
              start_centers, start_rotations, velocity, spin, centers, rotations, extents)
    return centers, rotations, extents


@kernel
def _boxes_at(pairs, toi, n_static, centers, rotations, extents, start_centers,
              start_rotations, velocity, spin, out_centers, out_rotations, out_extents):
    for k in range(pairs.shape[0]):
        for side in range(2):
            box = pairs[k, side]
            center, rotation = _pose_at(_motion_of(box, n_static, centers, rotations,
                                                   start_centers, start_rotations, velocity,
                                                   spin), toi[k])
            row = 2 * k + side
            for i in range(3):
                out_centers[row, i] = center[i]
                out_extents[row, i] = extents[box, i]
                for j in range(3):
                    out_rotations[row, i, j] = rotation[3 * i + j]


@kernel
def advance_pairs(pairs, n_static, centers, rotations, extents, start_centers, start_rotations,
                  velocity, spin, margin, box_margins, tolerance, toi):
    """Write each pair's first contact time to ``toi`` (NO_CONTACT when none); module docstring.

    ``pairs`` are box rows (static rows first); the motion arrays (``start_*``, ``velocity``,
    ``spin``) are by dynamic row; ``box_margins`` None or one per box. Returns (advancement
    steps taken, pairs left undecided).
    """
    steps = 0
    unresolved = 0
    for k in range(pairs.shape[0]):
        a = pairs[k, 0]
        b = pairs[k, 1]
        ea = (extents[a, 0], extents[a, 1], extents[a, 2])
        eb = (extents[b, 0], extents[b, 1], extents[b, 2])
        pair_margin = margin if box_margins is None else \
            margin + box_margins[a] + box_margins[b]
        motion_a = _motion_of(a, n_static, centers, rotations, start_centers, start_rotations,
                              velocity, spin)
        motion_b = _motion_of(b, n_static, centers, rotations, start_centers, start_rotations,
                              velocity, spin)
        toi[k], taken = _first_contact(motion_a, motion_b, ea, eb, pair_margin, tolerance)
        steps += taken
        unresolved += taken > MAX_ADVANCE_STEPS
    return steps, unresolved


@kernel
def _first_contact(motion_a, motion_b, ea, eb, margin, tolerance):
    """Return (toi or NO_CONTACT, steps) of one pair; steps > MAX_ADVANCE_STEPS: undecided."""
    # Δc of A relative to B, and the rotations' share of the closing speed.
    va = motion_a[4]
    vb = motion_b[4]
    closing = (va[0] - vb[0], va[1] - vb[1], va[2] - vb[2])
    turning = motion_a[5][1] * math.sqrt(dot(ea, ea)) + motion_b[5][1] * math.sqrt(dot(eb, eb))
    bound = math.sqrt(dot(closing, closing)) + turning
    if _spheres_apart(motion_a[2], motion_b[2], ea, eb, margin + bound):
        return NO_CONTACT, 0
    t = 0.0
    for step in range(MAX_ADVANCE_STEPS):
        ca, ra = _pose_at(motion_a, t)
        cb, rb = _pose_at(motion_b, t)
        d = (cb[0] - ca[0], cb[1] - ca[1], cb[2] - ca[2])
        rel, offset = relative_pose(ra, rb, d)
        scale = ea[0] + ea[1] + ea[2] + eb[0] + eb[1] + eb[2] + abs(d[0]) + abs(d[1]) \
            + abs(d[2])
        tie = TIE_ULPS * EPS * scale
        status = separating_axis_test(rel, offset, ea, eb, tie,
                                      margin + bound * (1.0 - t) + tie)[0]
        if status == SEPARATED:
            return NO_CONTACT, step + 1
        if status == COLLIDING:
            return t, step + 1
        distance, _, _, n = box_distance(rel, offset, ea, eb)
        excess = distance - margin
        if excess <= tie:
            return t, step + 1
        # The slab between the boxes across their closest direction n (A's frame), measured
        # from the boxes' projections on n: a lower bound of the distance however well
        # rounding let the closest features define n.
        slab = projection_gap(rel, offset, ea, eb, n) - margin
        rate = dot(rotate(ra, n), closing) + turning
        if bound * (1.0 - t) < excess - tie or rate * (1.0 - t) < slab - tie:
            return NO_CONTACT, step + 1  # neither bound lets it close the gap before t = 1
        reach = max(tolerance, TOLERANCE_FLOOR * scale)
        if excess <= reach:
            return t, step + 1
        # Aim at margin + reach / 2, not at the margin: a contact found there has a closest
        # direction float64 defines well (its normal), and it is still within the tolerance.
        aim = 0.5 * reach
        advance = (excess - aim) / bound
        if rate > 0.0:
            advance = max(advance, (slab - aim) / rate)
        t = min(t + advance, 1.0)
    return t, MAX_ADVANCE_STEPS + 1  # undecided: reported where it got to


@kernel
def _spheres_apart(ca, cb, ea, eb, reach):
    """Whether the boxes' bounding spheres (centres ``ca``, ``cb``) are more than ``reach`` apart.

    The boxes' distance is at least that of the spheres, so with ``reach`` = margin + L at
    t = 0 they stay apart over the whole interval. Compared squared, with a relative allowance
    for rounding (obb.spheres_apart's).
    """
    d = (cb[0] - ca[0], cb[1] - ca[1], cb[2] - ca[2])
    scale = math.sqrt(dot(ea, ea)) + math.sqrt(dot(eb, eb)) + reach
    slack = TIE_ULPS * EPS * (scale + abs(ca[0]) + abs(ca[1]) + abs(ca[2]) + abs(cb[0])
                              + abs(cb[1]) + abs(cb[2]))
    return dot(d, d) > (scale + slack) * (scale + slack)
