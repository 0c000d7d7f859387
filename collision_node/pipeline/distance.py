"""Exact Euclidean distance between two solid oriented boxes, and its closest points.

:func:`box_distance` is a per-pair kernel in sat.py's notation (everything in box A's frame:
``rel`` = AᵀB row-major with rel[3i + j] = a_i·b_j, ``t`` = Aᵀ(c_B − c_A), half extents
``ea``, ``eb``). sat.py calls it for pairs within their margin; ``sat.signed_distance``
is the validating one-pair query in world coordinates, on the same path.

Why it is exact (a finite candidate list that always holds a closest pair):

* Let p ∈ A, q ∈ B be closest and n = q − p ≠ 0. Every closest pair has the same n (the
  midpoint of two closest pairs with different n would be closer), so the closest points of A
  form P = A ∩ (B − n). Each of them maximises n·x over A and minimises n·x over B when moved
  by n, so P = F_A ∩ (F_B − n), F_A the support set (vertex, edge or face) of A along n and
  F_B that of B along −n: a non-empty convex polygon, segment or point in a plane ⊥ n.
* P has an extreme point v. Let G_A, G_B be the faces of F_A and F_B − n that hold v in their
  relative interior. If either is a vertex, v is a vertex of A (or v + n of B), and the
  distance is a vertex–box distance: the least of the 8 vertices of A against solid B and the
  8 vertices of B against solid A (clamp in the box's own frame). Otherwise both have
  dimension ≥ 1 and lie in the plane ⊥ n; if their affine hulls shared a line through v, v
  would be inside a segment of P, not extreme. So G_A is an edge of A along some a_i, G_B an
  edge of B along some b_j, not parallel, both ⊥ n: n ∥ c = a_i × b_j, and the two segments'
  distance is |n|.
* Which edges: c_A ∈ A and c_B ∈ B give n·(c_B − c_A) ≥ n·(q − p) = |n|² > 0, so n = λc
  with sign(λ) = sign(c·t). G_A ⊂ F_A fixes A's coordinates k ≠ i to sign(n_k)·ea_k, free
  where n_k = 0; G_B ⊂ F_B fixes B's coordinates m ≠ j to −sign(n·b_m)·eb_m, free where
  n·b_m = 0. A sign is tried both ways when its value is 0 (c's components are entries of
  ``rel``, exact) or, for the computed c·t and c·b_m, within rounding of 0 (a face parallel
  to n has two support edges; at touching, c·t itself may round either way): normally one
  edge pair per axis, at most 2 · 2 · 2 in degenerate configurations.
* Which axes: the gap between the boxes' projections on any axis (the SAT separation) is a
  lower bound of the distance, and on the crossing's axis c it is the distance (the support
  edges lie in the two support planes ⊥ c, and cross). So c has the largest separation of
  all 15 axes, and only edge axes within rounding of the largest are tried (normally none or
  one; several on parallel faces). Edges whose cross product is shorter than
  sat.MIN_EDGE_AXIS_LENGTH (1e-150) are skipped: near-parallel segments at an angle θ that
  cross have an end point within 2 · length · sin θ of the crossing's distance.
* Every candidate is a true pair of points of the two boxes, so extra candidates cannot
  make the answer smaller than the distance; the argument above shows that the list holds a
  closest pair. test/exact_distance.py checks every vertex–box and all 144 edge–edge pairs in
  rational arithmetic, with no support-set pruning, and certifies its own answer.

Segment–segment closest points (one edge pair): Ericson's clamped scheme (Real-Time Collision
Detection, 5.1.9), except that the parameter on A's edge comes from s = r·(b_j × c) / |c|²,
r = (B's edge centre) − (A's edge centre): the textbook (b·f − c·e) / (1 − b²) loses
eps·|r| / sin²θ to cancellation for edges at an angle θ, this form eps·|r| / sin θ, and an
error Δs in s moves the pair's distance by only sin θ · Δs, i.e. eps·|r| (the tests see the
difference: 1e-10 of the size against 1e-15 on near-parallel edges). The point on B's edge is
the projection of A's (clamped), and when it is clamped A's is projected again, so rounding
near the segments' ends costs no more. The distance of the two lines, (r·c)² / |c|², is a
lower bound that skips the pair when it is no closer than the best so far (plus the
tie of "Normal" below: equally close features are compared by their direction).

Precision. The kernel's result is the exact distance of the boxes that ``rel`` and ``t``
describe (B's axes orthonormal only to rounding; the vertex tests take Bᵀ for B⁻¹) up to a
few eps × (Σ half extents + |t|); that input is itself within a few eps of the exact boxes,
and the distance moves no more than the boxes do. Checked against the exact referee on the
hard classes of test/test_distance.py (parallel, turned and tilted faces, crossed, skew and
near-parallel edges, vertex cases, 1e-6-thin plates and needles; sizes 1e-3 to 1e3 m, offsets
up to 1e6 m, gaps 1e-12 to 10 × the size): within 4 eps × (Σ half extents + distance), far
inside the 1e-9 × Σ half extents that the tests require.

Normal. The kernel also returns n, the unit direction from A's closest feature to B's, taken
from the features themselves, not from the difference of two rounded points (which at a gap
d carries their rounding δ ≈ eps × scale over d: a noisy direction at tiny gaps):

* a vertex against a face: the face's unit axis itself (e_i or a column of R), exact;
* a vertex against an edge or a vertex: the vertex's excess over the other box's slabs, in
  that box's frame: exactly 0 along the edge, so n lies exactly in the other box's normal
  cone there; its direction is good to δ / d;
* two edges crossing between their ends: ±c = a_i × b_j, which float64 rotations define to
  ~eps / |c| (|c| the sine of the edges' angle), unless the points' offset defines it better
  (d > |c| × scale: long gaps between nearly parallel edges).

So the points and n agree: q − p = n · d to the points' rounding, at every gap, and the
boxes' projections on n are apart by the distance whenever rounding leaves n inside the
features' normal cones. Two candidates can be equally close to rounding (within the touching
tolerance ``tie``) and still hold different features: the vertex at the end of an edge lying
flat across the gap is as close as the edge's nearest point, yet its direction is off by up
to √(2 · tie / d), enough to tilt n out of the edge's cone and cost the edge's length × that
tilt of the gap along n. Of such tied candidates the kernel reports the one along whose
direction the boxes' projections are farthest apart (at most the distance: the closest
direction is the one direction that reaches it). Should rounding still leave n out of the
cones, sat.py takes the SAT's widest axis instead (sat._near_normal).

Cost: the 16 vertex–box tests (~20 flops each), the 15 SAT separations (as sat.py computes
them, one square root each for the 9 edge axes), then the edge pairs of the axes left
(~50 flops and one division each), squared distances throughout, one square root at the end.
Then one projection of the boxes on the direction found (~25 flops) confirms it; only when it
falls short (equally close candidates: never on random pairs) are the candidates compared
again by direction. test/distance_bench.py times it per pair, beside the SAT, which stops at
the first separating axis (doc/benchmarks.md).

Why not GJK/EPA: they iterate to a tolerance, and face-parallel contacts are their worst case
(the support mapping jumps between vertices). Measured in test/test_distance.py: FCL's GJK
distance is off by 15 % of the size on parallel faces, and answers "colliding" (-1) for
separated pairs that its own fcl.collide calls separated; coal with its default tolerance
answers 0, a negative depth or -DBL_MAX for pairs up to 1e-6 m apart. Boxes have few enough
features for an exhaustive, pruned candidate list to be exact at about 100 ns a pair.

Overlapping boxes: the kernel's value is the distance of some pair of points of the two boxes:
0 when a vertex of one lies in the other or two edges cross, but it can be > 0 (two needles
crossing like a plus sign). The SAT tells overlap and runs this only for separated pairs.
"""
import math

import numpy as np

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.frames import (column, cross, dot, edge_overlap, face_a_overlap,
                                            face_b_overlap, MIN_EDGE_AXIS_LENGTH,
                                            projection_gap)
from collision_node.pipeline.obb import EPS, TIE_ULPS

# A sign computed as x + y (two rounded products) is trusted when |x + y| exceeds this many
# ulps of |x| + |y|; closer to 0 both signs are tried. The sum's rounding error is below
# 2 ulps of |x| + |y|; extra candidates only cost time. (The tests pass without it too: when
# a face is parallel to n within rounding, the closest set has other extreme points that the
# other axes find. The proof needs it.)
SIGN_ULPS = 16.0


# Speed notes: as in sat.py, tuples of floats, never arrays, and the helpers that index a
# tuple are called with constant indices so that the indexing resolves at compile time.

@kernel
def box_distance(rel, t, ea, eb):
    """Return ``(distance, p, q, n)``: the distance, closest points p ∈ A, q ∈ B, unit normal.

    All in A's frame (3-tuples), sat.py's notation: ``rel`` = AᵀB row-major (9-tuple),
    ``t`` = Aᵀ(c_B − c_A), ``ea``, ``eb`` the half extents. n points from p to q, taken from
    the closest features (module docstring, "Normal"); (0, 0, 0) when the distance is 0.
    Exact up to float64 rounding for separated or touching boxes (module docstring); for
    overlapping ones see there.
    """
    tie = TIE_ULPS * EPS * (ea[0] + ea[1] + ea[2] + eb[0] + eb[1] + eb[2]
                            + abs(t[0]) + abs(t[1]) + abs(t[2]))
    least, p, q, v = _closest_features(rel, t, ea, eb, tie, None)
    distance = math.sqrt(least)
    n = _unit_or_zero(v)
    # The boxes' projections on the closest direction are apart by the distance, on any other
    # by less. Short of it by more than rounding: equally close candidates held other features
    # (module docstring, "Normal"); their directions decide.
    if projection_gap(rel, t, ea, eb, n) < distance - tie:
        _, p, q, v = _closest_features(rel, t, ea, eb, tie, True)
        n = _unit_or_zero(v)
    return distance, p, q, n


@kernel
def _closest_features(rel, t, ea, eb, tie, by_direction):
    """Return (least d², p, q, v) over the candidate features (module docstring).

    v is the direction from p to q, of any length. ``by_direction`` True: of candidates
    within ``tie`` of each other, the one that best separates the boxes gives p, q and v;
    None: the least (a None type compiles the comparison of directions out).
    """
    b_0, b_1, b_2 = column(rel, 0), column(rel, 1), column(rel, 2)
    first = _vertices_of_a(t, ea, eb, b_0, b_1, b_2)
    second = _vertices_of_b(t, ea, eb, b_0, b_1, b_2)
    # Candidates are compared by d², tied within ``tie`` of distance: (d + tie)² − d² for d
    # up to the nearer vertex's (an upper bound of the distance).
    tie_sq = 0.0 if by_direction is None else \
        tie * (2.0 * math.sqrt(min(first[0], second[0])) + tie)
    least = first[0]
    chosen = (first[0], first[1], first[2], first[3], np.nan)  # its gap, computed on a tie
    least, chosen = _choose(rel, t, ea, eb, by_direction, tie_sq, least, chosen, second)
    # Only an edge axis whose separation is within rounding of the largest of all 15 can
    # hold a closest pair (module docstring); separations below 0 cannot either.
    seps = (_edge_separation(rel, t, ea, eb, 0, 0), _edge_separation(rel, t, ea, eb, 0, 1),
            _edge_separation(rel, t, ea, eb, 0, 2), _edge_separation(rel, t, ea, eb, 1, 0),
            _edge_separation(rel, t, ea, eb, 1, 1), _edge_separation(rel, t, ea, eb, 1, 2),
            _edge_separation(rel, t, ea, eb, 2, 0), _edge_separation(rel, t, ea, eb, 2, 1),
            _edge_separation(rel, t, ea, eb, 2, 2))
    largest = max(-face_a_overlap(rel, t, ea, eb, 0), -face_a_overlap(rel, t, ea, eb, 1),
                  -face_a_overlap(rel, t, ea, eb, 2), -face_b_overlap(rel, t, ea, eb, 0),
                  -face_b_overlap(rel, t, ea, eb, 1), -face_b_overlap(rel, t, ea, eb, 2),
                  max(seps[0], seps[1], seps[2]), max(seps[3], seps[4], seps[5]),
                  max(seps[6], seps[7], seps[8]))
    floor = max(largest, 0.0) - tie
    # The edge pairs in a loop, (i, j) numbers at run time: numba compiles a kernel again for
    # each constant argument (nine _edge_pairs, 3 s of a first start), and few pass the floor.
    for k in range(9):
        if seps[k] >= floor:
            least, chosen = _choose(rel, t, ea, eb, by_direction, tie_sq, least, chosen,
                                    _edge_pairs(rel, t, ea, eb, k // 3, k % 3, least + tie_sq))
    return least, chosen[1], chosen[2], chosen[3]


@kernel
def _choose(rel, t, ea, eb, by_direction, tie_sq, least, chosen, candidate):
    """Return the least d² so far, and the features to report: ``chosen`` or ``candidate``.

    ``candidate`` = (d², p, q, v), v the direction from p to q (any length); ``chosen`` the
    same with the boxes' projection gap along v, or NaN until a tie needs it. Candidates
    within ``tie_sq`` of each other (``by_direction`` None: the least d² wins) are equally close
    to rounding, yet
    their directions can differ by √(2 · tie / d) (a vertex at the end of an edge lying flat
    across the gap is as close as the edge's nearest point): the one along which the boxes'
    projections are farther apart is the closest direction's better estimate (module
    docstring, "Normal").
    """
    d2 = candidate[0]
    if by_direction is None:
        if d2 < chosen[0]:
            return d2, (d2, candidate[1], candidate[2], candidate[3], np.nan)
        return least, chosen
    if not d2 < np.inf:
        return least, chosen
    if d2 < chosen[0] - tie_sq:
        return min(least, d2), (d2, candidate[1], candidate[2], candidate[3], np.nan)
    if d2 <= chosen[0] + tie_sq:
        chosen_gap = chosen[4]
        if math.isnan(chosen_gap):
            chosen_gap = projection_gap(rel, t, ea, eb, _unit_or_zero(chosen[3]))
        gap = projection_gap(rel, t, ea, eb, _unit_or_zero(candidate[3]))
        if gap > chosen_gap:
            return min(least, d2), (d2, candidate[1], candidate[2], candidate[3], gap)
        chosen = (chosen[0], chosen[1], chosen[2], chosen[3], chosen_gap)
    return min(least, d2), chosen


@kernel
def _edge_separation(rel, t, ea, eb, i, j):
    """Return the gap (< 0: overlap) of the boxes' projections on a_i × b_j, normalised.

    −inf for parallel edges (no axis).
    """
    overlap, length_sq = edge_overlap(rel, t, ea, eb, i, j)
    if length_sq < MIN_EDGE_AXIS_LENGTH * MIN_EDGE_AXIS_LENGTH:
        return -np.inf
    return -overlap / math.sqrt(length_sq)


@kernel
def _corner_sign(v, k):
    """Sign (±1.0) of coordinate k of vertex number v (bit k of v)."""
    return 1.0 if (v >> k) & 1 else -1.0


@kernel
def _clamp(x, e):
    return min(max(x, -e), e)


@kernel
def _excess_sq(x, e):
    """Squared distance of the coordinate x from the interval [−e, e]."""
    excess = max(abs(x) - e, 0.0)
    return excess * excess


@kernel
def _vertices_of_a(t, ea, eb, b_0, b_1, b_2):
    """Return (d², p, q, v) of the vertex of A closest to solid B, measured in B's frame.

    v = q − p, from the features (module docstring, "Normal").
    """
    # Vertex v = (s0 ea0, s1 ea1, s2 ea2) has B-coordinates u_m = b_m·v − b_m·t.
    w0, w1, w2 = -dot(b_0, t), -dot(b_1, t), -dot(b_2, t)
    h00, h10, h20 = b_0[0] * ea[0], b_0[1] * ea[1], b_0[2] * ea[2]
    h01, h11, h21 = b_1[0] * ea[0], b_1[1] * ea[1], b_1[2] * ea[2]
    h02, h12, h22 = b_2[0] * ea[0], b_2[1] * ea[1], b_2[2] * ea[2]
    best = np.inf
    best_v = 0
    for v in range(8):
        s0, s1, s2 = _corner_sign(v, 0), _corner_sign(v, 1), _corner_sign(v, 2)
        d2 = (_excess_sq(w0 + s0 * h00 + s1 * h10 + s2 * h20, eb[0])
              + _excess_sq(w1 + s0 * h01 + s1 * h11 + s2 * h21, eb[1])
              + _excess_sq(w2 + s0 * h02 + s1 * h12 + s2 * h22, eb[2]))
        if d2 < best:
            best, best_v = d2, v
    s0, s1, s2 = _corner_sign(best_v, 0), _corner_sign(best_v, 1), _corner_sign(best_v, 2)
    x0 = w0 + s0 * h00 + s1 * h10 + s2 * h20
    x1 = w1 + s0 * h01 + s1 * h11 + s2 * h21
    x2 = w2 + s0 * h02 + s1 * h12 + s2 * h22
    u0, u1, u2 = _clamp(x0, eb[0]), _clamp(x1, eb[1]), _clamp(x2, eb[2])
    p = (s0 * ea[0], s1 * ea[1], s2 * ea[2])
    q = (t[0] + u0 * b_0[0] + u1 * b_1[0] + u2 * b_2[0],
         t[1] + u0 * b_0[1] + u1 * b_1[1] + u2 * b_2[1],
         t[2] + u0 * b_0[2] + u1 * b_1[2] + u2 * b_2[2])
    # n from B's feature: the vertex's excess over B's slabs (B's frame), exactly 0 across a
    # face or an edge of B; turned into A's frame it is B's face axis itself, or lies in the
    # plane across B's edge (module docstring, "Normal").
    e0, e1, e2 = u0 - x0, u1 - x1, u2 - x2
    return best, p, q, (e0 * b_0[0] + e1 * b_1[0] + e2 * b_2[0],
                        e0 * b_0[1] + e1 * b_1[1] + e2 * b_2[1],
                        e0 * b_0[2] + e1 * b_1[2] + e2 * b_2[2])


@kernel
def _vertices_of_b(t, ea, eb, b_0, b_1, b_2):
    """Return (d², p, q, v) of the vertex of B closest to solid A, measured in A's frame."""
    g0 = (eb[0] * b_0[0], eb[0] * b_0[1], eb[0] * b_0[2])
    g1 = (eb[1] * b_1[0], eb[1] * b_1[1], eb[1] * b_1[2])
    g2 = (eb[2] * b_2[0], eb[2] * b_2[1], eb[2] * b_2[2])
    best = np.inf
    best_v = 0
    for v in range(8):
        s0, s1, s2 = _corner_sign(v, 0), _corner_sign(v, 1), _corner_sign(v, 2)
        d2 = (_excess_sq(t[0] + s0 * g0[0] + s1 * g1[0] + s2 * g2[0], ea[0])
              + _excess_sq(t[1] + s0 * g0[1] + s1 * g1[1] + s2 * g2[1], ea[1])
              + _excess_sq(t[2] + s0 * g0[2] + s1 * g1[2] + s2 * g2[2], ea[2]))
        if d2 < best:
            best, best_v = d2, v
    s0, s1, s2 = _corner_sign(best_v, 0), _corner_sign(best_v, 1), _corner_sign(best_v, 2)
    q = (t[0] + s0 * g0[0] + s1 * g1[0] + s2 * g2[0],
         t[1] + s0 * g0[1] + s1 * g1[1] + s2 * g2[1],
         t[2] + s0 * g0[2] + s1 * g1[2] + s2 * g2[2])
    p = (_clamp(q[0], ea[0]), _clamp(q[1], ea[1]), _clamp(q[2], ea[2]))
    # n from A's feature: the vertex's excess over A's slabs, exactly 0 across A's face or edge.
    return best, p, q, (q[0] - p[0], q[1] - p[1], q[2] - p[2])


@kernel
def _unit_or_zero(v):
    """Return ``v`` / |v|, or (0, 0, 0) when v is 0."""
    length_sq = dot(v, v)
    if not length_sq > 0.0:
        return 0.0, 0.0, 0.0
    length = math.sqrt(length_sq)
    return v[0] / length, v[1] / length, v[2] / length


@kernel
def _sign_and_doubt(x, y):
    """Return (sign of x + y as ±1.0, whether rounding may have flipped it)."""
    total = x + y
    doubt = abs(total) <= SIGN_ULPS * EPS * (abs(x) + abs(y))
    return (1.0 if total >= 0.0 else -1.0), doubt


@kernel
def _in_order(i, along, first, second):
    """Return the 3-tuple whose coordinate i is ``along``, i + 1 ``first``, i + 2 ``second``."""
    if i == 0:
        return along, first, second
    if i == 1:
        return second, along, first
    return first, second, along


@kernel
def _cyclic(v, i):
    """Return (v_i, v_i+1, v_i+2): coordinates turned so that axis i comes first."""
    return v[i], v[(i + 1) % 3], v[(i + 2) % 3]


@kernel
def _edge_pairs(rel, t, ea, eb, i, j, limit):
    """Return (d², p, q, v) of the support edges of A along a_i and B along b_j below ``limit``.

    (inf, ...) when their lines are no closer than ``limit`` (a d²). It only picks the
    numbers, in coordinates turned so that a_i is the first axis (a rotation: distances stay
    the same), for :func:`_turned_edge_pairs`.
    """
    d2, p, q, n = _turned_edge_pairs(
        _cyclic(column(rel, j), i), _cyclic(column(rel, (j + 1) % 3), i),
        _cyclic(column(rel, (j + 2) % 3), i), _cyclic(t, i), _cyclic(ea, i), eb[j],
        eb[(j + 1) % 3], eb[(j + 2) % 3], limit)
    return (d2, _in_order(i, p[0], p[1], p[2]), _in_order(i, q[0], q[1], q[2]),
            _in_order(i, n[0], n[1], n[2]))


@kernel
def _turned_edge_pairs(b_j, b_j1, b_j2, t, ea, eb_j, eb_j1, eb_j2, limit):
    """Edge pairs of A along (1, 0, 0) and B along b_j, with B's other axes b_j1, b_j2.

    Return the least (d², p, q, v) found below ``limit``, or (inf, ...) when none is.
    """
    # c = (1, 0, 0) × b_j = (0, −b_j[2], b_j[1]): exact.
    c1 = -b_j[2]
    c2 = b_j[1]
    c_sq = c1 * c1 + c2 * c2
    zero = (0.0, 0.0, 0.0)
    found = (np.inf, zero, zero, zero)
    if c_sq < MIN_EDGE_AXIS_LENGTH * MIN_EDGE_AXIS_LENGTH:
        return found
    inverse = 1.0 / c_sq
    sign_t, doubt_t = _sign_and_doubt(c1 * t[1], c2 * t[2])
    sign_b1, doubt_b1 = _sign_and_doubt(c1 * b_j1[1], c2 * b_j1[2])
    sign_b2, doubt_b2 = _sign_and_doubt(c1 * b_j2[1], c2 * b_j2[2])
    # c's own components are exact: only an exact 0 leaves A's edge undecided (with c ≠ 0,
    # at most one of them is 0).
    sign_a1 = 1.0 if c1 > 0.0 else -1.0
    sign_a2 = 1.0 if c2 > 0.0 else -1.0
    if not (doubt_t or doubt_b1 or doubt_b2 or c1 == 0.0 or c2 == 0.0):
        # The usual case: one edge pair.
        return _edge_pair(b_j, b_j1, b_j2, t, ea, eb_j, c1, c2, inverse, limit, sign_t,
                          sign_t * sign_a1 * ea[1], sign_t * sign_a2 * ea[2],
                          -sign_t * sign_b1 * eb_j1, -sign_t * sign_b2 * eb_j2)
    for n_dir in range(2 if doubt_t else 1):
        direction = sign_t if n_dir == 0 else -sign_t
        for n_a1 in range(2 if c1 == 0.0 else 1):
            x1 = direction * sign_a1 * (1.0 if n_a1 == 0 else -1.0) * ea[1]
            for n_a2 in range(2 if c2 == 0.0 else 1):
                x2 = direction * sign_a2 * (1.0 if n_a2 == 0 else -1.0) * ea[2]
                for n_b1 in range(2 if doubt_b1 else 1):
                    y1 = -direction * sign_b1 * (1.0 if n_b1 == 0 else -1.0) * eb_j1
                    for n_b2 in range(2 if doubt_b2 else 1):
                        y2 = -direction * sign_b2 * (1.0 if n_b2 == 0 else -1.0) * eb_j2
                        candidate = _edge_pair(b_j, b_j1, b_j2, t, ea, eb_j, c1, c2, inverse,
                                               min(limit, found[0]), direction, x1, x2, y1, y2)
                        if candidate[0] < found[0]:
                            found = candidate
    return found


@kernel
def _edge_pair(b_j, b_j1, b_j2, t, ea, eb_j, c1, c2, inverse, limit, direction, x1, x2, y1,
               y2):
    """(d², p, q, v) of A's edge (s, x1, x2), |s| ≤ ea[0], and B's edge q0 + u·b_j, |u| ≤ eb_j.

    q0 = t + y1·b_j1 + y2·b_j2; the edges support ±c, c = (0, c1, c2), with the sign
    ``direction``. (inf, ...) when the lines are no closer than ``limit`` (a d²).
    """
    q0 = (t[0] + y1 * b_j1[0] + y2 * b_j2[0], t[1] + y1 * b_j1[1] + y2 * b_j2[1],
          t[2] + y1 * b_j1[2] + y2 * b_j2[2])
    r1 = q0[1] - x1
    r2 = q0[2] - x2
    along_c = r1 * c1 + r2 * c2
    zero = (0.0, 0.0, 0.0)
    if along_c * along_c * inverse >= limit:
        return np.inf, zero, zero, zero
    # s = r·(b_j × c) / |c|² (module docstring), with r = q0 − (0, x1, x2).
    w = cross(b_j, (0.0, c1, c2))
    s = (q0[0] * w[0] + r1 * w[1] + r2 * w[2]) * inverse
    inside = abs(s) <= ea[0]
    s = _clamp(s, ea[0])
    # The point of B's line closest to p = (s, x1, x2), clamped; then A's again if it was.
    u = (s - q0[0]) * b_j[0] - r1 * b_j[1] - r2 * b_j[2]
    if abs(u) > eb_j:
        inside = False
        u = _clamp(u, eb_j)
        s = _clamp(q0[0] + u * b_j[0], ea[0])
    q = (q0[0] + u * b_j[0], q0[1] + u * b_j[1], q0[2] + u * b_j[2])
    e = (q[0] - s, q[1] - x1, q[2] - x2)
    d2 = dot(e, e)
    # The lines' closest points are apart along c, whose direction float64 rotations define to
    # ~eps / |c| (|c| = the sine of the edges' angle); their offset e defines it to
    # ~eps · scale / |e|. The better of the two (module docstring, "Normal"); an end of an
    # edge is a vertex pair, which only e describes.
    scale = (abs(t[0]) + abs(t[1]) + abs(t[2]) + ea[0] + ea[1] + ea[2] + eb_j + abs(y1)
             + abs(y2))
    c_sq = c1 * c1 + c2 * c2
    if inside and d2 <= c_sq * scale * scale:
        return d2, (s, x1, x2), q, (0.0, direction * c1, direction * c2)
    return d2, (s, x1, x2), q, e
