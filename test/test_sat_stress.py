"""Stress classes for the SAT kernel, each case labelled by the exact referee.

Every class builds pairs of boxes aimed at one hard situation (touching faces, edges and
vertices; gaps and overlaps of ±1e-9, ±1e-6 and ±1e-3 of the box size; sizes 1e-3 to 1e3 m;
offsets 0, 1e3 and 1e6 m from the origin; near-parallel edges; crossing edges; plates and
needles; a box inside another; quaternions off unit norm or negated). The generator only
aims: the exact referee (``exact_sat.py``) says what each pair really is, and the kernel is
checked against it:

* verdict: every pair farther from touching than ``sat.touch_tolerance`` gets the exact
  verdict (pairs within it may go either way; they are counted, not excused silently);
* depth: within ``RELATIVE_ACCURACY`` × size of the exact SAT depth;
* normal: unit, pointing from A to B, the boxes overlap along it by the reported depth, and it
  is (within ``RELATIVE_ACCURACY``) one of the exact axes whose overlap is within
  ``RELATIVE_ACCURACY`` × size of the least (several axes may tie);
* contact point: inside or on both boxes, within ``RELATIVE_ACCURACY`` × size.

A small subset of every class runs quickly; the ``slow`` marker runs hundreds per class. Run
this file as a script to print failure counts per class and check:
``PYTHONPATH=. python test/test_sat_stress.py [cases per class]`` (see ``report``).
"""
from collections import Counter
from decimal import Decimal
import math
import sys
from typing import NamedTuple

from exact_sat import distance_outside, exact_sat, separation_along, signed_offset_along
import numpy as np
import pytest

from collision_node.pipeline import sat
from collision_node.pipeline.obb import Boxes, EPS, set_boxes, TIE_ULPS

# Depth, normal and contact point agree with the exact values to this fraction of the size of
# the larger box (its largest half extent); float64 rounding alone is ~1e-14 of it.
RELATIVE_ACCURACY = 1e-9
# The direction of an edge×edge axis e_a × e_b is only defined to ~eps / sin(angle between the
# edges) by float64 rotation matrices (the referee's exact rotation and the kernel's float64 one
# differ by an ulp); seen: up to 1.4 eps / sine.
EDGE_NORMAL_ULPS = 16.0
SIZES = (1e-3, 1e-2, 1e-1, 1.0, 1e1, 1e2, 1e3)       # metres, the scale of a pair
OFFSETS = (0.0, 1e3, 1e6)                            # metres from the world origin
GAPS = (0.0, 1e-9, -1e-9, 1e-6, -1e-6, 1e-3, -1e-3)  # fraction of the size; < 0: overlap
FAST_CASES = 12     # per class, in the default run
SLOW_CASES = 400    # per class, marked slow


class Case(NamedTuple):
    pose_a: np.ndarray   # x y z qx qy qz qw
    half_a: np.ndarray
    pose_b: np.ndarray
    half_b: np.ndarray


# ---------------------------------------------------------------- float64 construction helpers

def random_quaternion(rng):
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def axis_angle(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.r_[axis * math.sin(0.5 * angle), math.cos(0.5 * angle)]


def multiply(p, q):
    """Return the quaternion product p ⊗ q in (x, y, z, w) order: q first, then p."""
    px, py, pz, pw = p
    qx, qy, qz, qw = q
    return np.array([pw * qx + px * qw + py * qz - pz * qy,
                     pw * qy - px * qz + py * qw + pz * qx,
                     pw * qz + px * qy - py * qx + pz * qw,
                     pw * qw - px * qx - py * qy - pz * qz])


def matrix(q):
    """Return the rotation matrix of a quaternion; column k is box axis k."""
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def random_unit(rng):
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def perpendicular(rng, u, magnitude):
    """Return a random vector perpendicular to unit ``u``, of length up to ``magnitude``."""
    v = np.cross(u, random_unit(rng))
    return v / np.linalg.norm(v) * magnitude * rng.uniform()


def signs(rng):
    return rng.choice((-1.0, 1.0), size=3)


def float_axes(qa, qb):
    """Return the 15 SAT axes in float64 (unit), skipping parallel edges' cross products."""
    ra, rb = matrix(qa), matrix(qb)
    axes = [ra[:, i] for i in range(3)] + [rb[:, j] for j in range(3)]
    for i in range(3):
        for j in range(3):
            c = np.cross(ra[:, i], rb[:, j])
            if np.linalg.norm(c) > 1e-9:
                axes.append(c / np.linalg.norm(c))
    return ra, rb, axes


def place_on_ray(qa, ea, qb, eb, lateral, u, gap):
    """Return B's centre relative to A's where the SAT says "touching", moved by ``gap``.

    B moves along the ray ``lateral + s u``; the gap is the separation along the deciding
    axis. None if the ray misses A.
    """
    ra, rb, axes = float_axes(qa, qb)
    low, high, deciding = -np.inf, np.inf, None
    for axis in axes:
        reach = np.abs(ra.T @ axis) @ ea + np.abs(rb.T @ axis) @ eb
        along, base = u @ axis, lateral @ axis
        if abs(along) < 1e-12:
            if abs(base) > reach:
                return None
            continue
        ends = sorted(((-reach - base) / along, (reach - base) / along))
        low = max(low, ends[0])
        if ends[1] < high:
            high, deciding = ends[1], abs(along)
    if low > high:
        return None
    return lateral + (high + gap / deciding) * u


def support_offset(rotation, extents, direction):
    """Return the box's vertex farthest along ``direction``, relative to its centre."""
    return rotation @ (np.sign(rotation.T @ direction) * extents)


# ---------------------------------------------------------------- the classes
# Each takes (rng, size, gap) and returns (qa, half_a, qb, half_b, c_b − c_a) or None (retry).

def extents_of(rng, size):
    return size * rng.uniform(0.2, 1.0, 3)


def touching_faces(rng, size, gap):
    """B lies on a face of A, turned about the face normal (0, a multiple of 90° or any)."""
    qa, ea, eb = random_quaternion(rng), extents_of(rng, size), extents_of(rng, size)
    i = rng.integers(3)
    turn = rng.choice((0.0, 0.5 * math.pi * rng.integers(1, 4), rng.uniform(0, 2 * math.pi)))
    qb = multiply(qa, axis_angle(np.eye(3)[i], turn))
    u = matrix(qa)[:, i] * rng.choice((-1.0, 1.0))
    lateral = perpendicular(rng, u, 0.5 * min(ea.min(), eb.min()))
    return qa, ea, qb, eb, place_on_ray(qa, ea, qb, eb, lateral, u, gap)


def touching_edges(rng, size, gap):
    """Cross an edge of A with an edge of B at a known point, apart by ``gap`` on their axis."""
    qa, qb = random_quaternion(rng), random_quaternion(rng)
    ea, eb = extents_of(rng, size), extents_of(rng, size)
    return (qa, ea, qb, eb) + (crossing_edges_offset(rng, qa, ea, qb, eb, gap),)


def crossing_edges_offset(rng, qa, ea, qb, eb, gap, i=None, j=None):
    ra, rb = matrix(qa), matrix(qb)
    i = rng.integers(3) if i is None else i
    j = rng.integers(3) if j is None else j
    axis = np.cross(ra[:, i], rb[:, j])
    if not np.linalg.norm(axis) > 0.0:   # parallel to the last bit: no crossing to aim at
        return None
    axis /= np.linalg.norm(axis)
    # A's edge along a_i that supports +axis, B's edge along b_j that supports -axis.
    edge_a = support_offset(ra, ea * (np.arange(3) != i), axis)
    edge_b = support_offset(rb, eb * (np.arange(3) != j), -axis)
    cross_at = rng.uniform(-0.8, 0.8, 2) * (ea[i], eb[j])
    return edge_a + gap * axis + cross_at[0] * ra[:, i] - cross_at[1] * rb[:, j] - edge_b


def touching_vertex_face(rng, size, gap):
    """B's lowest vertex sits on a face of A."""
    qa, qb = random_quaternion(rng), random_quaternion(rng)
    ea, eb = extents_of(rng, size), extents_of(rng, size)
    ra, rb = matrix(qa), matrix(qb)
    i = rng.integers(3)
    u = ra[:, i] * rng.choice((-1.0, 1.0))
    on_face = ra @ (rng.uniform(-0.9, 0.9, 3) * ea * (np.arange(3) != i)) + ea[i] * u
    return qa, ea, qb, eb, on_face + gap * u - support_offset(rb, eb, -u)


def touching_vertices(rng, size, gap):
    """Put a vertex of B against a vertex of A, along A's diagonal there."""
    qa, qb = random_quaternion(rng), random_quaternion(rng)
    ea, eb = extents_of(rng, size), extents_of(rng, size)
    ra, rb = matrix(qa), matrix(qb)
    corner = signs(rng)
    u = ra @ (corner / math.sqrt(3.0))
    return qa, ea, qb, eb, ra @ (corner * ea) + gap * u - support_offset(rb, eb, -u)


def near_parallel(rng, size, gap):
    """Turn an edge of B by 1e-12 to 1e-3 rad from an edge of A.

    Either the two edges face each other (their edge×edge axis is the only separating one for
    gaps below about size × angle), or B is placed against a face, edge or vertex of A.
    """
    qa, ea, eb = random_quaternion(rng), extents_of(rng, size), extents_of(rng, size)
    i = rng.integers(3)
    turn = axis_angle(np.eye(3)[i], rng.choice((0.0, 0.5 * math.pi, rng.uniform(0, 2 * math.pi))))
    tilt = axis_angle(random_unit(rng), 10.0 ** rng.uniform(-12, -3))
    qb = multiply(multiply(qa, turn), tilt)
    if rng.uniform() < 0.5:
        return qa, ea, qb, eb, crossing_edges_offset(rng, qa, ea, qb, eb, gap, i, i)
    ra = matrix(qa)
    feature = signs(rng) * (rng.permutation(3) < rng.integers(1, 4))  # face, edge or vertex
    u = ra @ feature / np.linalg.norm(feature)
    lateral = perpendicular(rng, u, 0.3 * min(ea.min(), eb.min()))
    return qa, ea, qb, eb, place_on_ray(qa, ea, qb, eb, lateral, u, gap)


def crossing_edges(rng, size, gap):
    """Push crossing edges into each other so that an edge×edge axis has the least overlap.

    The referee decides; pairs where it is not are drawn again.
    """
    qa, qb = random_quaternion(rng), random_quaternion(rng)
    ea, eb = extents_of(rng, size), extents_of(rng, size)
    overlap = -abs(gap) if gap else -1e-4 * size
    return qa, ea, qb, eb, crossing_edges_offset(rng, qa, ea, qb, eb, overlap)


def plates_needles(rng, size, gap):
    """Plates (one half extent 1e-6 of the size or exactly 0), needles (two), points (three)."""
    qa, qb = random_quaternion(rng), random_quaternion(rng)
    ea, eb = extents_of(rng, size), extents_of(rng, size)
    for e in (ea, eb):
        thin = rng.permutation(3)[:rng.integers(0, 4)]
        e[thin] = rng.choice((0.0, 1e-6 * size))
    if rng.uniform() < 0.5:
        return qa, ea, qb, eb, crossing_edges_offset(rng, qa, ea, qb, eb, gap,
                                                     int(np.argmax(ea)), int(np.argmax(eb)))
    u = random_unit(rng)
    lateral = perpendicular(rng, u, 0.3 * size)
    return qa, ea, qb, eb, place_on_ray(qa, ea, qb, eb, lateral, u, gap)


def contained(rng, size, gap):
    """B lies inside A (sometimes the same box, or concentric)."""
    qa, ea = random_quaternion(rng), extents_of(rng, size)
    kind = rng.integers(4)
    if kind == 0:
        return qa, ea, qa.copy(), ea.copy(), np.zeros(3)
    qb = random_quaternion(rng)
    ra, rb = matrix(qa), matrix(qb)
    eb = ea.min() * rng.uniform(0.05, 0.5, 3)
    reach = np.abs(ra.T @ rb) @ eb          # B's half extents along A's axes
    room = np.maximum(ea - reach, 0.0)
    local = np.zeros(3) if kind == 1 else room * rng.uniform(-1.0, 1.0, 3)
    return qa, ea, qb, eb, ra @ local


def random_pairs(rng, size, gap):
    """Any orientations and extents (1:20), B's centre anywhere up to 3 sizes away."""
    qa, qb = random_quaternion(rng), random_quaternion(rng)
    ea, eb = size * rng.uniform(0.05, 1.0, 3), size * rng.uniform(0.05, 1.0, 3)
    return qa, ea, qb, eb, random_unit(rng) * rng.uniform(0, 3 * size)


def quaternion_norm(rng, size, gap):
    """Take a touching case and turn its quaternions off unit norm by up to 1e-3, or negate."""
    case = CLASSES[rng.choice(('touching_faces', 'touching_edges', 'touching_vertex_face',
                               'near_parallel'))](rng, size, gap)
    qa, ea, qb, eb, t = case
    for q in (qa, qb):
        q *= rng.choice((-1.0, 1.0)) * (1.0 + rng.choice((-1.0, 1.0))
                                        * 10.0 ** rng.uniform(-12, -3.05))
    return qa, ea, qb, eb, t


CLASSES = {
    'touching_faces': touching_faces,
    'touching_edges': touching_edges,
    'touching_vertex_face': touching_vertex_face,
    'touching_vertices': touching_vertices,
    'near_parallel': near_parallel,
    'crossing_edges': crossing_edges,
    'plates_needles': plates_needles,
    'contained': contained,
    'quaternion_norm': quaternion_norm,
    'random_pairs': random_pairs,
}


def draw_cases(classes, name, count, seed, judge, sizes=SIZES, gaps=GAPS, offsets=OFFSETS):
    """Return ``count`` items ``judge(case)`` of class ``name`` (None: draw again).

    Each case is at a random size, gap (× size) and offset from the origin drawn from
    ``sizes``, ``gaps`` and ``offsets``; test_distance.py draws its classes the same way.
    """
    rng = np.random.default_rng([seed, list(classes).index(name)])
    items = []
    while len(items) < count:
        size = rng.choice(sizes)
        made = classes[name](rng, size, rng.choice(gaps) * size)
        if made[-1] is None:
            continue
        qa, ea, qb, eb, t = made
        center_a = rng.choice(offsets) * random_unit(rng)
        item = judge(Case(np.r_[center_a, qa], ea, np.r_[center_a + t, qb], eb))
        if item is not None:
            items.append(item)
    return items


def generate(name, count, seed):
    """``count`` cases of class ``name``, each at a random size, gap and offset."""
    def judge(case):
        edges_wanted = name == 'crossing_edges'
        return None if edges_wanted and exact_sat(*case).best.kind != 'edge' else case
    return draw_cases(CLASSES, name, count, seed, judge)


# ---------------------------------------------------------------- running and checking

def run_kernel(cases, collide=None):
    """Run ``collide_pairs`` on the cases through the real pose → box path (obb.set_boxes)."""
    collide = collide or sat.collide_pairs
    boxes = Boxes(2 * len(cases))
    poses = np.array([p for case in cases for p in (case.pose_a, case.pose_b)])
    halves = np.array([h for case in cases for h in (case.half_a, case.half_b)])
    set_boxes(boxes, 0, poses, halves)
    pairs = np.arange(2 * len(cases)).reshape(-1, 2)
    return collide(boxes.centers, boxes.rotations, boxes.half_extents, boxes.radii, pairs)


def size_of(case):
    return max(case.half_a.max(), case.half_b.max())


def check(case, status, depth, normal, point, tolerance, edge_normal_ulps=EDGE_NORMAL_ULPS):
    """Return the list of failed checks for one pair, and whether it was within tolerance."""
    verdict = exact_sat(*case)
    near_touching = abs(verdict.separation) <= Decimal(tolerance)
    if status == sat.INVALID:
        return ['invalid'], near_touching
    if not near_touching and (status == sat.COLLIDING) != verdict.colliding:
        return ['verdict'], near_touching
    if not (status == sat.COLLIDING and verdict.colliding):
        return [], near_touching
    failed = []
    accuracy = Decimal(RELATIVE_ACCURACY * size_of(case))
    if abs(Decimal(depth) - verdict.depth) > accuracy:
        failed.append('depth')
    if not (abs(np.linalg.norm(normal) - 1.0) < 1e-12
            and abs(separation_along(*case, normal) + Decimal(depth)) <= accuracy
            and signed_offset_along(case.pose_a, case.pose_b, normal) >= -accuracy
            and any(axis.separation >= verdict.separation - accuracy
                    and np.linalg.norm(np.subtract(axis.normal, normal))
                    <= RELATIVE_ACCURACY + edge_normal_ulps * EPS / axis.sine
                    for axis in verdict.axes)):
        failed.append('normal')
    # The point is in world coordinates: far from the origin, their rounding adds up to
    # eps·|c| (0.1 nm at 1e6 m) however exact the kernel is.
    representable = Decimal(4 * EPS * np.abs(case.pose_a[:3]).max())
    if max(distance_outside(point, case.pose_a, case.half_a),
           distance_outside(point, case.pose_b, case.half_b)) > accuracy + representable:
        failed.append('point')
    return failed, near_touching


def failures(name, count, seed=0, collide=None, tolerance=None,
             edge_normal_ulps=EDGE_NORMAL_ULPS):
    """Count the failed checks over ``count`` cases of class ``name``.

    Also counted: 'near_touching', the pairs within the touching tolerance, and 'cases'.
    """
    tolerance = tolerance or sat.touch_tolerance
    cases = generate(name, count, seed)
    status, depth, normal, point, _ = run_kernel(cases, collide)
    counts = Counter(cases=len(cases))
    for k, case in enumerate(cases):
        failed, near = check(case, status[k], depth[k], normal[k], point[k],
                             tolerance(case.pose_a[:3], case.pose_b[:3],
                                       case.half_a, case.half_b), edge_normal_ulps)
        counts.update(failed)
        counts['near_touching'] += near
    return counts


def assert_no_failures(name, count, seed):
    counts = failures(name, count, seed)
    assert set(counts) <= {'cases', 'near_touching'}, counts


@pytest.mark.parametrize('name', CLASSES)
def test_stress_subset(name):
    assert_no_failures(name, FAST_CASES, seed=1)


@pytest.mark.slow
@pytest.mark.parametrize('name', CLASSES)
def test_stress(name):
    assert_no_failures(name, SLOW_CASES, seed=2)


def non_finite_statuses(count, seed):
    """Poison one random entry of one box of each of ``count`` stress pairs with NaN or ±Inf.

    Returns the statuses without and with the sphere prefilter, and the untouched statuses.
    The arrays go to the kernel directly: set_boxes would refuse them.
    """
    rng = np.random.default_rng(seed)
    cases = [case for name in CLASSES for case in generate(name, count // len(CLASSES) + 1,
                                                           seed)][:count]
    boxes = Boxes(2 * len(cases))
    set_boxes(boxes, 0, np.array([p for c in cases for p in (c.pose_a, c.pose_b)]),
              np.array([h for c in cases for h in (c.half_a, c.half_b)]))
    arrays = [boxes.centers, boxes.rotations, boxes.half_extents, boxes.radii]
    pairs = np.arange(2 * len(cases)).reshape(-1, 2)
    clean = sat.collide_pairs(*arrays, pairs)[0]
    for k in range(len(cases)):
        box = 2 * k + rng.integers(2)
        array = arrays[rng.integers(3)]  # radii are derived: a NaN there only skips the test
        array[(box,) + tuple(rng.integers(3, size=array.ndim - 1))] = rng.choice(
            (np.nan, np.inf, -np.inf))
    return (sat.collide_pairs(*arrays, pairs, False)[0],
            sat.collide_pairs(*arrays, pairs, True)[0], clean)


@pytest.mark.parametrize('count', [pytest.param(100), pytest.param(2000, marks=pytest.mark.slow)])
def test_non_finite_input_is_always_invalid(count):
    plain, prefiltered, clean = non_finite_statuses(count, seed=4)
    assert (clean != sat.INVALID).all()
    assert (plain == sat.INVALID).all()
    assert (prefiltered == sat.INVALID).all()


def pair_tolerance(center_a, center_b, half_a, half_b):
    """Return the documented touching tolerance (sat.py), restated for the report below."""
    scale = np.sum(half_a) + np.sum(half_b) + np.sum(np.abs(np.subtract(center_b, center_a)))
    return TIE_ULPS * EPS * scale


def initial_tolerance(center_a, center_b, half_a, half_b):
    """Return the tolerance the first sat.py documented (centres' distance from the origin)."""
    scale = np.abs(center_a).max() + np.abs(center_b).max() + np.sum(half_a) + np.sum(half_b)
    return TIE_ULPS * EPS * scale


def test_the_restated_tolerance_is_the_documented_one():
    rng = np.random.default_rng(0)
    for _ in range(100):
        args = (rng.normal(size=3) * 1e3, rng.normal(size=3), rng.uniform(0, 2, 3),
                rng.uniform(0, 2, 3))
        assert pair_tolerance(*args) == pytest.approx(sat.touch_tolerance(*args), rel=1e-15)


def report(arguments):
    """Print failure counts per class (see the module docstring).

    ``[cases] [--initial-tolerance] [--strict]``: the first sat.py's tolerance instead of the
    documented one; no eps / sin θ allowance for edge×edge normals. Runs against whichever
    collision_node is first on the path, e.g. an older one via PYTHONPATH.
    """
    count = int(arguments[0]) if arguments and arguments[0].isdigit() else SLOW_CASES
    tolerance = initial_tolerance if '--initial-tolerance' in arguments else pair_tolerance
    edge_normal_ulps = 0.0 if '--strict' in arguments else EDGE_NORMAL_ULPS
    checks = ('verdict', 'depth', 'normal', 'point', 'invalid')
    print('%-22s %6s %6s ' % ('class', 'cases', 'near') + ' '.join('%7s' % c for c in checks))
    for name in CLASSES:
        counts = failures(name, count, seed=2, tolerance=tolerance,
                          edge_normal_ulps=edge_normal_ulps)
        print('%-22s %6d %6d ' % (name, counts['cases'], counts['near_touching'])
              + ' '.join('%7d' % counts[c] for c in checks), flush=True)


if __name__ == '__main__':
    report(sys.argv[1:])
