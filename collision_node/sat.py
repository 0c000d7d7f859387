"""Separating axis test (SAT) between oriented boxes, over an array of candidate pairs.

Everything is computed in float64 in the frame of box A of each pair: R = AᵀB and
t = Aᵀ(c_B − c_A). Working relative to A keeps the numbers as small as the pair, not as
large as its distance from the world origin.

Verdict: a pair collides when no axis separates it (touching counts as colliding). Within
TOUCH_TOLERANCE(A, B) = TIE_ULPS · eps · (|c_A|∞ + |c_B|∞ + Σ half extents of A and B) of
touching, rounding may decide either way; farther from touching the verdict is exact.

Depth, normal and contact point of a colliding pair:
* normal: unit vector, world frame, along the axis of least overlap, pointing from A to B;
* depth: the overlap of the two boxes' projections on that axis, i.e. how far B has to move
  along the normal until the boxes only touch. For a box contained in another this is the
  distance to push it out through the nearest side, which is more than its own size;
* point: on a face axis, the centre of the incident feature of the other box (vertex, edge or
  face: whatever lies deepest) clamped to the reference face and placed halfway through the
  overlap; on an edge×edge axis, the midpoint of the closest points of the two edges.
Face axes win ties with edge axes (within the tolerance), so boxes resting face on face never
get a phantom contact along a noisy edge×edge axis.
"""
import math

import numpy as np

from collision_node._jit import kernel
from collision_node.obb import EPS, spheres_apart, TIE_ULPS

SEPARATED = 0
COLLIDING = 1
INVALID = 2  # a NaN reached the test: it claims neither verdict

# Two edges whose cross product is shorter than this are parallel: their axis is the zero
# vector and the face axes already decide the pair. Any longer cross product is normalised,
# so even a noisy direction is a valid axis (SAT holds for every direction).
MIN_EDGE_AXIS_LENGTH = 1e-150
# A box axis this close to perpendicular to the normal counts as lying flat on it when the
# contact feature is picked, so a face lying on a face yields the middle of that face.
FEATURE_TOLERANCE = 1e-9


def collide_pairs(centers, rotations, half_extents, radii, pairs, sphere_prefilter=False):
    """Run the SAT on each row ``(a, b)`` of ``pairs`` (P, 2).

    Returns ``(status, depth, normal, point, sat_tests)``: status (P,) int8 SEPARATED,
    COLLIDING or INVALID; depth (P,), normal (P, 3) and point (P, 3) valid where COLLIDING;
    ``sat_tests`` the number of pairs that reached the SAT (the rest failed the sphere test).
    """
    pairs = np.ascontiguousarray(pairs, dtype=np.int64).reshape(-1, 2)
    n = len(pairs)
    if n and (pairs.min() < 0 or pairs.max() >= len(centers)):
        raise ValueError('pair indices must lie in [0, %d)' % len(centers))
    status = np.empty(n, np.int8)
    depth = np.empty(n)
    normal = np.empty((n, 3))
    point = np.empty((n, 3))
    sat_tests = _collide_pairs(centers, rotations, half_extents, radii, pairs,
                               bool(sphere_prefilter), status, depth, normal, point)
    return status, depth, normal, point, sat_tests


@kernel
def _collide_pairs(centers, rotations, extents, radii, pairs, sphere_prefilter,
                   status, depth, normal, point):
    rel = np.empty((3, 3))    # R = AᵀB: column j is B's axis j in A's frame
    t = np.empty(3)           # B's centre in A's frame
    axis = np.empty(3)        # least-overlap axis in A's frame, A → B
    local_point = np.empty(3)
    sat_tests = 0
    for k in range(pairs.shape[0]):
        a = pairs[k, 0]
        b = pairs[k, 1]
        if sphere_prefilter and spheres_apart(centers, radii, a, b):
            status[k] = SEPARATED
            continue
        sat_tests += 1
        status[k], depth[k] = _separating_axis_test(centers, rotations, extents, a, b,
                                                    rel, t, axis, local_point)
        if status[k] == COLLIDING:
            for i in range(3):
                normal[k, i] = 0.0
                point[k, i] = centers[a, i]
                for j in range(3):
                    normal[k, i] += rotations[a, i, j] * axis[j]
                    point[k, i] += rotations[a, i, j] * local_point[j]
    return sat_tests


@kernel
def _separating_axis_test(centers, rotations, extents, a, b, rel, t, axis, local_point):
    """Return (status, depth); fill ``axis`` and ``local_point`` (A's frame) when colliding."""
    ea = extents[a]
    eb = extents[b]
    ra = rotations[a]
    rb = rotations[b]
    d0 = centers[b, 0] - centers[a, 0]
    d1 = centers[b, 1] - centers[a, 1]
    d2 = centers[b, 2] - centers[a, 2]
    scale = 0.0
    for i in range(3):
        t[i] = ra[0, i] * d0 + ra[1, i] * d1 + ra[2, i] * d2
        for j in range(3):
            rel[i, j] = ra[0, i] * rb[0, j] + ra[1, i] * rb[1, j] + ra[2, i] * rb[2, j]
        scale += ea[i] + eb[i] + abs(t[i])
    tie = TIE_ULPS * EPS * scale

    best = np.inf
    best_kind = -1  # 0: face of A, 1: face of B, 2: edge of A × edge of B
    best_i = 0
    best_j = 0
    for i in range(3):
        radius_b = eb[0] * abs(rel[i, 0]) + eb[1] * abs(rel[i, 1]) + eb[2] * abs(rel[i, 2])
        overlap = ea[i] + radius_b - abs(t[i])
        if overlap < 0.0:
            return SEPARATED, overlap
        if overlap != overlap:
            return INVALID, overlap
        if overlap < best:
            best, best_kind, best_i = overlap, 0, i
    for j in range(3):
        radius_a = ea[0] * abs(rel[0, j]) + ea[1] * abs(rel[1, j]) + ea[2] * abs(rel[2, j])
        dist = abs(t[0] * rel[0, j] + t[1] * rel[1, j] + t[2] * rel[2, j])
        overlap = radius_a + eb[j] - dist
        if overlap < 0.0:
            return SEPARATED, overlap
        if overlap != overlap:
            return INVALID, overlap
        if overlap < best:
            best, best_kind, best_j = overlap, 1, j
    best_face = best
    for i in range(3):
        i1 = (i + 1) % 3
        i2 = (i + 2) % 3
        for j in range(3):
            # axis = e_i × b_j; its i-th component is 0, the others come straight from R,
            # so the cross product itself adds no rounding.
            length = math.sqrt(rel[i1, j] * rel[i1, j] + rel[i2, j] * rel[i2, j])
            if length < MIN_EDGE_AXIS_LENGTH:
                continue
            n1 = -rel[i2, j] / length
            n2 = rel[i1, j] / length
            radius_a = ea[i1] * abs(n1) + ea[i2] * abs(n2)
            radius_b = 0.0
            for m in range(3):
                radius_b += eb[m] * abs(n1 * rel[i1, m] + n2 * rel[i2, m])
            overlap = radius_a + radius_b - abs(n1 * t[i1] + n2 * t[i2])
            if overlap < 0.0:
                return SEPARATED, overlap
            if overlap != overlap:
                return INVALID, overlap
            if overlap < best and overlap < best_face - tie:
                best, best_kind, best_i, best_j = overlap, 2, i, j

    if best_kind == 0:
        _face_a_contact(ea, eb, rel, t, best_i, best, axis, local_point)
    elif best_kind == 1:
        _face_b_contact(ea, eb, rel, t, best_j, best, axis, local_point)
    else:
        _edge_contact(ea, eb, rel, t, best_i, best_j, axis, local_point)
    return COLLIDING, best


@kernel
def _sign_of(x):
    if x > FEATURE_TOLERANCE:
        return 1.0
    if x < -FEATURE_TOLERANCE:
        return -1.0
    return 0.0


@kernel
def _face_a_contact(ea, eb, rel, t, i, depth, axis, p):
    """Axis e_i of A: B's deepest feature, clamped to A's face, halfway through the overlap."""
    s = 1.0 if t[i] >= 0.0 else -1.0
    for m in range(3):
        axis[m] = 0.0
        p[m] = t[m]
    axis[i] = s
    for k in range(3):
        toward = _sign_of(s * rel[i, k])  # B's axis k along the normal
        for m in range(3):
            p[m] -= eb[k] * toward * rel[m, k]
    for m in range(3):
        if m != i:
            p[m] = min(max(p[m], -ea[m]), ea[m])
    p[i] = s * (ea[i] - 0.5 * depth)


@kernel
def _face_b_contact(ea, eb, rel, t, j, depth, axis, p):
    """Axis b_j of B: A's deepest feature, clamped to B's face, halfway through the overlap."""
    length = math.sqrt(rel[0, j] ** 2 + rel[1, j] ** 2 + rel[2, j] ** 2)
    s = 1.0 if t[0] * rel[0, j] + t[1] * rel[1, j] + t[2] * rel[2, j] >= 0.0 else -1.0
    for m in range(3):
        axis[m] = s * rel[m, j] / length
    # A's support point along +axis, as coordinates u in B's frame relative to B's centre.
    u0 = 0.0
    u1 = 0.0
    u2 = 0.0
    for m in range(3):
        q = ea[m] * _sign_of(axis[m]) - t[m]
        u0 += rel[m, 0] * q
        u1 += rel[m, 1] * q
        u2 += rel[m, 2] * q
    u0 = min(max(u0, -eb[0]), eb[0])
    u1 = min(max(u1, -eb[1]), eb[1])
    u2 = min(max(u2, -eb[2]), eb[2])
    face = -s * (eb[j] - 0.5 * depth)
    if j == 0:
        u0 = face
    elif j == 1:
        u1 = face
    else:
        u2 = face
    for m in range(3):
        p[m] = t[m] + rel[m, 0] * u0 + rel[m, 1] * u1 + rel[m, 2] * u2


@kernel
def _edge_contact(ea, eb, rel, t, i, j, axis, p):
    """Axis e_i × b_j: midpoint of the closest points of A's and B's supporting edges."""
    i1 = (i + 1) % 3
    i2 = (i + 2) % 3
    length = math.sqrt(rel[i1, j] ** 2 + rel[i2, j] ** 2)
    axis[i] = 0.0
    axis[i1] = -rel[i2, j] / length
    axis[i2] = rel[i1, j] / length
    if axis[i1] * t[i1] + axis[i2] * t[i2] < 0.0:
        axis[i1] = -axis[i1]
        axis[i2] = -axis[i2]
    # A's edge runs along e_i through A's support point along +axis (kept in p);
    # B's edge runs along b_j through B's support point along -axis (pb).
    p[i] = 0.0
    p[i1] = ea[i1] * _sign_of(axis[i1])
    p[i2] = ea[i2] * _sign_of(axis[i2])
    pb0 = t[0]
    pb1 = t[1]
    pb2 = t[2]
    for k in range(3):
        if k != j:
            toward = _sign_of(axis[0] * rel[0, k] + axis[1] * rel[1, k] + axis[2] * rel[2, k])
            pb0 -= eb[k] * toward * rel[0, k]
            pb1 -= eb[k] * toward * rel[1, k]
            pb2 -= eb[k] * toward * rel[2, k]
    # Closest points of P(s) = p + s e_i, |s| <= ea_i, and Q(u) = pb + u b_j, |u| <= eb_j
    # (Ericson, Real-Time Collision Detection, 5.1.9, with centred parameters).
    r0 = p[0] - pb0
    r1 = p[1] - pb1
    r2 = p[2] - pb2
    c = r0 if i == 0 else (r1 if i == 1 else r2)
    f = rel[0, j] * r0 + rel[1, j] * r1 + rel[2, j] * r2
    b_len_sq = rel[0, j] ** 2 + rel[1, j] ** 2 + rel[2, j] ** 2
    cos_ab = rel[i, j]
    denom = b_len_sq - cos_ab * cos_ab
    s = 0.0
    if denom > 0.0:
        s = min(max((cos_ab * f - c * b_len_sq) / denom, -ea[i]), ea[i])
    u = (cos_ab * s + f) / b_len_sq
    if u < -eb[j] or u > eb[j]:
        u = min(max(u, -eb[j]), eb[j])
        s = min(max(cos_ab * u - c, -ea[i]), ea[i])
    p[i] += s
    p[0] = 0.5 * (p[0] + pb0 + u * rel[0, j])
    p[1] = 0.5 * (p[1] + pb1 + u * rel[1, j])
    p[2] = 0.5 * (p[2] + pb2 + u * rel[2, j])
