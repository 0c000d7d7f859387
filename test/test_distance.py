"""distance.box_distance against the exact referee, with python-fcl and coal beside it.

Every class aims at one hard situation (parallel faces flush, offset, turned 45° about their
normal so that the closest set is an octagon holding no vertex, or tilted by a rounding-level
angle; crossed, skew and nearly parallel edges; vertex against face, edge and vertex, and
against an edge of the other box lying flat across the gap to 1e-16..1e-6 rad; plates and
needles 1e-6 thin or flat) at sizes 1e-3 to 1e3 m, offsets 0, 1e3 and 1e6 m from the origin
and gaps from 1e-15 to 10 × the size. The generator only aims: test/exact_distance.py says
what each pair's distance is (pairs it finds overlapping or touching are drawn again), and the
kernel, called through sat.signed_distance (the World's own path), must give

* the distance within ``ACCURACY`` × (Σ half extents of both boxes), and within float64
  rounding (``ROUNDING_ULPS``),
* a point on A and a point on B (within that, plus the rounding of world coordinates),
  which are the cloud's point ∓ normal · distance / 2,
* whose distance is the one returned,
* a unit normal along which the boxes' projections are apart, within the SAT's touching
  tolerance, and by the distance within ``ACCURACY`` × size (both checked exactly),
* the same distance with A and B swapped.

A failure names its class, seed and pair. A subset of each class runs by default, more under
the ``slow`` marker (both in the suite). Run this file as a script for the peers' table
(``PYTHONPATH=. python test/test_distance.py [pairs per class]``).

The peers on the same pairs (150 per class, seed 2; python-fcl 0.7.0.11 with its default GJK,
coal 3.0.3 with its defaults and with gjk_tolerance 1e-12). Per peer: wrong contact claims
(an answer ≤ 0, i.e. -1, 0, a negative depth or -DBL_MAX, for a pair farther apart than
ACCURACY × size), then the largest error of the other answers as a fraction of Σ half extents,
and (in brackets) how many of them are off by more than ACCURACY. Ours: no claims, largest
error 1.3e-14 of the size (plates and needles; 3e-15 elsewhere), none beyond.

    class                       fcl                coal               coal_1e-12
    random_pairs          0  1.5e-03 ( 7)   17  3.5e-06 ( 1)    0  3.1e-10 ( 0)
    flush_faces           0  1.5e-01 (22)   18  1.0e-04 ( 1)    0  3.5e-10 ( 0)
    turned_faces          0  1.5e-01 (32)   22  6.1e-10 ( 0)    0  3.6e-10 ( 0)
    tilted_faces          0  1.7e-01 (20)   10  5.5e-06 ( 1)    0  3.7e-10 ( 0)
    edges_crossed         0  1.5e-08 ( 3)   18  4.0e-10 ( 0)    0  2.4e-10 ( 0)
    edges_skew            0  9.5e-04 ( 7)   12  2.8e-05 ( 1)    0  3.8e-10 ( 0)
    edges_near_parallel   0  3.0e-06 (13)   17  2.1e-07 ( 5)    1  3.0e-06 (10)
    vertex_face           0  1.0e-04 (10)   17  1.1e-04 ( 1)    0  3.7e-10 ( 0)
    vertex_edge           0  2.2e-08 ( 7)   15  3.4e-10 ( 0)    0  2.4e-10 ( 0)
    vertex_vertex         1  9.0e-09 ( 8)   20  6.6e-10 ( 0)    0  2.5e-10 ( 0)
    nearly_flat_vertex    0  9.9e-09 ( 8)   10  2.7e-05 ( 2)    0  3.1e-10 ( 0)
    plates_needles        0  4.5e-06 (21)   19  6.5e-06 (22)    1  2.5e-06 (19)

* python-fcl: 15-17 % of the size off on parallel faces (flush, turned or tilted), 1e-4 to
  1.5e-3 on some vertex–face, skew-edge and random pairs, 1e-6 on plates and near-parallel
  edges; one separated pair answered -1 ("colliding"). Moved to the origin, its errors on
  crossed edges and vertex pairs shrink to 1e-9 or less: those are world-coordinate rounding
  at 1e6 m; the face, vertex–face, plate and near-parallel errors stay.
* coal, defaults: a pair closer than about 1e-6 m is "in contact" (0, a negative depth or
  -DBL_MAX), 10-22 per class; errors up to 1e-4 on faces, edges and vertex–face pairs.
* coal, gjk_tolerance 1e-12: within 4e-10 of the size except near-parallel edges and plates
  (3e-6), one wrong contact claim each there.

``test_peers`` asserts ours against ACCURACY and the peers only against ten times the errors
above (``PEER_BOUNDS``), so that a change in a peer shows up without failing the suite for
what the peer gets wrong.
"""
from collections import defaultdict
from decimal import Decimal
from fractions import Fraction
import functools
import math
import os
import pathlib
import subprocess
import sys

import coal
from exact_distance import exact_distance, support, unit_box
import fcl
import numpy as np
import pytest
from test_sat_stress import (axis_angle, Case, crossing_edges_offset, draw_cases, matrix,
                             multiply, place_on_ray, random_quaternion, random_unit, signs,
                             support_offset, touching_vertex_face, touching_vertices)

from collision_node.pipeline import distance, sat
from collision_node.pipeline.obb import EPS

REPO = pathlib.Path(__file__).resolve().parent.parent
ACCURACY = 1e-9       # of the pair's size: Σ half extents of both boxes
# What the kernel promises is ACCURACY; it does better, float64 rounding: within this many
# ulps of (pair size + distance) of the exact distance (seen: up to 4). This catches a
# formula that loses digits long before ACCURACY does: Ericson's textbook segment parameter
# (b·f − c·e) / (a·e − b²) instead of distance.py's loses 1e5 × more on near-parallel edges.
ROUNDING_ULPS = 64.0
# The normal is unit to this many ulps (a face normal is a column of a float64 rotation).
NORMAL_ULPS = 16.0
SIZES = (1e-3, 1e-2, 1e-1, 1.0, 1e1, 1e2, 1e3)     # metres
OFFSETS = (0.0, 1e3, 1e6)                          # metres from the world origin
GAPS = (1e-15, 1e-12, 1e-9, 1e-6, 1e-3, 1e-1, 1.0, 10.0)   # × size, the aimed gap
FAST_CASES = 10
SLOW_CASES = 150


def pair_size(case):
    return float(np.sum(case.half_a) + np.sum(case.half_b))


# ---------------------------------------------------------------- the classes
# Each takes (rng, size, gap) and returns (qa, half_a, qb, half_b, c_b − c_a) or None (retry).

def extents_of(rng, size):
    return size * rng.uniform(0.2, 1.0, 3)


def random_pairs(rng, size, gap):
    """Any orientations and extents (1:20), B moved from A's centre until the SAT gap is gap."""
    qa, qb = random_quaternion(rng), random_quaternion(rng)
    ea, eb = size * rng.uniform(0.05, 1.0, 3), size * rng.uniform(0.05, 1.0, 3)
    return qa, ea, qb, eb, place_on_ray(qa, ea, qb, eb, np.zeros(3), random_unit(rng), gap)


def face_frame(rng):
    """Return (qa, i, u): A's orientation, a face axis i and its outward normal u (world)."""
    qa = random_quaternion(rng)
    i = int(rng.integers(3))
    return qa, i, matrix(qa)[:, i] * rng.choice((-1.0, 1.0))


def flush_faces(rng, size, gap):
    """B turned like A, against a face of A: flush (same face, edges aligned) or offset."""
    qa, i, u = face_frame(rng)
    ea, eb = extents_of(rng, size), extents_of(rng, size)
    lateral = np.zeros(3)
    if rng.uniform() < 0.5:
        eb[np.arange(3) != i] = ea[np.arange(3) != i]      # flush: same face, same place
    else:
        reach = (ea + eb) * (np.arange(3) != i)             # offset: the faces overlap in part
        lateral = rng.uniform(-0.95, 0.95, 3) * reach
    return qa, ea, qa.copy(), eb, matrix(qa) @ lateral + (ea[i] + eb[i] + gap) * u


def turned_faces(rng, size, gap):
    """B's face on A's, turned about the normal: by 45° on equal squares (an octagon), or any."""
    qa, i, u = face_frame(rng)
    ea, eb = extents_of(rng, size), extents_of(rng, size)
    side = size * rng.uniform(0.2, 1.0)
    ea[np.arange(3) != i] = side
    eb[np.arange(3) != i] = side
    turn = math.pi / 4 if rng.uniform() < 0.6 else rng.uniform(0.0, 2 * math.pi)
    qb = multiply(qa, axis_angle(np.eye(3)[i], turn))
    return qa, ea, qb, eb, (ea[i] + eb[i] + gap) * u


def edges_crossed(rng, size, gap):
    """Cross an edge of B with an edge of A at right angles (no faces parallel), gap apart."""
    qa = random_quaternion(rng)
    ea, eb = extents_of(rng, size), extents_of(rng, size)
    i, j = int(rng.integers(3)), int(rng.integers(3))
    e_i, e_j = np.eye(3)[i], np.eye(3)[j]
    v = np.cross(e_i, random_unit(rng))
    v /= np.linalg.norm(v)                                   # ⊥ a_i, in A's frame
    to_v = np.cross(e_j, v)
    angle = math.atan2(np.linalg.norm(to_v), e_j @ v)
    local = multiply(axis_angle(v, rng.uniform(0, 2 * math.pi)),
                     axis_angle(to_v if np.linalg.norm(to_v) > 1e-9 else np.eye(3)[(j + 1) % 3],
                                angle))
    qb = multiply(qa, local)
    return qa, ea, qb, eb, crossing_edges_offset(rng, qa, ea, qb, eb, gap, i, j)


def edges_skew(rng, size, gap):
    """Crossing edges at any angle, apart by gap along their common normal."""
    qa, qb = random_quaternion(rng), random_quaternion(rng)
    ea, eb = extents_of(rng, size), extents_of(rng, size)
    return qa, ea, qb, eb, crossing_edges_offset(rng, qa, ea, qb, eb, gap)


def edges_near_parallel(rng, size, gap):
    """Turn an edge of B by 1e-16 to 1e-3 rad from an edge of A, crossing it gap apart."""
    qa, ea, eb = random_quaternion(rng), extents_of(rng, size), extents_of(rng, size)
    i = int(rng.integers(3))
    turn = axis_angle(np.eye(3)[i], rng.choice((0.0, 0.5 * math.pi, rng.uniform(0, 2 * math.pi))))
    tilt = axis_angle(random_unit(rng), 10.0 ** rng.uniform(-16, -3))
    qb = multiply(multiply(qa, turn), tilt)
    return qa, ea, qb, eb, crossing_edges_offset(rng, qa, ea, qb, eb, gap, i, i)


def tilted_faces(rng, size, gap):
    """B's face over A's, turned about the normal and tilted by 1e-17 to 1e-13 rad.

    The tilt is at the level of rounding: the signs that pick the support edges are in doubt.
    Half of them on equal squares, half shifted sideways.
    """
    qa, i, u = face_frame(rng)
    ea, eb = extents_of(rng, size), extents_of(rng, size)
    lateral = np.zeros(3)
    if rng.uniform() < 0.5:
        side = size * rng.uniform(0.2, 1.0)
        ea[np.arange(3) != i] = side
        eb[np.arange(3) != i] = side
    else:
        lateral = rng.uniform(-0.95, 0.95, 3) * (ea + eb) * (np.arange(3) != i)
    turn = rng.choice((0.0, 0.25 * math.pi, 0.5 * math.pi, rng.uniform(0, 2 * math.pi)))
    tilt = axis_angle(random_unit(rng), 10.0 ** rng.uniform(-17, -13))
    qb = multiply(multiply(qa, axis_angle(np.eye(3)[i], turn)), tilt)
    return qa, ea, qb, eb, matrix(qa) @ lateral + (ea[i] + eb[i] + gap) * u


def vertex_face(rng, size, gap):
    """B's lowest vertex over a face of A."""
    return touching_vertex_face(rng, size, gap)


def vertex_edge(rng, size, gap):
    """B's vertex nearest A over an edge of A, along a direction in the edge's normal cone."""
    qa, qb = random_quaternion(rng), random_quaternion(rng)
    ea, eb = extents_of(rng, size), extents_of(rng, size)
    ra, rb = matrix(qa), matrix(qb)
    i = int(rng.integers(3))                     # the edge runs along a_i
    side = signs(rng) * (np.arange(3) != i)
    weights = rng.uniform(0.1, 1.0, 3) * side
    u = ra @ weights / np.linalg.norm(weights)   # outward, between the edge's two faces
    on_edge = ra @ (side * ea + rng.uniform(-0.9, 0.9) * ea[i] * np.eye(3)[i])
    return qa, ea, qb, eb, on_edge + gap * u - support_offset(rb, eb, -u)


def vertex_vertex(rng, size, gap):
    """Put a vertex of B against a vertex of A, along A's diagonal there."""
    return touching_vertices(rng, size, gap)


def nearly_flat_vertex(rng, size, gap):
    """B's vertex over an edge or a vertex of A, with an edge of B 1e-16 to 1e-6 rad from flat.

    That edge of B runs almost across the gap, so the closest features' normal cones are
    nearly their boundary: rounding can tilt a normal computed from the points out of them,
    by the gap's rounding over its length. Half of the pairs are swapped (A's vertex).
    """
    qa, ea, eb = random_quaternion(rng), extents_of(rng, size), extents_of(rng, size)
    ra = matrix(qa)
    feature = signs(rng) * (rng.permutation(3) < rng.integers(2, 4))   # an edge or a vertex
    weights = rng.uniform(0.1, 1.0, 3) * feature
    u = ra @ weights / np.linalg.norm(weights)
    on_feature = ra @ (feature * ea + (feature == 0) * rng.uniform(-0.9, 0.9) * ea)
    v = np.cross(u, random_unit(rng))
    v /= np.linalg.norm(v)
    tilt = rng.choice((-1.0, 1.0)) * 10.0 ** rng.uniform(-16, -6)
    b_0 = math.cos(tilt) * v + math.sin(tilt) * u                      # B's edge, nearly ⊥ u
    x = np.array([1.0, 0.0, 0.0])
    turn = np.cross(x, b_0)
    if np.linalg.norm(turn) < 1e-9:
        return qa, ea, qa, eb, None
    qb = multiply(axis_angle(turn, math.atan2(np.linalg.norm(turn), x @ b_0)),
                  axis_angle(x, rng.uniform(0.0, 2.0 * math.pi)))
    t = on_feature + gap * u - support_offset(matrix(qb), eb, -u)
    if rng.uniform() < 0.5:
        return qb, eb, qa, ea, -t
    return qa, ea, qb, eb, t


def plates_needles(rng, size, gap):
    """Plates (one half extent 1e-6 of the size or 0) and needles (two)."""
    qa, qb = random_quaternion(rng), random_quaternion(rng)
    ea, eb = extents_of(rng, size), extents_of(rng, size)
    for e in (ea, eb):
        thin = rng.permutation(3)[:rng.integers(1, 3)]
        e[thin] = rng.choice((0.0, 1e-6 * size))
    if rng.uniform() < 0.5:
        return qa, ea, qb, eb, crossing_edges_offset(rng, qa, ea, qb, eb, gap,
                                                     int(np.argmax(ea)), int(np.argmax(eb)))
    return qa, ea, qb, eb, place_on_ray(qa, ea, qb, eb, np.zeros(3), random_unit(rng), gap)


CLASSES = {
    'random_pairs': random_pairs,
    'flush_faces': flush_faces,
    'turned_faces': turned_faces,
    'tilted_faces': tilted_faces,
    'edges_crossed': edges_crossed,
    'edges_skew': edges_skew,
    'edges_near_parallel': edges_near_parallel,
    'vertex_face': vertex_face,
    'vertex_edge': vertex_edge,
    'vertex_vertex': vertex_vertex,
    'nearly_flat_vertex': nearly_flat_vertex,
    'plates_needles': plates_needles,
}


@functools.lru_cache(maxsize=None)
def generate(name, count, seed):
    """Return ``count`` separated pairs of class ``name`` with their exact distances."""
    def separated(case):
        exact = exact_distance(*case)
        return None if exact.colliding else (case, exact)
    return tuple(draw_cases(CLASSES, name, count, seed, separated, SIZES, GAPS, OFFSETS))


# ---------------------------------------------------------------- running and checking

def ours(case, swap=False):
    """Return (distance, point on A, point on B) from sat.signed_distance (world frame)."""
    a = (case.pose_a[:3], matrix(case.pose_a[3:]), case.half_a)
    b = (case.pose_b[:3], matrix(case.pose_b[3:]), case.half_b)
    if swap:
        d, point_b, point_a, normal = sat.signed_distance(*b, *a)
        return sat.SignedDistance(d, point_a, point_b, -normal)
    return sat.signed_distance(*a, *b)


def outside(point, pose, half_extents):
    """How far ``point`` lies outside the box (max over its axes; float64 is enough)."""
    offset = matrix(pose[3:]).T @ (np.asarray(point) - pose[:3])
    return float(np.max(np.abs(offset) - half_extents))


def projection_gap(case, normal):
    """Return the exact gap between the boxes' projections on ``normal`` (a float vector)."""
    box_a, box_b = unit_box(case.pose_a, case.half_a), unit_box(case.pose_b, case.half_b)
    n = tuple(Fraction(float(x)) for x in normal)
    return -support(box_b, tuple(-x for x in n)) - support(box_a, n)


def check(case, exact):
    """Return the failed checks and the relative distance error of one pair."""
    tolerance = ACCURACY * pair_size(case)
    # World coordinates far from the origin are rounded to eps·|c| (0.2 nm at 1e6 m).
    representable = 4 * EPS * float(np.abs(case.pose_a[:3]).max())
    d, point_a, point_b, normal = ours(case)
    error = abs(Decimal(d) - exact.distance)
    failed = []
    if abs(np.linalg.norm(normal) - 1.0) > NORMAL_ULPS * EPS:
        failed.append('normal_unit')
    touching = sat.touch_tolerance(case.pose_a[:3], case.pose_b[:3], case.half_a, case.half_b)
    gap = projection_gap(case, normal)
    if gap < -Fraction(touching):
        failed.append('normal_separates')
    if Decimal(gap.numerator) / Decimal(gap.denominator) < exact.distance - Decimal(tolerance):
        failed.append('normal_closest')
    if error > Decimal(tolerance):
        failed.append('distance')
    if error > Decimal(ROUNDING_ULPS * EPS) * (Decimal(pair_size(case)) + exact.distance):
        failed.append('rounding')
    if outside(point_a, case.pose_a, case.half_a) > tolerance + representable:
        failed.append('point_a')
    if outside(point_b, case.pose_b, case.half_b) > tolerance + representable:
        failed.append('point_b')
    if abs(np.linalg.norm(point_b - point_a) - d) > tolerance + 2 * representable:
        failed.append('points_apart')
    if abs(ours(case, swap=True)[0] - d) > tolerance:
        failed.append('symmetry')
    return failed, float(error) / pair_size(case)


def failures(name, count, seed):
    """Return {check: (how many pairs failed it, the first of them)}, and the worst error."""
    failed_pairs = {}
    worst = 0.0
    for index, (case, exact) in enumerate(generate(name, count, seed)):
        failed, error = check(case, exact)
        for reason in failed:
            number, first = failed_pairs.get(reason, (0, None))
            failed_pairs[reason] = (number + 1, first or describe(name, seed, index, case, exact))
        worst = max(worst, error)
    return failed_pairs, worst


def describe(name, seed, index, case, exact):
    """Name one pair so that a failure can be reproduced: class, seed, index and its numbers."""
    return ('%s seed %d pair %d: distance %.3g m, size %.3g m, %.3g m from the origin; %r'
            % (name, seed, index, float(exact.distance), pair_size(case),
               float(np.abs(case.pose_a[:3]).max()), case))


@pytest.mark.parametrize('name', CLASSES)
def test_against_the_exact_referee(name):
    failed, worst = failures(name, FAST_CASES, seed=1)
    assert failed == {}, (failed, worst)


@pytest.mark.slow
@pytest.mark.parametrize('name', CLASSES)
def test_against_the_exact_referee_many(name):
    failed, worst = failures(name, SLOW_CASES, seed=2)
    assert failed == {}, (failed, worst)


# ---------------------------------------------------------------- through touching

@pytest.mark.parametrize('name', ['flush_faces', 'turned_faces', 'tilted_faces', 'edges_skew',
                                  'vertex_face', 'vertex_edge', 'vertex_vertex'])
def test_distance_goes_to_zero_linearly_through_touching(name):
    """The same configuration at gaps 0.1 × size down to 1e-12 × size, then touching.

    Each class moves B along a direction in which its gap is exactly the distance (a face
    normal, the edges' common normal, a direction in the normal cone of A's vertex or edge),
    so the distance must be the gap: linear down to 0, and equal to the referee's.
    """
    for seed in range(4):
        gaps = [10.0 ** -k for k in range(1, 13)] + [0.0]
        found = []
        for gap in gaps:
            rng = np.random.default_rng([seed, 99])  # the same draws for every gap
            qa, ea, qb, eb, t = CLASSES[name](rng, 1.0, gap)
            case = Case(np.r_[0.0, 0.0, 0.0, qa], ea, np.r_[t, qb], eb)
            exact = exact_distance(*case)
            d = ours(case)[0]
            rounding = ROUNDING_ULPS * EPS * (pair_size(case) + gap)
            assert abs(Decimal(d) - exact.distance) <= Decimal(ACCURACY * pair_size(case))
            assert abs(d - gap) <= rounding, (gap, d)
            found.append(d)
        assert found == sorted(found, reverse=True)


# ---------------------------------------------------------------- the kernel and the wrapper

IDENTITY = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)


def test_kernel_returns_the_distance_points_and_normal_in_a_frame():
    """Analytic cases, one per kind of closest features: vertex–vertex, face, edge–edge."""
    ones = (1.0, 1.0, 1.0)
    d, p, q, n = distance.box_distance(IDENTITY, (3.0, 3.0, 3.0), ones, ones)
    assert (d, p, q) == (math.sqrt(3.0), (1.0, 1.0, 1.0), (2.0, 2.0, 2.0))
    assert np.allclose(n, np.full(3, 1.0 / math.sqrt(3.0)), rtol=0, atol=1e-16)
    d, p, q, n = distance.box_distance(IDENTITY, (0.0, 3.5, 0.25), ones, (0.5, 0.5, 0.5))
    assert d == 2.0 and p[1] == 1.0 and q[1] == 3.0 and abs(p[0]) <= 0.5 and p[2] >= -0.25
    assert n == (0.0, 1.0, 0.0)  # the face normal itself, not a rounded offset
    assert all(isinstance(x, float) for x in p + q + n)
    # A turned 45° about y, B 45° about x, B above A: A's top edge (along y) crosses B's
    # bottom edge (along x) at right angles, 0.5 apart.
    ra, rb = matrix(axis_angle([0, 1, 0], math.pi / 4)), matrix(axis_angle([1, 0, 0], math.pi / 4))
    rel = tuple((ra.T @ rb).ravel())
    t = tuple(ra.T @ np.array([0.0, 0.0, 2 * math.sqrt(2.0) + 0.5]))
    d, p, q, n = distance.box_distance(rel, t, ones, ones)
    assert abs(d - 0.5) < 1e-15
    assert np.allclose(ra @ p, [0.0, 0.0, math.sqrt(2.0)], rtol=0, atol=1e-15)
    assert np.allclose(ra @ q, [0.0, 0.0, math.sqrt(2.0) + 0.5], rtol=0, atol=1e-15)
    assert np.allclose(ra @ n, [0.0, 0.0, 1.0], rtol=0, atol=1e-15)


@pytest.mark.parametrize('gap', [1e-15, 1e-12, 1e-9, 1e-7, 1e-3])
def test_a_vertex_over_an_edge_at_tiny_gaps(gap):
    """B's vertex over A's edge, along the edge's bisector: n = (1, 1, 0)/√2 at every gap.

    B is a cube whose diagonal points along the bisector. The SAT's widest axis (a face
    normal, 45° off) separates the boxes too, but points taken with it lie up to 0.77 × the
    gap / 2 off their boxes (the rule before: below 1.2e-7 × size); only the direction between
    the features gives points on the boxes, their distance apart.
    """
    bisector = np.array([1.0, 1.0, 0.0]) / math.sqrt(2.0)
    diagonal = np.ones(3) / math.sqrt(3.0)
    axis = np.cross(diagonal, bisector)
    qb = axis_angle(axis, math.atan2(np.linalg.norm(axis), diagonal @ bisector))
    rb = matrix(qb)
    center_b = np.array([1.0, 1.0, 0.25]) + gap * bisector - rb @ -np.ones(3)
    pose_a = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    case = Case(pose_a, np.ones(3), np.r_[center_b, qb], np.ones(3))
    exact = exact_distance(*case)
    assert not exact.colliding
    found = ours(case)
    assert abs(Decimal(found.distance) - exact.distance) <= Decimal(ROUNDING_ULPS * EPS * 6.0)
    assert check(case, exact)[0] == []
    if gap >= 1e-9:   # far above the rounding of the vertex (eps × 3): the exact bisector
        assert np.allclose(found.normal, bisector, rtol=0, atol=4 * EPS * 3.0 / gap)


def test_kernel_on_overlapping_boxes_is_not_a_distance_but_the_sat_says_overlap():
    """Two needles crossing like a plus sign: no vertex inside, no edges crossing."""
    a = (np.zeros(3), np.eye(3), np.array([1.0, 0.01, 0.01]))
    turned = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    b = (np.zeros(3), turned, np.array([1.0, 0.02, 0.02]))
    rel = tuple((a[1].T @ b[1]).ravel())
    assert distance.box_distance(rel, (0.0, 0.0, 0.0), tuple(a[2]), tuple(b[2]))[0] > 0.0
    d, point_a, point_b, _ = sat.signed_distance(*a, *b)
    assert d == -0.03 and np.array_equal(point_a, point_b)  # minus the depth: 0.01 + 0.02 in z
    assert np.all(np.abs(point_a) <= a[2]) and np.all(np.abs(b[1].T @ point_b) <= b[2])


def test_far_from_the_origin_only_the_relative_pose_counts():
    shift = np.array([1e6, -1e6, 3e5])
    turned = matrix(axis_angle([1.0, 2.0, 3.0], 0.7))
    a = (np.zeros(3), np.eye(3), np.array([0.5, 0.25, 0.125]))
    b = (np.array([2.0, 0.5, 0.25]), turned, np.array([0.25, 0.5, 0.125]))
    near = sat.signed_distance(*a, *b)
    far = sat.signed_distance(a[0] + shift, a[1], a[2], b[0] + shift, b[1], b[2])
    assert near[0] == far[0]
    assert np.allclose(far[1] - shift, near[1], atol=1e-9)


@pytest.mark.parametrize('change, message', [
    (lambda args: args.__setitem__(0, [0.0, 0.0]), 'center_a must have shape'),
    (lambda args: args.__setitem__(4, np.eye(4)), 'rotation_b must have shape'),
    (lambda args: args[3].__setitem__(1, np.nan), 'center_b has a NaN'),
    (lambda args: args[1].__setitem__((0, 0), np.inf), 'rotation_a has a NaN or Inf'),
    (lambda args: args[5].__setitem__(2, -1.0), 'half_extents_b must be >= 0'),
    (lambda args: args.__setitem__(1, np.eye(3) * 1.001), 'rotation_a must be orthonormal'),
    (lambda args: args.__setitem__(1, np.eye(3).astype(np.float32) @ matrix(
        np.array([0.1, 0.2, 0.3, 0.9])).astype(np.float32)), 'rotation_a must be orthonormal'),
    (lambda args: (args[0].__setitem__(0, -1.7e308), args[3].__setitem__(0, 1.7e308)),
     'too far apart'),
])
def test_wrapper_refuses_bad_input(change, message):
    args = [np.zeros(3), np.eye(3), np.ones(3), np.array([3.0, 0.0, 0.0]), np.eye(3), np.ones(3)]
    assert sat.signed_distance(*args)[0] == 1.0
    change(args)
    with pytest.raises(ValueError, match=message):
        sat.signed_distance(*args)


CACHE_CHECK = """
import numpy as np
from collision_node.pipeline import distance, sat
assert type(distance.box_distance._cache).__name__ == 'FunctionCache'
print(sat.signed_distance(np.zeros(3), np.eye(3), np.ones(3), np.full(3, 3.0),
                          np.eye(3), np.ones(3))[0])
print(sum(sat.collide_pair_rows.stats.cache_hits.values()))
"""


def test_the_kernel_is_cached(tmp_path):
    """In fresh processes: the first compiles into numba's cache, the second loads it."""
    def run():
        done = subprocess.run([sys.executable, '-c', CACHE_CHECK], capture_output=True,
                              text=True, timeout=300, cwd=str(REPO),
                              env=dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path)))
        assert done.returncode == 0, done.stderr[-3000:]
        value, hits = done.stdout.split()
        assert float(value) == math.sqrt(3.0)
        return int(hits)
    assert run() == 0
    assert run() == 1
    assert any(name.startswith('distance.box_distance')
               for _, _, names in os.walk(tmp_path) for name in names)


# ---------------------------------------------------------------- the peers

def fcl_distance(case):
    """Return python-fcl's distance (fcl.Box takes full side lengths)."""
    def body(pose, half_extents):
        return fcl.CollisionObject(fcl.Box(*(2.0 * np.asarray(half_extents))),
                                   fcl.Transform(matrix(pose[3:]), np.asarray(pose[:3])))
    result = fcl.DistanceResult()
    return fcl.distance(body(case.pose_a, case.half_a), body(case.pose_b, case.half_b),
                        fcl.DistanceRequest(enable_nearest_points=True), result)


def coal_distance(case, gjk_tolerance=None):
    """Return coal's distance (coal.Box takes full side lengths too)."""
    def shape(half_extents):
        return coal.Box(*(2.0 * np.asarray(half_extents)))

    def place(pose):
        return coal.Transform3s(matrix(pose[3:]), np.asarray(pose[:3], dtype=float))
    request = coal.DistanceRequest()
    if gjk_tolerance is not None:
        request.gjk_tolerance = gjk_tolerance
    return coal.distance(shape(case.half_a), place(case.pose_a), shape(case.half_b),
                         place(case.pose_b), request, coal.DistanceResult())


PEERS = {
    'fcl': fcl_distance,
    'coal': coal_distance,                                        # its default gjk_tolerance 1e-6
    'coal_1e-12': lambda case: coal_distance(case, gjk_tolerance=1e-12),
}


def at_origin(case):
    """Return the case moved so that A's centre is at the origin, or None if not exact."""
    shift = case.pose_b[:3] - case.pose_a[:3]
    exact = all(Fraction(b) - Fraction(a) == Fraction(d)
                for a, b, d in zip(case.pose_a[:3], case.pose_b[:3], shift))
    return Case(np.r_[0.0, 0.0, 0.0, case.pose_a[3:]], case.half_a,
                np.r_[shift, case.pose_b[3:]], case.half_b) if exact else None


def peer_results(name, count, seed, origin=False):
    """Return {peer: (wrong contact claims, relative errors of the other answers)}.

    A contact claim is an answer ≤ 0 or not finite (python-fcl answers -1 when it finds the
    boxes colliding; coal 0, a negative depth or -DBL_MAX). It is wrong when the exact
    distance exceeds ACCURACY × pair size; else it counts as the answer 0.
    ``origin``: measure the pairs moved to A's centre (world rounding left out).
    """
    claims = defaultdict(int)
    errors = defaultdict(list)
    for case, exact in generate(name, count, seed):
        if origin:
            case = at_origin(case)
            if case is None:
                continue
        for peer, measure in PEERS.items():
            got = measure(case)
            if not (math.isfinite(got) and got > 0.0):
                if exact.distance > Decimal(ACCURACY * pair_size(case)):
                    claims[peer] += 1
                    continue
                got = 0.0
            errors[peer].append(float(abs(Decimal(got) - exact.distance)) / pair_size(case))
    return {peer: (claims[peer], np.array(errors[peer] or [0.0])) for peer in PEERS}


def report(count, seed=2):
    """Print, per class and peer: contact claims, largest error, pairs beyond ACCURACY."""
    for origin in (False, True):
        where = ', moved to the origin' if origin else ''
        print('\n%d pairs per class%s; per peer: wrong contact claims / largest relative '
              'error of the rest (pairs beyond %g)' % (count, where, ACCURACY))
        print('%-20s' % 'class' + ''.join('%28s' % peer for peer in PEERS))
        for name in CLASSES:
            results = peer_results(name, count, seed, origin)
            print('%-20s' % name + ''.join(
                '%9d %9.1e (%3d)' % (claims, errors.max(), (errors > ACCURACY).sum())
                for claims, errors in results.values()))


# Ten times the largest errors in the module docstring's table (fcl, coal, coal_1e-12).
PEER_BOUNDS = {
    'random_pairs': (1.5e-2, 3.5e-5, 3.1e-9),
    'flush_faces': (1.5, 1.0e-3, 3.5e-9),
    'turned_faces': (1.5, 6.1e-9, 3.6e-9),
    'tilted_faces': (1.7, 5.5e-5, 3.7e-9),
    'edges_crossed': (1.5e-7, 4.0e-9, 2.4e-9),
    'edges_skew': (9.5e-3, 2.8e-4, 3.8e-9),
    'edges_near_parallel': (3.0e-5, 2.1e-6, 3.0e-5),
    'vertex_face': (1.0e-3, 1.1e-3, 3.7e-9),
    'vertex_edge': (2.2e-7, 3.4e-9, 2.4e-9),
    'vertex_vertex': (9.0e-8, 6.6e-9, 2.5e-9),
    'nearly_flat_vertex': (9.9e-8, 2.7e-4, 3.1e-9),
    'plates_needles': (4.5e-5, 6.5e-5, 2.5e-5),
}


@pytest.mark.parametrize('name', CLASSES)
def test_peers(name):
    for case, exact in generate(name, FAST_CASES, seed=1):
        assert check(case, exact)[0] == []
    for (claims, errors), bound in zip(peer_results(name, FAST_CASES, seed=1).values(),
                                       PEER_BOUNDS[name]):
        assert errors.max() <= bound


if __name__ == '__main__':
    report(int(sys.argv[1]) if len(sys.argv) > 1 else 150)
