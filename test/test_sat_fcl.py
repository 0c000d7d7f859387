"""The SAT and the brute-force pipeline against python-fcl, an independent implementation.

python-fcl is a test-only dependency. ``fcl.Box`` takes full side lengths; its quaternions are
(w, x, y, z). Only verdicts are compared: FCL's box-box test (ODE's dBoxBox) biases its
normal toward face axes and overshoots the depth on edge contacts, so depth and normal are
checked against the exact referee instead (test_sat_stress.py).

Pairs on which the kernel and FCL disagree are allowed only within the touching tolerance
(sat.touch_tolerance, measured by the exact referee), and they are counted: the tests assert
how many there were, so an exclusion can never hide silently.
"""
from decimal import Decimal

from broadphase_reference import log_scale_half_extents, random_quaternions
from exact_sat import exact_sat
import fcl
import numpy as np
import pytest
from test_sat_stress import Case, CLASSES, generate, random_quaternion, run_kernel, size_of

from collision_node import World
from collision_node.pipeline import sat, scenes

# FCL's own box-box test adds a fixed epsilon to |R| (and a 5 % bias toward face axes): its
# verdict is only trusted farther than this fraction of the size from touching.
FCL_SLOP = 1e-6


def fcl_transform(pose):
    """Return the pose as an fcl.Transform: fcl wants (w, x, y, z), normalised."""
    x, y, z, qx, qy, qz, qw = pose
    q = np.array([qw, qx, qy, qz])
    return fcl.Transform(q / np.linalg.norm(q), np.array([x, y, z]))


def fcl_object(pose, half_extents):
    return fcl.CollisionObject(fcl.Box(*(2.0 * np.asarray(half_extents))), fcl_transform(pose))


def fcl_collides(case):
    result = fcl.CollisionResult()
    fcl.collide(fcl_object(case.pose_a, case.half_a), fcl_object(case.pose_b, case.half_b),
                fcl.CollisionRequest(), result)
    return result.is_collision


def near_touching(case):
    tolerance = sat.touch_tolerance(case.pose_a[:3], case.pose_b[:3], case.half_a, case.half_b)
    return abs(exact_sat(*case).separation) <= Decimal(tolerance)


def random_pairs(count, seed):
    """Return random pairs of 1e-3 to 1e3 m, about half colliding, at offsets up to 1e6 m."""
    rng = np.random.default_rng(seed)
    cases = []
    for _ in range(count):
        size = 10.0 ** rng.uniform(-3, 3)
        half_a, half_b = size * rng.uniform(0.05, 1, 3), size * rng.uniform(0.05, 1, 3)
        offset = rng.choice((0.0, 1e3, 1e6)) * rng.normal(size=3)
        direction = rng.normal(size=3)
        distance = rng.uniform(0, 1.2) * (np.linalg.norm(half_a) + np.linalg.norm(half_b))
        cases.append(Case(np.r_[offset, random_quaternion(rng)], half_a,
                          np.r_[offset + distance * direction / np.linalg.norm(direction),
                                random_quaternion(rng)], half_b))
    return cases


def test_random_pairs_agree_with_fcl():
    cases = random_pairs(3000, seed=11)
    status = run_kernel(cases)[0]
    assert not (status == sat.INVALID).any()
    colliding = status == sat.COLLIDING
    assert 0.3 < colliding.mean() < 0.7
    disagreements = [case for case, hit in zip(cases, colliding) if fcl_collides(case) != hit]
    assert all(near_touching(case) for case in disagreements)
    assert len(disagreements) == 0  # none excluded in practice


@pytest.mark.parametrize('name', CLASSES)
def test_stress_classes_agree_with_fcl_away_from_touching(name):
    # Degenerate pairs (touching, near-parallel, thin, contained...): the kernel must agree
    # with FCL wherever FCL itself is trustworthy (farther than FCL_SLOP from touching);
    # the exact referee covers the rest (test_sat_stress.py).
    cases = generate(name, 40, seed=3)
    status = run_kernel(cases)[0]
    checked = 0
    for case, got in zip(cases, status):
        if abs(exact_sat(*case).separation) > Decimal(FCL_SLOP * size_of(case)):
            checked += 1
            assert (got == sat.COLLIDING) == fcl_collides(case)
    assert checked > 0


def fcl_pairs(poses, half_extents, n_static):
    """Return the colliding pairs (row, row) from one fcl DynamicAABBTreeCollisionManager.

    Static-static pairs are left out; rows: statics first, as in the World.
    """
    geometries = [fcl.Box(*(2.0 * h)) for h in half_extents]
    objects = [fcl.CollisionObject(g, fcl_transform(p)) for g, p in zip(geometries, poses)]
    row_of = {id(g): k for k, g in enumerate(geometries)}
    manager = fcl.DynamicAABBTreeCollisionManager()
    manager.registerObjects(objects)
    manager.setup()
    data = fcl.CollisionData(request=fcl.CollisionRequest(num_max_contacts=10 ** 8))
    manager.collide(data, fcl.defaultCollisionCallback)
    pairs = {tuple(sorted((row_of[id(c.o1)], row_of[id(c.o2)]))) for c in data.result.contacts}
    return {pair for pair in pairs if pair[1] >= n_static}


def world_pairs(static_poses, static_half, dynamic_poses, dynamic_half):
    world = World(broad_phase='brute_force', sphere_prefilter=False)
    world.set_static(static_poses, static_half)
    contacts = world.step(dynamic_poses, dynamic_half).contacts
    n_static = len(static_poses)

    def row(ids, types):
        return np.where(types == 1, ids, n_static + ids.astype(np.int64))

    rows_a = row(contacts['id_a'], contacts['type_a'])
    rows_b = row(contacts['id_b'], contacts['type_b'])
    return {tuple(sorted(pair)) for pair in zip(rows_a.tolist(), rows_b.tolist())}


def resting_scene(n, seed):
    """Return boxes resting exactly on a static floor, on each other and side by side.

    Some are turned about the vertical: thousands of pairs touch exactly or within rounding.
    """
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(n / 2)))
    floor = np.array([[0.0, 0.0, -0.5, 0.0, 0.0, 0.0, 1.0]]), np.array([[50.0, 50.0, 0.5]])
    poses, halves = [], []
    for k in range(n):
        column, level = divmod(k, 2)
        x, y = 0.4 * (column % side), 0.4 * (column // side)
        half = np.array([0.2, 0.2, 0.1])
        turn = rng.choice((0.0, rng.uniform(0, 2 * np.pi)))
        poses.append([x, y, 0.1 + 0.2 * level, 0.0, 0.0, np.sin(turn / 2), np.cos(turn / 2)])
        halves.append(half)
    return floor, (np.array(poses), np.array(halves))


def compare_with_fcl(static, dynamic):
    """Return (pairs found, pairs excluded within the touching tolerance); assert the rest."""
    n_static = len(static[0])
    poses = np.concatenate([static[0], dynamic[0]])
    halves = np.concatenate([static[1], dynamic[1]])
    ours = world_pairs(static[0], static[1], dynamic[0], dynamic[1])
    theirs = fcl_pairs(poses, halves, n_static)
    excluded = 0
    for a, b in ours ^ theirs:
        case = Case(poses[a], halves[a], poses[b], halves[b])
        assert near_touching(case), (a, b, a < n_static, exact_sat(*case).separation)
        excluded += 1
    return len(ours), excluded


@pytest.mark.parametrize('make', [scenes.uniform, scenes.clustered])
def test_brute_force_world_agrees_with_fcl_on_random_scenes(make):
    scene = make(4000, seed=5)
    found, excluded = compare_with_fcl((scene.static_poses, scene.static_half_extents),
                                       (scene.dynamic_poses(0.7), scene.dynamic_half_extents))
    assert found > 1000
    assert excluded == 0  # none within the touching tolerance in practice


def test_brute_force_world_agrees_with_fcl_on_resting_boxes():
    found, excluded = compare_with_fcl(*resting_scene(3000, seed=6))
    assert found > 3000
    # Touching pairs whose exact separation is within the tolerance may go either way; on
    # this scene both sides call them colliding (touching counts), so none differ.
    assert excluded == 0


def scattered(rng, halves, low, high, n_static):
    """Return (static, dynamic) (poses, half extents): the boxes at random in a cube."""
    quaternions = random_quaternions(rng, len(halves))
    boxes = np.concatenate([rng.uniform(low, high, (len(halves), 3)), quaternions], axis=1)
    return (boxes[:n_static], halves[:n_static]), (boxes[n_static:], halves[n_static:])


def mixed_shapes_scene(n, seed):
    """Return needles, plates and cubes from 1 cm to 3 m across, at random angles."""
    rng = np.random.default_rng(seed)
    shapes = np.array([[1.0, 0.01, 0.01], [1.0, 1.0, 0.01], [1.0, 1.0, 1.0]])
    halves = shapes[rng.integers(0, 3, n)] * rng.uniform(0.05, 1.5, (n, 1))
    return scattered(rng, halves, 0.0, 12.0, n // 2)


def test_brute_force_world_agrees_with_fcl_on_needles_plates_and_cubes():
    found, excluded = compare_with_fcl(*mixed_shapes_scene(2000, seed=9))
    assert found > 5000
    assert excluded == 0


def mixed_scales_scene(n, seed):
    """Return boxes from 1 mm to 50 m across in one scene, each side on a log scale."""
    rng = np.random.default_rng(seed)
    halves = log_scale_half_extents(rng, n)
    return scattered(rng, halves, -30.0, 30.0, n // 3)


def test_brute_force_world_agrees_with_fcl_on_mixed_scales():
    found, excluded = compare_with_fcl(*mixed_scales_scene(1200, seed=10))
    assert found > 1500
    assert excluded == 0


def test_far_from_the_origin_the_pipeline_still_agrees():
    scene = scenes.uniform(2000, seed=8)
    shift = np.array([1e6, -1e6, 1e5])
    static = scene.static_poses.copy()
    dynamic = scene.dynamic_poses(0.3)
    static[:, :3] += shift
    dynamic[:, :3] += shift
    found, excluded = compare_with_fcl((static, scene.static_half_extents),
                                       (dynamic, scene.dynamic_half_extents))
    assert found > 500 and excluded == 0
