"""The SAT kernel on analytic cases, bad input and its symmetries (property tests).

Expected values in the analytic cases are derived by hand in the comments, not taken from
the code; the property tests use the exact referee (exact_sat.py) only to tell a legitimate
near-tie from a bug.
"""
from decimal import Decimal
import math

from exact_sat import distance_outside, exact_sat
from hypothesis import assume, example, given, HealthCheck, settings, strategies as st
import numpy as np
import pytest
from test_sat_stress import axis_angle, Case, matrix, multiply, run_kernel

from collision_node import World
from collision_node.pipeline import sat
from collision_node.pipeline.obb import Boxes, EPS, set_boxes

IDENTITY = (0.0, 0.0, 0.0, 1.0)
SQRT2 = math.sqrt(2.0)


def pose(position, quaternion=IDENTITY):
    return np.r_[np.asarray(position, float), np.asarray(quaternion, float)]


def collide(pose_a, half_a, pose_b, half_b):
    """Return (status, depth, normal, point) of one pair, through set_boxes and the SAT."""
    status, depth, normal, point, _ = run_kernel(
        [Case(pose_a, np.asarray(half_a, float), pose_b, np.asarray(half_b, float))])
    return status[0], depth[0], normal[0], point[0]


def assert_contact(result, depth, normal, point, accuracy=1e-12):
    status, got_depth, got_normal, got_point = result
    assert status == sat.COLLIDING
    assert got_depth == pytest.approx(depth, abs=accuracy)
    np.testing.assert_allclose(got_normal, normal, atol=accuracy)
    np.testing.assert_allclose(got_point, point, atol=accuracy)


# ---------------------------------------------------------------- analytic cases

@pytest.mark.parametrize('offset', [0.0, 1e3, 1e6])
def test_touching_faces_collide_with_zero_depth(offset):
    # Unit cubes (half extent 1) with centres 2 apart along x share the face x = 1.
    base = np.array([offset, -offset, offset])
    result = collide(pose(base), (1, 1, 1), pose(base + (2, 0, 0)), (1, 1, 1))
    assert_contact(result, 0.0, (1, 0, 0), base + (1, 0, 0), accuracy=1e-12 * max(1, offset))


@pytest.mark.parametrize('gap', [1e-9, 1e-6, 1e-3, 0.5])
def test_known_gap_separates(gap):
    status, *_ = collide(pose((0, 0, 0)), (1, 1, 1), pose((2 + gap, 0.3, -0.2)), (1, 1, 1))
    assert status == sat.SEPARATED


@pytest.mark.parametrize('depth', [1e-9, 1e-6, 1e-3, 0.5])
def test_known_overlap_gives_depth_normal_and_point(depth):
    # B (half 1) sits at x = 2 - depth, shifted by (0.3, -0.2) sideways: it overlaps A along x
    # by `depth` (y and z overlap by ~1.7). The contact point is on B's face centre line
    # clamped into A, i.e. (., 0.3, -0.2), halfway through the overlap: x = 1 - depth / 2.
    result = collide(pose((0, 0, 0)), (1, 1, 1), pose((2 - depth, 0.3, -0.2)), (1, 1, 1))
    assert_contact(result, depth, (1, 0, 0), (1 - depth / 2, 0.3, -0.2))


def test_normal_points_from_a_to_b():
    result = collide(pose((0, 0, 0)), (1, 1, 1), pose((0, 0, -1.5)), (1, 1, 1))
    assert_contact(result, 0.5, (0, 0, -1), (0, 0, -0.75))


@pytest.mark.parametrize('depth', [0.0, 1e-6, 0.25])
def test_box_turned_45_degrees_touches_with_its_edge(depth):
    # B (half 1) turned 45° about z reaches sqrt(2) along x with its edge (x, 0, z). At a
    # distance 1 + sqrt(2) - depth it enters A's face x = 1 by `depth`; B's face axes see an
    # overlap of (1 + depth) / sqrt(2), and the edge axes coincide with face axes.
    turned = axis_angle((0, 0, 1), math.pi / 4)
    result = collide(pose((0, 0, 0)), (1, 1, 1), pose((1 + SQRT2 - depth, 0, 0), turned),
                     (1, 1, 1))
    assert_contact(result, depth, (1, 0, 0), (1 - depth / 2, 0, 0))
    status, *_ = collide(pose((0, 0, 0)), (1, 1, 1),
                         pose((1 + SQRT2 + 1e-9, 0, 0), turned), (1, 1, 1))
    assert status == sat.SEPARATED


@pytest.mark.parametrize('depth', [1e-6, 0.1])
def test_edge_edge_crossing_has_known_depth_normal_and_point(depth):
    # A: unit cube (half 1); its vertical edge (1, 1, z) supports n = (1, 1, 0) / sqrt(2)
    # at n·x = sqrt(2). B (half 1) turned -45° about z, then 45° about its own x axis
    # (1, -1, 0)/sqrt(2): its cross-section across that axis is a diamond whose vertex edge,
    # along (1, -1, 0)/sqrt(2), points along -n at sqrt(2) from B's centre. With B's centre at
    # s·n, s = 2 sqrt(2) - depth, that edge passes through (1 - depth/sqrt(2)) (1, 1, 0) and
    # crosses A's edge at (1, 1, 0) with an overlap of `depth` along n. Face axes overlap by
    # at least sqrt(2)/2 + depth/sqrt(2) (worked out in the tests' notes), so n has the
    # least overlap; the point is the midpoint of the two crossing points.
    turned = multiply(axis_angle((0, 0, 1), -math.pi / 4), axis_angle((1, 0, 0), math.pi / 4))
    n = np.array([1.0, 1.0, 0.0]) / SQRT2
    result = collide(pose((0, 0, 0)), (1, 1, 1), pose((2 * SQRT2 - depth) * n, turned),
                     (1, 1, 1))
    assert_contact(result, depth, n, (1 - depth / (2 * SQRT2)) * np.array([1, 1, 0]))
    status, *_ = collide(pose((0, 0, 0)), (1, 1, 1), pose((2 * SQRT2 + 1e-9) * n, turned),
                         (1, 1, 1))
    assert status == sat.SEPARATED


def test_contained_box_is_pushed_out_through_the_nearest_side():
    # B (half 0.5) inside A (half 2) at x = 0.5: leaving along +x takes 2 + 0.5 - 0.5 = 2,
    # along y or z 2.5, along -x 3. The point is the middle of B's chord along x: B's centre.
    result = collide(pose((0, 0, 0)), (2, 2, 2), pose((0.5, 0, 0)), (0.5, 0.5, 0.5))
    assert_contact(result, 2.0, (1, 0, 0), (0.5, 0, 0))


def test_turned_contained_box_point_is_inside_it():
    # B turned 45° about z (reach 0.5 sqrt(2) along x and y) at (0.3, 0.2, 0) in A (half 2):
    # the least way out is +x, 2 + 0.5 sqrt(2) - 0.3.
    turned = axis_angle((0, 0, 1), math.pi / 4)
    pose_b, half_b = pose((0.3, 0.2, 0), turned), np.array([0.5, 0.5, 0.5])
    status, depth, normal, point = collide(pose((0, 0, 0)), (2, 2, 2), pose_b, half_b)
    assert status == sat.COLLIDING
    assert depth == pytest.approx(2 + 0.5 * SQRT2 - 0.3, abs=1e-12)
    np.testing.assert_allclose(normal, (1, 0, 0), atol=1e-12)
    assert distance_outside(point, pose_b, half_b) == 0


def test_identical_boxes_overlap_by_their_full_width():
    result = collide(pose((1, 2, 3)), (0.5, 0.2, 0.1), pose((1, 2, 3)), (0.5, 0.2, 0.1))
    # t = 0: every face axis overlaps by twice the half extent; z (0.2) is the least.
    assert result[0] == sat.COLLIDING
    assert result[1] == pytest.approx(0.2, abs=1e-15)
    assert abs(result[2][2]) == pytest.approx(1.0)


@pytest.mark.parametrize('thickness', [0.0, 1e-6])
def test_plates_crossing_at_right_angles(thickness):
    # Plate A in the xy plane (half 1 x 1 x thickness); plate B turned 90° about x lies in
    # the xz plane (world half extents 1, thickness, 1) centred at (0, 0.9, 0). Along y they
    # overlap by 1 - (0.9 - thickness), along z by 1 + thickness, along x by 2: B is pushed
    # out along +y. B's face towards A is the anchor; the chord along y through it is B's
    # thickness, whose middle is B's mid-plane y = 0.9.
    result = collide(pose((0, 0, 0)), (1, 1, thickness),
                     pose((0, 0.9, 0), axis_angle((1, 0, 0), math.pi / 2)), (1, 1, thickness))
    assert_contact(result, 0.1 + thickness, (0, 1, 0), (0, 0.9, 0))


def test_points_and_needles():
    # Two zero-size boxes at one point touch; a needle through a box collides.
    assert collide(pose((1, 1, 1)), (0, 0, 0), pose((1, 1, 1)), (0, 0, 0))[0] == sat.COLLIDING
    assert collide(pose((1, 1, 1)), (0, 0, 0), pose((1, 1, 1 + 1e-12)),
                   (0, 0, 0))[0] == sat.SEPARATED
    needle = collide(pose((0, 0, 0)), (1, 1, 1), pose((0.5, 0.5, 0.5), axis_angle((1, 1, 0), 1.0)),
                     (0, 0, 3))
    assert needle[0] == sat.COLLIDING


# ---------------------------------------------------------------- invalid input

def nan_arrays(n=4):
    return (np.full((n, 3), np.nan), np.full((n, 3, 3), np.nan), np.full((n, 3), np.nan),
            np.full(n, np.nan))


@pytest.mark.parametrize('prefilter', [False, True])
def test_nan_arrays_are_invalid(prefilter):
    status, *_ = sat.collide_pairs(*nan_arrays(), np.array([[0, 1], [2, 3], [1, 2]]),
                                   prefilter)
    assert (status == sat.INVALID).all()


def valid_boxes():
    """Four unit cubes: 0 and 1 touch, 2 and 3 are far from everything."""
    boxes = Boxes(4)
    set_boxes(boxes, 0, np.array([pose((0, 0, 0)), pose((1.5, 0, 0)), pose((50, 0, 0)),
                                  pose((0, 80, 0))]), (1, 1, 1))
    return [boxes.centers, boxes.rotations, boxes.half_extents, boxes.radii]


@pytest.mark.parametrize('array, index', [(0, (1, 2)), (1, (1, 2, 0)), (2, (1, 0)),
                                          (0, (2, 0)), (1, (2, 1, 1)), (2, (2, 2))])
@pytest.mark.parametrize('bad', [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize('prefilter', [False, True])
def test_one_non_finite_value_makes_its_pairs_invalid(array, index, bad, prefilter):
    # Box 1 overlaps box 0; box 2 is far away, so the sphere test would reject its pairs
    # without looking at its rotation or extents.
    arrays = valid_boxes()
    arrays[array][index] = bad
    pairs = np.array([[0, 1], [0, 2], [1, 2], [0, 3]])
    status, *_ = sat.collide_pairs(*arrays, pairs, prefilter)
    touched = [index[0] in pair for pair in pairs]
    assert (status[touched] == sat.INVALID).all()
    assert status[3] == sat.SEPARATED


def test_the_sphere_test_rejects_far_pairs_without_the_sat():
    status, _, _, _, sat_tests = sat.collide_pairs(*valid_boxes(),
                                                   np.array([[0, 1], [0, 2], [2, 3]]), True)
    assert list(status) == [sat.COLLIDING, sat.SEPARATED, sat.SEPARATED]
    assert sat_tests == 1


def test_pair_indices_out_of_range_are_refused():
    with pytest.raises(ValueError, match='pair indices'):
        sat.collide_pairs(*valid_boxes(), np.array([[0, 4]]))
    with pytest.raises(ValueError, match='pair indices'):
        sat.collide_pairs(*valid_boxes(), np.array([[-1, 0]]))


def test_no_pairs():
    status, depth, normal, point, sat_tests = sat.collide_pairs(*valid_boxes(),
                                                                np.zeros((0, 2), int))
    assert status.shape == (0,) and normal.shape == (0, 3) and sat_tests == 0


@pytest.mark.parametrize('field, value, reason', [
    (0, np.nan, 'NaN or Inf'), (2, np.inf, 'NaN or Inf'), (5, -np.inf, 'NaN or Inf'),
    (6, np.nan, 'NaN or Inf'), ('zero quaternion', 0.0, 'quaternion'),
    ('half extent', -1.0, 'half extents')])
def test_world_rejects_a_non_finite_pose_naming_the_body(field, value, reason):
    poses = np.array([pose((0, 0, 0)), pose((0.5, 0, 0)), pose((5, 0, 0))])
    half_extents = np.ones((3, 3))
    if field == 'zero quaternion':
        poses[1, 3:] = 0.0
    elif field == 'half extent':
        half_extents[1, 2] = value
    else:
        poses[1, field] = value
    world = World(broad_phase='brute_force')
    with pytest.raises(ValueError, match='body 1: .*' + reason):
        world.step(poses, half_extents)


def test_world_names_the_first_bad_body_in_random_poses():
    rng = np.random.default_rng(9)
    world = World(broad_phase='brute_force')
    good = np.c_[rng.uniform(-2, 2, (50, 3)), np.tile(IDENTITY, (50, 1))]
    world.step(good, (0.5, 0.5, 0.5))
    for _ in range(100):
        poses = good.copy()
        bad = np.sort(rng.choice(50, size=rng.integers(1, 4), replace=False))
        for body in bad:
            poses[body, rng.integers(7)] = rng.choice((np.nan, np.inf, -np.inf))
        with pytest.raises(ValueError, match='body %d: pose has a NaN or Inf' % bad[0]):
            world.step(poses, (0.5, 0.5, 0.5))


# ---------------------------------------------------------------- q against -q, off-unit q

def test_negated_quaternion_gives_bitwise_identical_results():
    rng = np.random.default_rng(7)
    cases, negated = [], []
    for _ in range(200):
        qa, qb = rng.normal(size=4), rng.normal(size=4)
        qa, qb = qa / np.linalg.norm(qa), qb / np.linalg.norm(qb)
        pa, pb = pose(rng.normal(size=3), qa), pose(rng.normal(size=3), qb)
        ha, hb = rng.uniform(0.1, 1, 3), rng.uniform(0.1, 1, 3)
        cases.append(Case(pa, ha, pb, hb))
        negated.append(Case(np.r_[pa[:3], -qa], ha, np.r_[pb[:3], -qb], hb))
    status, *results = run_kernel(cases)[:4]
    status_negated, *results_negated = run_kernel(negated)[:4]
    np.testing.assert_array_equal(status_negated, status)
    hit = status == sat.COLLIDING
    for got, expected in zip(results_negated, results):  # depth, normal, point
        np.testing.assert_array_equal(got[hit], expected[hit])
    assert 20 < hit.sum() < 180  # both verdicts occur


# ---------------------------------------------------------------- property tests

coordinates = st.floats(-3.0, 3.0)
half_extent = st.floats(0.01, 2.0)
quaternion = st.tuples(*[st.floats(-1.0, 1.0)] * 4).filter(
    lambda q: 0.1 < np.linalg.norm(q)).map(lambda q: np.array(q) / np.linalg.norm(q))
box = st.tuples(st.tuples(coordinates, coordinates, coordinates), quaternion,
                st.tuples(half_extent, half_extent, half_extent)).map(
    lambda b: (pose(b[0], b[1]), np.array(b[2])))
PROPERTY_SETTINGS = settings(max_examples=150, deadline=None, derandomize=True)


def pair_size(half_a, half_b):
    return max(np.max(half_a), np.max(half_b))


def near_touching(case):
    """Tell whether the exact SAT separation is within the touching tolerance."""
    tolerance = sat.touch_tolerance(case.pose_a[:3], case.pose_b[:3], case.half_a, case.half_b)
    return abs(exact_sat(*case).separation) <= Decimal(tolerance)


def unique_least_axis(case):
    """Tell whether no other axis (not parallel) overlaps within 1e-9 of the size of it."""
    verdict = exact_sat(*case)
    margin = Decimal(1e-9 * pair_size(case.half_a, case.half_b))
    return not any(
        axis.separation >= verdict.separation - margin
        and abs(abs(np.dot(axis.normal, verdict.best.normal)) - 1.0) > 1e-9
        for axis in verdict.axes)


@PROPERTY_SETTINGS
@given(box, box)
def test_swapping_a_and_b(a, b):
    forward, backward = Case(*a, *b), Case(*b, *a)
    status, depth, normal, _ = [x[0] for x in run_kernel([forward])[:4]]
    status_back, depth_back, normal_back, _ = [x[0] for x in run_kernel([backward])[:4]]
    if status != status_back:
        assert near_touching(forward)
        return
    if status == sat.COLLIDING:
        assert depth_back == pytest.approx(depth, abs=1e-9 * pair_size(a[1], b[1]))
        if unique_least_axis(forward):
            # Concentric along the normal (e.g. the same centre): its sign is arbitrary.
            sign = -1.0 if abs(np.dot(b[0][:3] - a[0][:3], normal)) > 1e-12 else np.sign(
                np.dot(normal_back, normal))
            np.testing.assert_allclose(normal_back, sign * normal, atol=1e-9)


rigid = st.tuples(quaternion, st.tuples(*[st.floats(-1e3, 1e3)] * 3))


def moved(case, turn, shift):
    """Return the case with both boxes turned by ``turn`` about the origin, then shifted."""
    rotation = matrix(turn)
    return Case(*[np.r_[rotation @ p[:3] + shift, multiply(turn, p[3:])] if k % 2 == 0 else p
                  for k, p in enumerate(case)])


@PROPERTY_SETTINGS
@given(box, box, rigid)
@example(a=(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 2.0 / math.sqrt(5.0), 1.0 / math.sqrt(5.0)]),
            np.array([1.0, 1.0, 1.0])),
         b=(np.array([2.2853465932811716e-77, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]),
            np.array([2.0, 1.0, 2.0])),
         motion=(np.array([0.0, 0.0, 0.0, 1.0]), (1.0, 0.0, 0.0)))  # found by hypothesis
def test_a_common_rigid_motion_changes_nothing(a, b, motion):
    case = Case(*a, *b)
    other = moved(case, motion[0], np.array(motion[1]))
    results = run_kernel([case, other])
    status, depth = results[0], results[1]
    if status[0] != status[1]:
        assert near_touching(case) or near_touching(other)
        return
    if status[0] == sat.COLLIDING:
        # The motion rounds the inputs by ~eps of the new coordinates (up to ~1e3).
        assert depth[1] == pytest.approx(depth[0], abs=1e-9 * pair_size(a[1], b[1]))
        if unique_least_axis(case):
            turned = matrix(motion[0]) @ results[2][0]
            # Concentric along the normal to within the motion's rounding (the centres 1e-77
            # apart, say): its sign is arbitrary, as in test_swapping_a_and_b.
            coordinates = np.abs(np.r_[case.pose_a[:3], case.pose_b[:3], other.pose_a[:3],
                                       other.pose_b[:3]])
            if abs(np.dot(b[0][:3] - a[0][:3], results[2][0])) <= 1e-12 * max(
                    1.0, np.max(coordinates)):
                turned *= np.sign(np.dot(results[2][1], turned))
            np.testing.assert_allclose(results[2][1], turned, atol=1e-9)


def push_margin(case):
    """Return ε for moving B along the normal.

    Well above the touching tolerance and the rounding of the moved centre (B's coordinates
    are rounded to float64 after the move).
    """
    tolerance = sat.touch_tolerance(case.pose_a[:3], case.pose_b[:3], case.half_a, case.half_b)
    return 64 * (tolerance + EPS * np.abs(case.pose_b[:3]).max())


# Only colliding pairs can be pushed apart, so most drawn pairs are filtered out by design.
@settings(PROPERTY_SETTINGS, suppress_health_check=[HealthCheck.filter_too_much])
@given(box, box)
def test_pushing_b_by_the_depth_separates(a, b):
    case = Case(*a, *b)
    status, depth, normal, _ = [x[0] for x in run_kernel([case])[:4]]
    assume(status == sat.COLLIDING)
    epsilon = push_margin(case)
    out = case._replace(pose_b=np.r_[case.pose_b[:3] + (depth + epsilon) * normal,
                                     case.pose_b[3:]])
    still_in = case._replace(pose_b=np.r_[case.pose_b[:3] + (depth - epsilon) * normal,
                                          case.pose_b[3:]])
    assume(depth > epsilon)
    assert list(run_kernel([out, still_in])[0]) == [sat.SEPARATED, sat.COLLIDING]


@PROPERTY_SETTINGS
@given(box, box, st.tuples(*[st.floats(0.0, 1.0)] * 3), st.booleans())
def test_shrinking_a_box_never_creates_a_collision(a, b, factors, shrink_a):
    case = Case(*a, *b)
    status = run_kernel([case])[0][0]
    assume(status == sat.SEPARATED and not near_touching(case))
    if shrink_a:
        smaller = case._replace(half_a=case.half_a * factors)
    else:
        smaller = case._replace(half_b=case.half_b * factors)
    assert run_kernel([smaller])[0][0] == sat.SEPARATED


@PROPERTY_SETTINGS
@given(box, box)
def test_contact_point_lies_in_both_boxes(a, b):
    case = Case(*a, *b)
    status, depth, _, point = [x[0] for x in run_kernel([case])[:4]]
    assume(status == sat.COLLIDING)
    accuracy = Decimal(1e-12 * pair_size(a[1], b[1]))
    assert distance_outside(point, *a) <= accuracy
    assert distance_outside(point, *b) <= accuracy


def benchmark(bodies=10000, repeats=30):
    """Print SAT throughput (ns per pair) on the candidate pairs of a uniform scene.

    The pairs are those whose AABBs overlap (the brute-force broad phase), as the World
    hands them over, and their colliding and separated parts.
    """
    import time

    from collision_node.pipeline import scenes
    from collision_node.pipeline.broadphase.brute_force import BruteForce

    scene = scenes.uniform(bodies, seed=0)
    poses = np.concatenate([scene.static_poses, scene.dynamic_poses(0.0)])
    half_extents = np.concatenate([scene.static_half_extents, scene.dynamic_half_extents])
    boxes = Boxes(len(poses))
    set_boxes(boxes, 0, poses, half_extents)
    n_static = len(scene.static_poses)
    pairs = BruteForce().find_pairs(boxes, n_static, len(poses) - n_static)[0].copy()
    arrays = (boxes.centers, boxes.rotations, boxes.half_extents, boxes.radii)
    status = sat.collide_pairs(*arrays, pairs)[0]
    print('%d bodies, %d candidate pairs (%d colliding)'
          % (bodies, len(pairs), (status == sat.COLLIDING).sum()))
    for mix, chosen in (('candidates', pairs), ('colliding', pairs[status == sat.COLLIDING]),
                        ('separated', pairs[status == sat.SEPARATED])):
        for prefilter in (False, True):
            best = np.inf
            for _ in range(repeats):
                start = time.perf_counter()
                sat.collide_pairs(*arrays, chosen, prefilter)
                best = min(best, time.perf_counter() - start)
            print('%-10s sphere prefilter %-5s %6.1f ns/pair %7.3f ms'
                  % (mix, prefilter, 1e9 * best / len(chosen), 1e3 * best))


if __name__ == '__main__':
    benchmark()
