"""The robot's pass (pipeline/robot_pass.py) against World.step on the robot's box poses.

Its culls read only the boxes' centres and must never drop a pair the SAT reports: every
state's contacts must be step's to the bit, with margins of every kind, filters, one state
or many, and boxes that touch a static box to the last bit. Bad joint values are refused.
"""
import numpy as np
import pytest

from collision_node import World

STATIC_POSES = [[0.5, 0.0, 0.3, 0.0, 0.0, 0.0, 1.0], [0.0, 0.0, -0.06, 0.0, 0.0, 0.0, 1.0],
                [-0.3, 0.4, 0.5, 0.2, 0.1, 0.0, 0.9747]]
STATIC_HALF_EXTENTS = [[0.05, 0.3, 0.3], [1.0, 1.0, 0.05], [0.1, 0.12, 0.08]]


def random_states(robot, count, seed):
    limits = robot.joint_limits
    return np.random.default_rng(seed).uniform(limits[:, 0], limits[:, 1], (count, robot.dof))


def assert_as_step(world, robot, states, contacts):
    """Assert that each state's contacts are step's on its box poses, field by field."""
    for k, poses in enumerate(world.robot_poses(states)):
        step = world.step(poses, robot.half_extents).contacts
        mine = contacts[contacts['state'] == k]
        assert len(mine) == len(step), k
        for name in step.dtype.names:
            np.testing.assert_array_equal(mine[name], step[name], err_msg=name)


@pytest.mark.parametrize('margin, own_margins', [(0.0, 0.0), (0.03, 0.0), (0.0, 0.04),
                                                 (0.02, [0.0, 0.05, 0.01])])
def test_one_state_and_many_answer_as_step_with_every_margin(panda, margin, own_margins):
    world = World(margin=margin, threads=2)
    world.set_static(STATIC_POSES, STATIC_HALF_EXTENTS, margins=own_margins)
    world.set_robot(panda, [0.05, 0.1, 0.0, 0.0, 0.0, 0.2588190, 0.9659258])
    states = random_states(panda, 700, seed=4)  # chunks of MIN_STATES_PER_CHUNK, 2 threads
    contacts = world.check_joints(states).contacts
    assert_as_step(world, panda, states, contacts)
    for k in range(0, 700, 70):
        one = world.check_joints(states[k]).contacts
        mine = contacts[contacts['state'] == k]
        assert len(one) == len(mine) and not np.any(one['state'])
        for name in set(one.dtype.names) - {'state'}:
            np.testing.assert_array_equal(one[name], mine[name], err_msg=name)
    world.close()


def x_axis(quaternion):
    """Return the first column of a unit quaternion's rotation (x y z w)."""
    x, y, z, w = quaternion
    return np.array([1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + z * w), 2.0 * (x * z - y * w)])


def rotation(quaternion):
    """Return the rotation matrix of a unit quaternion (x y z w)."""
    x, y, z, w = quaternion
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def turning_x_to(u):
    """Return the unit quaternion of the shortest turn of the x axis onto unit vector u."""
    quaternion = np.concatenate([np.cross([1.0, 0.0, 0.0], u), [1.0 + u[0]]])
    return quaternion / np.linalg.norm(quaternion)


def touching_boxes(robot, q, offsets, rng):
    """Return a static box touching each robot box at q, apart by ``offsets``.

    Half of them face to face, the others with a face on a corner of the robot box, its
    normal along the corner's direction from the centre: the corner lies on the box's
    bounding sphere, where the culls decide by their rounding allowance.
    """
    static_half = np.array([0.05, 0.07, 0.09])
    poses = []
    for pose, half, offset in zip(robot.box_poses(q), robot.half_extents, offsets):
        axes = rotation(pose[3:])
        if rng.random() < 0.5:
            direction, reach, turn = axes[:, 0], half[0], pose[3:]
        else:
            corner = axes @ (half * rng.choice([-1.0, 1.0], 3))
            direction = corner / np.linalg.norm(corner)
            reach, turn = np.linalg.norm(corner), turning_x_to(direction)
        center = pose[:3] + direction * (reach + static_half[0] + offset)
        poses.append(np.concatenate([center, turn]))
    return np.array(poses), np.tile(static_half, (len(poses), 1))


@pytest.mark.parametrize('seed', range(6))
def test_a_static_box_touching_a_face_or_corner_to_the_last_bit_is_answered_as_step(panda, seed):
    rng = np.random.default_rng(seed)
    q = random_states(panda, 1, seed=seed + 10)[0]
    offsets = rng.choice([0.0, 1e-15, -1e-15, 1e-12, -1e-12, 1e-9], len(panda.half_extents))
    poses, extents = touching_boxes(panda, q, offsets, rng)
    for margin in (0.0, 1e-9):
        world = World(margin=margin)
        world.set_static(poses, extents)
        world.set_robot(panda)
        contacts = world.check_joints(q).contacts
        assert_as_step(world, panda, q[None], contacts)
        touching = {int(c['id_b']) for c in contacts
                    if c['type_b'] == 1 and c['id_a'] == c['id_b']}
        assert len(touching) >= np.count_nonzero(offsets < 0.0)


ARM = ('<robot name="arm"><link name="base"/><link name="arm"><collision>'
       '<origin xyz="1 0 0"/><geometry><box size="0.2 0.2 0.2"/></geometry></collision></link>'
       '<joint name="turn" type="continuous"><parent link="base"/><child link="arm"/>'
       '<axis xyz="0 0 1"/></joint></robot>')


@pytest.mark.parametrize('x, listed', [(1.19, True), (1.25, True), (1.30, False)])
def test_a_static_box_out_of_reach_at_any_angle_is_left_out(x, listed):
    """The arm's box centre stays 1 m from the joint: its sphere (0.173 m) reaches 1.173 m.

    A static box of half width 0.1 at x is culled at every angle once x - 0.1 > 1.173.
    """
    from collision_node import Robot
    robot = Robot.from_urdf(ARM)
    world = World()
    world.set_static([[x, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]], [[0.1, 0.1, 0.1]])
    world.set_robot(robot)
    rows = world.robot_pass()
    assert len(rows.pairs) == int(listed) and rows.all_pairs == 1 and rows.filtered == 0
    states = np.linspace(-np.pi, np.pi, 721)[:, None]  # state 360: angle 0
    contacts = world.check_joints(states).contacts
    assert_as_step(world, robot, states, contacts)
    assert (360 in contacts['state']) == (x < 1.2)  # at angle 0 the boxes overlap below 1.2
    path = world.check_trajectory(states[::60]).contacts  # every 30 degrees, through 0
    assert (len(path) > 0) == (x < 1.2) and (x > 1.2 or 6 in path['state'])


def test_panda_pairs_out_of_reach_are_left_out_and_answers_stay_steps(panda):
    world = World(margin=0.01)
    far = [[2.5, 0.0, 0.3, 0.0, 0.0, 0.0, 1.0]]  # beyond the Panda's reach
    world.set_static(STATIC_POSES + far, STATIC_HALF_EXTENTS + [[0.1, 0.1, 0.1]])
    world.set_robot(panda)
    rows = world.robot_pass()
    listed = {tuple(key) for key in rows.keys.tolist()}
    fingers = {box for box, link in enumerate(panda.box_links) if 'finger' in link}
    far_pairs = {key[0] for key in listed if key[1:] == (1, 3)}
    assert far_pairs == fingers  # sliding fingers have no fixed point: their pairs stay
    assert (0, 1, 1) in listed  # the base box and the table it stands on
    states = random_states(panda, 400, seed=8)
    assert_as_step(world, panda, states, world.check_joints(states).contacts)


def test_ignored_pairs_and_masks_leave_the_same_pairs_out(panda):
    world = World()
    world.set_static(STATIC_POSES, STATIC_HALF_EXTENTS)
    world.set_robot(panda)
    hand = [b for b, link in enumerate(panda.box_links) if link == 'panda_hand']
    masks = np.full(len(panda.box_links), 0xFFFF)
    masks[hand[0]] = 0  # the hand's first box collides with nothing
    world.set_filters(masks=masks, ignored_pairs=[[hand[-1], 0, 1, 1]])  # nor its last the table
    states = random_states(panda, 300, seed=5)
    contacts = world.check_joints(states).contacts
    assert not np.any((contacts['id_a'] == hand[0]) | (contacts['id_b'] == hand[0])
                      & (contacts['type_b'] == 0))
    assert not np.any((contacts['id_a'] == hand[-1]) & (contacts['type_b'] == 1)
                      & (contacts['id_b'] == 1))
    assert_as_step(world, panda, states, contacts)


def test_a_bad_single_state_is_refused_naming_the_joint_or_box(panda):
    world = World()
    world.set_static(STATIC_POSES, STATIC_HALF_EXTENTS)
    world.set_robot(panda)
    q = np.zeros(panda.dof)
    q[3] = np.inf
    with pytest.raises(ValueError, match="state 0, joint '%s'" % panda.joint_names[3]):
        world.check_joints(q)
    world.set_robot(panda, [1e9, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])  # its boxes beyond 1e9 m
    with pytest.raises(ValueError, match=r'state 0: dynamic body \d+: position beyond'):
        world.check_joints(np.zeros(panda.dof))


@pytest.mark.parametrize('bad_box_state, bad_joint_state', [(9, 13), (13, 9), (7, 8), (20, 3)])
def test_a_batch_fails_at_its_first_bad_state_across_and_within_blocks(panda, bad_box_state,
                                                                       bad_joint_state):
    """The pass runs robot_pass.LANES states at once: the first bad state still decides.

    One state's finger slid 1e12 m (its boxes beyond 1e9 m), another's joint NaN, in one
    block of lanes or in two: the pass (World.robot_pass, as the node's joint lane runs it)
    names whichever comes first. (World.check_joints refuses a NaN anywhere in q before its
    pass, by the joint's name.) A World with two states placed out of range names the first.
    """
    from collision_node.pipeline.robot_pass import LANES, NON_FINITE_JOINT
    assert LANES == 8  # the states above sit in one block or two for 8 lanes
    world = World()
    world.set_static(STATIC_POSES, STATIC_HALF_EXTENTS)
    world.set_robot(panda)
    states = random_states(panda, 24, seed=5)
    finger = panda.joint_names.index('panda_finger_joint1')
    states[bad_box_state, finger] = 1e12
    states[bad_joint_state, 2] = np.nan
    contacts, _, state, box, _, _ = world.robot_pass().check(states, 0, len(states))
    assert len(contacts) == 0 and state == min(bad_box_state, bad_joint_state)
    if bad_box_state < bad_joint_state:
        assert panda.box_links[box] in ('panda_leftfinger', 'panda_rightfinger')
    else:
        assert box == NON_FINITE_JOINT
    states[bad_joint_state, 2] = 0.0
    states[bad_joint_state, finger] = 1e12
    with pytest.raises(ValueError, match=r'state %d: dynamic body \d+: position beyond'
                       % min(bad_box_state, bad_joint_state)):
        world.check_joints(states)
    good = random_states(panda, 24, seed=5)
    assert_as_step(world, panda, good, world.check_joints(good).contacts)
