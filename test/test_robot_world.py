"""A robot in the World: joint values in, contacts out, whole trajectories checked.

check_joints is checked against step on the robot's box poses (bit for bit) and against
python-fcl on the same boxes with the robot's filter; check_trajectory against a dense
sampled referee (no segment with a sampled collision may go unreported) and by hand.
"""
import fcl
import numpy as np
import pytest

from collision_node import World
from collision_node.pipeline.contacts import DYNAMIC, STATIC
from collision_node.pipeline.robot_bodies import gap_terms, separation, separation_gap
from collision_node.pipeline.sat import signed_distance

STATIC_POSES = [[0.5, 0.0, 0.3, 0.0, 0.0, 0.0, 1.0],       # a wall in front
                [0.0, 0.0, -0.06, 0.0, 0.0, 0.0, 1.0],     # the table under the base
                [-0.3, 0.4, 0.5, 0.2, 0.1, 0.0, 0.9747]]   # a tilted crate
STATIC_HALF_EXTENTS = [[0.05, 0.3, 0.3], [1.0, 1.0, 0.05], [0.1, 0.12, 0.08]]


def panda_world(robot, base_pose=None, **settings):
    world = World(**settings)
    world.set_static(STATIC_POSES, STATIC_HALF_EXTENTS)
    world.set_robot(robot, base_pose)
    return world


def random_states(robot, count, seed):
    limits = robot.joint_limits
    return np.random.default_rng(seed).uniform(limits[:, 0], limits[:, 1],
                                               (count, robot.dof))


def pair_keys(contacts):
    return {(int(c['state']), int(c['id_a']), int(c['type_b']), int(c['id_b']))
            for c in contacts}


@pytest.mark.parametrize('settings', [{}, {'margin': 0.02}, {'broad_phase': 'grid'},
                                      {'sphere_prefilter': False}])
def test_check_joints_equals_step_on_the_box_poses(panda, settings):
    base = [0.1, -0.2, 0.05, 0.0, 0.0, 0.3826834, 0.9238795]
    world = panda_world(panda, base, **settings)
    states = random_states(panda, 60, seed=1)
    contacts = world.check_joints(states).contacts
    bodies = world._robot.bodies
    for k, q in enumerate(states):
        step = world.step(bodies.poses(q)[0], panda.half_extents).contacts
        mine = contacts[contacts['state'] == k]
        assert len(mine) == len(step), k
        for name in step.dtype.names:
            np.testing.assert_array_equal(mine[name], step[name], err_msg=name)
    assert len(contacts)  # random Panda states collide


def test_the_filter_leaves_out_same_link_adjacent_and_srdf_pairs(panda):
    world = panda_world(panda)
    allowed = {tuple(pair) for pair in panda.allowed_box_pairs.tolist()}
    contacts = world.check_joints(random_states(panda, 200, seed=2)).contacts
    robot_pairs = {(c['id_a'], c['id_b']) for c in contacts if c['type_b'] == DYNAMIC}
    assert robot_pairs and robot_pairs <= allowed


def fcl_box(half_extents, pose):
    x, y, z, qx, qy, qz, qw = pose
    return fcl.CollisionObject(fcl.Box(*(2.0 * np.asarray(half_extents))),
                               fcl.Transform(np.array([qw, qx, qy, qz]), np.array([x, y, z])))


def test_collisions_equal_python_fcl_on_the_same_boxes(panda):
    world = panda_world(panda)
    states = random_states(panda, 150, seed=3)
    ours = pair_keys(world.check_joints(states).contacts)
    statics = [fcl_box(h, p) for p, h in zip(STATIC_POSES, STATIC_HALF_EXTENTS)]
    theirs = set()
    request = fcl.CollisionRequest()
    for k, poses in enumerate(panda.box_poses(states)):
        boxes = [fcl_box(h, p) for p, h in zip(poses, panda.half_extents)]
        for a, b in panda.allowed_box_pairs.tolist():
            if fcl.collide(boxes[a], boxes[b], request, fcl.CollisionResult()):
                theirs.add((k, a, DYNAMIC, b))
        for a, box in enumerate(boxes):
            for s, static in enumerate(statics):
                if fcl.collide(box, static, request, fcl.CollisionResult()):
                    theirs.add((k, a, STATIC, s))
    assert len(theirs) > 100
    assert ours == theirs


def test_a_bad_q_or_base_pose_is_refused_and_changes_nothing(panda):
    world = panda_world(panda)
    with pytest.raises(ValueError, match='shape'):
        world.check_joints(np.zeros(panda.dof + 1))
    q = np.zeros((3, panda.dof))
    q[2, 4] = np.nan
    with pytest.raises(ValueError, match="state 2, joint '%s'" % panda.joint_names[4]):
        world.check_joints(q)
    with pytest.raises(ValueError, match='quaternion'):
        world.set_robot(panda, [0, 0, 0, 0, 0, 0, 0])
    assert world._robot.bodies.base_pose.tolist() == [0, 0, 0, 0, 0, 0, 1]
    with pytest.raises(ValueError, match='set_robot'):
        World().check_joints(np.zeros(panda.dof))


def first_sampled_collisions(world, robot, start, end, samples):
    """Return {(id_a, type_b, id_b): first colliding s} over ``samples`` points of a segment."""
    s = np.linspace(0.0, 1.0, samples)
    states = start + s[:, None] * (end - start)
    first = {}
    for contact in world.check_joints(states).contacts:
        key = (int(contact['id_a']), int(contact['type_b']), int(contact['id_b']))
        first.setdefault(key, s[contact['state']])
    return first


@pytest.mark.parametrize('seed', range(4))
def test_no_segment_with_a_sampled_collision_goes_unreported(panda, seed):
    world = panda_world(panda)
    rng = np.random.default_rng(seed)
    limits = panda.joint_limits
    centre = rng.uniform(limits[:, 0], limits[:, 1])
    steps = rng.normal(0.0, 0.15, (12, panda.dof))
    waypoints = np.clip(centre + np.cumsum(steps, axis=0), limits[:, 0], limits[:, 1])
    contacts = world.check_trajectory(waypoints).contacts
    reported = {}
    for c in contacts:
        key = (int(c['state']), int(c['id_a']), int(c['type_b']), int(c['id_b']))
        reported[key] = min(reported.get(key, np.inf), c['toi'])
    missed, seen = [], 0
    for k in range(len(waypoints) - 1):
        sampled = first_sampled_collisions(world, panda, waypoints[k], waypoints[k + 1], 400)
        seen += len(sampled)
        for pair, s in sampled.items():
            toi = reported.get((k, *pair))
            if toi is None or toi > s:
                missed.append((k, pair, s, toi))
    assert seen > 0
    assert missed == []


def test_a_trajectory_past_the_one_pass_answers_as_in_a_small_scene(panda):
    """1,000 more static boxes far away: the answer stays the same.

    The waypoints go through check_states and the segments place their boxes by forward
    kinematics (no kept frames).
    """
    from collision_node.pipeline.world import ONE_PASS_PAIRS
    rng = np.random.default_rng(21)
    limits = panda.joint_limits
    waypoints = np.clip(rng.uniform(limits[:, 0], limits[:, 1])
                        + np.cumsum(rng.normal(0.0, 0.2, (8, panda.dof)), axis=0),
                        limits[:, 0], limits[:, 1])
    small = panda_world(panda)
    large = World()
    far = np.column_stack([rng.uniform(20.0, 30.0, (1000, 3)), np.zeros((1000, 3)),
                           np.ones(1000)])
    large.set_static(np.vstack([STATIC_POSES, far]),
                     np.vstack([STATIC_HALF_EXTENTS, np.full((1000, 3), 0.1)]))
    large.set_robot(panda)
    assert large._robot.robot_pass(ONE_PASS_PAIRS) is None  # past the one pass
    expected = small.check_trajectory(waypoints).contacts
    assert len(expected) and (expected['toi'] > 0.0).any()
    got = large.check_trajectory(waypoints).contacts
    assert len(got) == len(expected)
    for name in expected.dtype.names:
        np.testing.assert_array_equal(got[name], expected[name], err_msg=name)


def test_waypoints_are_exact_and_a_free_path_reports_nothing(panda):
    world = panda_world(panda)
    states = random_states(panda, 3, seed=5)
    trajectory = world.check_trajectory(states).contacts
    at_waypoints = trajectory[trajectory['toi'] == 0.0]
    exact = world.check_joints(states).contacts
    assert pair_keys(exact) <= pair_keys(at_waypoints)
    # A far-away robot, still: nothing anywhere.
    free = panda_world(panda, [5.0, 5.0, 5.0, 0, 0, 0, 1])
    q = np.zeros(panda.dof)
    q[3], q[5] = -1.5, 1.5  # folded: the fingers and links 0-7 apart
    path = np.array([q, q + 0.01, q + 0.02])
    assert len(free.check_trajectory(path).contacts) == len(free.check_joints(path).contacts)


def test_a_crossing_between_collision_free_waypoints_is_reported(panda):
    """Both waypoints free, the wall between them: a waypoint-only check misses it."""
    world = World()
    world.set_static([[0.45, 0.0, 0.5, 0.0, 0.0, 0.0, 1.0]], [[0.01, 0.01, 0.6]])  # a thin pole
    world.set_robot(panda)
    q = np.array([0.0, 0.4, 0.0, -1.5, 0.0, 1.9, 0.8, 0.0])[:panda.dof]
    left, right = q.copy(), q.copy()
    left[0], right[0] = -0.6, 0.6
    waypoints = np.array([left, right])
    exact = world.check_joints(waypoints).contacts
    assert not any(exact['type_b'] == STATIC)
    trajectory = world.check_trajectory(waypoints).contacts
    hits = trajectory[(trajectory['type_b'] == STATIC) & (trajectory['state'] == 0)]
    assert len(hits)
    sampled = first_sampled_collisions(world, panda, left, right, 2000)
    first = min(s for (a, kind, b), s in sampled.items() if kind == STATIC)
    assert 0.0 < hits['toi'].min() <= first


def pole_world(panda, x):
    world = World()
    world.set_static([[x, 0.0, 0.5, 0.0, 0.0, 0.0, 1.0]], [[0.01, 0.01, 0.6]])
    world.set_robot(panda)
    return world


def box_corners(pose, half):
    centre, rotation = box_frame(pose)
    signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)])
    return centre + (signs * half) @ rotation.T


def nearest_to_pole(panda, x, states):
    """Return the least signed distance from any box to the pole at ``x`` over ``states``."""
    centre, rotation = box_frame(np.array([x, 0.0, 0.5, 0.0, 0.0, 0.0, 1.0]))
    return min(signed_distance(*box_frame(pose), half, centre, rotation,
                               np.array([0.01, 0.01, 0.6])).distance
               for poses in panda.box_poses(states)
               for pose, half in zip(poses, panda.half_extents))


@pytest.mark.parametrize('gap', [0.003, -0.001])
def test_an_arm_sweeping_past_a_pole_within_millimetres(panda, gap):
    """Free 3 mm past it: nothing reported; 1 mm into it: reported, at or before contact.

    The arm turns about its base by 1.2 rad, its hand 0.5 m out: tens of centimetres of
    motion pass millimetres from the pole, where the chords' planes do the proving.
    """
    q = np.array([0.0, 0.4, 0.0, -1.5, 0.0, 1.9, 0.8, 0.0])[:panda.dof]
    left, right = q.copy(), q.copy()
    left[0], right[0] = -0.6, 0.6
    dense = left + np.linspace(0.0, 1.0, 601)[:, None] * (right - left)
    # The pole just beyond the arm's reach, then moved until the sweep's nearest approach is
    # ``gap``: the reach's corner turns on a circle about the base's axis.
    corners_at = [corner for pose, half in zip(panda.box_poses(q), panda.half_extents)
                  for corner in box_corners(pose, half)]
    x = max(np.hypot(c[0], c[1]) for c in corners_at) + 0.01 + gap
    for _ in range(3):
        x += gap - nearest_to_pole(panda, x, dense)
    assert nearest_to_pole(panda, x, dense) == pytest.approx(gap, abs=1e-4)
    world = pole_world(panda, x)
    waypoints = np.array([left, right])
    assert len(world.check_joints(waypoints).contacts) == 0
    hits = world.check_trajectory(waypoints, resolution=0.001).contacts
    if gap > 0.0:
        assert len(hits) == 0
    else:
        sampled = first_sampled_collisions(world, panda, left, right, 1201)
        assert sampled and len(hits)
        assert 0.0 < hits['toi'].min() <= min(sampled.values())


def box_frame(pose):
    x, y, z, w = pose[3:]
    return np.array(pose[:3]), np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


@pytest.mark.parametrize('seed', range(3))
def test_a_reported_segment_is_within_twice_the_resolution_of_contact(panda, seed):
    """A segment row not colliding at its toi comes from a piece whose grown boxes touch."""
    world = panda_world(panda)
    rng = np.random.default_rng(10 + seed)
    limits = panda.joint_limits
    waypoints = np.clip(rng.uniform(limits[:, 0], limits[:, 1])
                        + np.cumsum(rng.normal(0.0, 0.2, (10, panda.dof)), axis=0),
                        limits[:, 0], limits[:, 1])
    resolution = 0.004
    rows = world.check_trajectory(waypoints, resolution=resolution).contacts
    loose = rows[(rows['depth'] == 0.0) & np.isnan(rows['distance'])]
    assert len(loose)
    for row in loose:
        k, toi = row['state'], row['toi']
        poses = panda.box_poses(waypoints[k] + toi * (waypoints[k + 1] - waypoints[k]))
        center_a, rotation_a = box_frame(poses[row['id_a']])
        if row['type_b'] == DYNAMIC:
            center_b, rotation_b = box_frame(poses[row['id_b']])
            half_b = panda.half_extents[row['id_b']]
        else:
            center_b, rotation_b = box_frame(np.array(STATIC_POSES[row['id_b']]))
            half_b = np.array(STATIC_HALF_EXTENTS[row['id_b']])
        distance = signed_distance(center_a, rotation_a, panda.half_extents[row['id_a']],
                                   center_b, rotation_b, half_b).distance
        assert distance <= 2 * resolution + 1e-9, (row, distance)


def random_rotation(rng):
    quaternion = rng.normal(size=4)
    return box_frame(np.concatenate([np.zeros(3), quaternion / np.linalg.norm(quaternion)]))[1]


def test_the_gaps_a_segment_starts_from_never_exceed_the_distance():
    """A pair's kept separation proves a gap no wider than the boxes' distance.

    Two robot boxes (their bounding spheres) and a robot box against a static box (its
    sphere against the box itself), against the SAT's exact distance, on random pairs from
    overlapping to a metre apart; and a small box over a table, where the gap is the height
    of the box's centre less its half diagonal, not what the table's huge sphere would leave.
    """
    rng = np.random.default_rng(5)
    pairs = np.array([[0, 1], [0, 2]])  # rows 0 and 1 robot boxes, row 2 a static box
    for _ in range(2000):
        centers = rng.uniform(-1.0, 1.0, (3, 3))
        rotations = np.array([random_rotation(rng) for _ in range(3)])
        extents = rng.uniform(0.01, 0.5, (3, 3))
        extents[2] = extents[1]
        centers[2], rotations[2] = centers[1], rotations[1]
        scale, offset = gap_terms(pairs, np.linalg.norm(extents, axis=1), 2)
        distance = max(signed_distance(centers[0], rotations[0], extents[0], centers[1],
                                       rotations[1], extents[1]).distance, 0.0)
        for p, (a, b) in enumerate(pairs):
            gap = separation_gap(separation((centers, rotations, extents), a, b, 2), scale[p],
                                 offset[p])
            assert gap <= distance
    half = np.array([0.03, 0.04, 0.12])
    boxes = (np.array([[0.2, -0.3, 0.5], [0.0, 0.0, -0.05]]), np.array([np.eye(3)] * 2),
             np.array([half, [1.0, 1.0, 0.05]]))
    scale, offset = gap_terms(np.array([[0, 1]]), np.linalg.norm(boxes[2], axis=1), 1)
    gap = separation_gap(separation(boxes, 0, 1, 1), scale[0], offset[0])
    assert gap == pytest.approx(0.5 - 0.13, abs=1e-12) and gap < 0.5 - 0.13
