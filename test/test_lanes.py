"""The lanes against the full way, message by message (ros/lanes.py).

The joint_states full way: cdr.parse_joint_state, JointValues.merge, then World.check_joints
on q; the PoseArray one: cdr.parse_pose_array. A lane, once it has learned a message's
layout, must give the same contacts (poses) and stamp and leave the same joint values, or
leave the message to the full way (None) without changing them. Messages are written field
by field with struct, in either byte order, so that the cases a lane must not answer
(big-endian, bad lengths, trailing bytes) are built as they would come.
"""
import struct

import numpy as np
import pytest

from collision_node.benchmarks.robot_model import panda_world
from collision_node.pipeline.contacts import CONTACT_DTYPE, STATE_CONTACT_DTYPE
from collision_node.pipeline.world import World
from collision_node.ros.cdr import CdrError, parse_joint_state, parse_pose_array
from collision_node.ros.joints import JointInputError, JointValues
from collision_node.ros.lanes import JointLane, PoseLane
from collision_node.ros.messages import CloudWriter


class Cdr:
    """A CDR message written field by field with struct, in byte order ``order``."""

    def __init__(self, order, sec, nanosec, frame_id):
        self.order = order
        self.out = bytearray(b'\x00\x01\x00\x00' if order == '<' else b'\x00\x00\x00\x00')
        self.put('i', sec)
        self.put('I', nanosec)
        self.text(frame_id)

    def put(self, fmt, *values):
        """Append values, aligned to the item's size counted after the 4-byte header."""
        self.out.extend(bytes(-(len(self.out) - 4) % struct.calcsize(fmt)))
        self.out.extend(struct.pack(self.order + fmt, *values))

    def text(self, value):
        self.put('I', len(value.encode()) + 1)
        self.out.extend(value.encode() + b'\x00')

    def doubles(self, values):
        self.put('I', len(values))
        for value in values:
            self.put('d', value)


def joint_state_cdr(names, positions, velocities=(), efforts=(), sec=5, nanosec=6,
                    frame_id='base', order='<', trailing=b''):
    """Write a sensor_msgs/JointState as CDR."""
    cdr = Cdr(order, sec, nanosec, frame_id)
    cdr.put('I', len(names))
    for name in names:
        cdr.text(name)
    for values in (positions, velocities, efforts):
        cdr.doubles(values)
    return bytes(cdr.out) + trailing


def pose_array_cdr(poses, sec=5, nanosec=6, frame_id='world', order='<', trailing=b''):
    """Write a geometry_msgs/PoseArray as CDR."""
    cdr = Cdr(order, sec, nanosec, frame_id)
    cdr.put('I', len(poses))
    for value in np.ravel(poses):
        cdr.put('d', value)
    return bytes(cdr.out) + trailing


# The node's writer of the robot's clouds (their contacts carry a state, the cloud does not),
# and its frame.
JOINTS_WRITER = CloudWriter(STATE_CONTACT_DTYPE, CONTACT_DTYPE.names)
FRAME = 'world'
CLOUD = (JOINTS_WRITER, FRAME)


class FullWay:
    """The node's path for a message without the lane; its joint values."""

    def __init__(self, robot):
        self.joints = JointValues(robot.joint_names)
        self.previous = None

    def answer(self, world, buffer):
        """Return (contacts, sec, nanosec), None while a joint has no value; raise refusals."""
        view = parse_joint_state(buffer, self.previous)
        self.joints.merge(view.names, view.positions)
        self.previous = view
        if self.joints.missing:
            return None
        return world.check_joints(self.joints.q()).contacts, view.sec, view.nanosec


@pytest.fixture(scope='module')
def scene(panda):
    return panda_world(panda), panda


def driver_names(robot):
    """Return a driver's names: every joint, in another order, and a name of no joint."""
    names = list(robot.joint_names[::-1])
    names.insert(3, 'conveyor_joint')
    return names


def positions_of(names, robot, q):
    """Return the positions a message of ``names`` carries for q (0.5 for unknown names)."""
    index = {name: i for i, name in enumerate(robot.joint_names)}
    return [float(q[index[name]]) if name in index else 0.5 for name in names]


def learned_lane(world, robot, names, frame_id='base'):
    """Return (lane, its JointValues, the full way) after one message went the full way."""
    lane, full, reference = JointLane(), FullWay(robot), FullWay(robot)
    q = np.zeros(robot.dof)
    buffer = joint_state_cdr(names, positions_of(names, robot, q), frame_id=frame_id)
    full.answer(world, buffer)
    reference.answer(world, buffer)
    lane.learn(buffer, full.previous, full.joints)
    return lane, full, reference


def test_a_drivers_stream_is_answered_as_the_full_way(scene):
    world, robot = scene
    names = driver_names(robot)
    lane, joints, reference = learned_lane(world, robot, names)
    limits = robot.joint_limits
    rng = np.random.default_rng(0)
    reported = 0
    for k, q in enumerate(rng.uniform(limits[:, 0], limits[:, 1], (300, robot.dof))):
        sec, nanosec = int(rng.integers(-2**31, 2**31)), int(rng.integers(0, 2**32))
        buffer = joint_state_cdr(names, positions_of(names, robot, q), velocities=[0.1] * (k % 3),
                                 efforts=[0.2] * len(names) * (k % 2), sec=sec, nanosec=nanosec)
        contacts, passed, sat_tests, lane_sec, lane_nanosec, cloud = lane.answer(
            buffer, joints.joints, world.robot_pass(), *CLOUD)
        expected, expected_sec, expected_nanosec = reference.answer(world, buffer)
        assert np.array_equal(contacts, expected)
        assert cloud == JOINTS_WRITER.serialize(expected, sec, nanosec, FRAME)  # as the node's
        assert (lane_sec, lane_nanosec) == (expected_sec, expected_nanosec) == (sec, nanosec)
        assert np.array_equal(joints.joints.q(), reference.joints.q())
        assert sat_tests <= passed
        reported += len(contacts)
    assert reported > 100  # colliding states among them: not vacuous


def refused(full, world, buffer):
    """Return why the full way refuses ``buffer`` (None: it answers it)."""
    try:
        full.answer(world, buffer)
    except (CdrError, JointInputError) as error:
        return str(error)
    return None


def test_messages_it_cannot_answer_go_the_full_way_unchanged(scene):
    world, robot = scene
    names = driver_names(robot)
    q = np.full(robot.dof, 0.1)
    good = positions_of(names, robot, q)
    nan = list(good)
    nan[2] = float('nan')
    others = {
        'other names': joint_state_cdr(names[::-1], good[::-1]),
        'other frame': joint_state_cdr(names, good, frame_id='odom'),
        'big-endian': joint_state_cdr(names, good, order='>'),
        'NaN position': joint_state_cdr(names, nan),
        'fewer positions': joint_state_cdr(names, good[:-1]),
        'no positions': joint_state_cdr(names, [], velocities=good),
        'trailing bytes': joint_state_cdr(names, good, trailing=bytes(24)),
        'truncated': joint_state_cdr(names, good, efforts=good)[:-5],
    }
    expected_refusals = {'NaN position', 'fewer positions', 'trailing bytes', 'truncated'}
    for case, buffer in others.items():
        lane, full, reference = learned_lane(world, robot, names)
        before = full.joints.q()
        assert lane.answer(buffer, full.joints, world.robot_pass(), *CLOUD) is None, case
        assert np.array_equal(full.joints.q(), before), case
        assert (refused(reference, world, buffer) is not None) == (case in expected_refusals)
        # The next message of the learned layout is the lane's again.
        answer = lane.answer(joint_state_cdr(names, good), full.joints, world.robot_pass(), *CLOUD)
        assert answer is not None and np.array_equal(
            answer[0], world.check_joints(full.joints.q()).contacts), case


def test_a_joint_without_a_value_leaves_the_answer_to_the_full_way(scene):
    world, robot = scene
    arm = [name for name in robot.joint_names if 'finger' not in name]
    lane, full, _ = learned_lane(world, robot, arm)
    assert full.joints.missing
    buffer = joint_state_cdr(arm, [0.2] * len(arm))
    assert lane.answer(buffer, full.joints, world.robot_pass(), *CLOUD) is None
    assert full.answer(world, buffer) is None  # the full way waits (and warns) too
    # A gripper's message (another layout) completes q the full way; the arm's next one goes
    # the full way too (the values last merged the gripper's names), and is learned.
    gripper = [name for name in robot.joint_names if 'finger' in name]
    gripper_message = joint_state_cdr(gripper, [0.01] * len(gripper))
    assert lane.answer(gripper_message, full.joints, world.robot_pass(), *CLOUD) is None
    full.answer(world, gripper_message)
    arm_message = joint_state_cdr(arm, [0.3] * len(arm))
    assert lane.answer(arm_message, full.joints, world.robot_pass(), *CLOUD) is None
    full.answer(world, arm_message)
    lane.learn(arm_message, full.previous, full.joints)
    answer = lane.answer(joint_state_cdr(arm, [0.4] * len(arm)), full.joints,
                         world.robot_pass(), *CLOUD)
    assert answer is not None
    assert np.array_equal(answer[0], world.check_joints(full.joints.q()).contacts)


def test_no_robot_pass_or_another_joint_values_mean_the_full_way(scene):
    world, robot = scene
    names = driver_names(robot)
    lane, full, _ = learned_lane(world, robot, names)
    buffer = joint_state_cdr(names, positions_of(names, robot, np.zeros(robot.dof)))
    assert lane.answer(buffer, full.joints, None, *CLOUD) is None  # continuous, or past one pass
    assert lane.answer(buffer, JointValues(robot.joint_names, full.joints),
                       world.robot_pass(), *CLOUD) is None  # a new model: its values unmerged
    assert lane.answer(buffer, None, world.robot_pass(), *CLOUD) is None


def random_poses(rng, count):
    poses = np.concatenate([rng.normal(size=(count, 3)), rng.normal(size=(count, 4))], axis=1)
    poses[:, 3:] /= np.linalg.norm(poses[:, 3:], axis=1, keepdims=True)
    return poses


@pytest.mark.parametrize('frame_id', ['', 'world', 'map_12'])
def test_a_trackers_pose_arrays_read_as_the_full_way(frame_id):
    rng = np.random.default_rng(len(frame_id))
    config = object()  # the node's configuration: the lane answers under the one it learned
    for count in (7, 1, 0):
        lane = PoseLane()
        first = pose_array_cdr(random_poses(rng, count), frame_id=frame_id)
        assert lane.read(first, config) is None  # nothing learned yet
        lane.learn(first, parse_pose_array(first), config)
        for _ in range(20):
            sec, nanosec = int(rng.integers(-2**31, 2**31)), int(rng.integers(0, 2**32))
            buffer = pose_array_cdr(random_poses(rng, count), sec, nanosec, frame_id,
                                    trailing=bytes(int(rng.integers(0, 8))))
            read, expected = lane.read(buffer, config), parse_pose_array(buffer)
            assert (read.sec, read.nanosec, read.frame_id) == (sec, nanosec, frame_id)
            assert read.poses.tobytes() == expected.poses.tobytes()
            assert read.poses.shape == (count, 7) and read.poses.flags.writeable \
                and read.poses.flags.c_contiguous and read.poses.dtype == np.float64


def test_pose_arrays_of_another_layout_go_the_full_way():
    rng = np.random.default_rng(9)
    config = object()
    poses = random_poses(rng, 7)
    lane = PoseLane()
    learned = pose_array_cdr(poses)
    lane.learn(learned, parse_pose_array(learned), config)
    others = {
        'other frame': pose_array_cdr(poses, frame_id='map'),
        'more poses': pose_array_cdr(random_poses(rng, 8)),
        'fewer poses': pose_array_cdr(poses[:6]),
        'big-endian': pose_array_cdr(poses, order='>'),
        'trailing bytes': pose_array_cdr(poses, trailing=bytes(8)),
        'truncated': pose_array_cdr(poses)[:-3],
    }
    for case, buffer in others.items():
        assert lane.read(buffer, config) is None, case
    assert lane.read(learned, object()) is None  # another configuration: its own rules
    assert lane.read(learned, config) is not None
    big = pose_array_cdr(poses, order='>')
    lane.learn(big, parse_pose_array(big), config)  # big-endian: read the full way only
    assert lane.read(big, config) is None and lane.read(learned, config) is None


class PoseConfig:
    """The node's configuration as a lane reads it: the bodies' sizes and the cloud's frame."""

    def __init__(self, half_extents, frame_id='world'):
        self.dynamic_half_extents = half_extents
        self.frame_id = frame_id


def pose_scene(margin):
    """Return two Worlds of one scene of 3 static boxes: one for the lane, one for the full way."""
    rng = np.random.default_rng(3)
    statics = random_poses(rng, 3)
    worlds = World(margin=margin), World(margin=margin)
    for world in worlds:
        world.set_static(statics, np.full((3, 3), 0.4))
    return worlds


def full_way_answer(world, buffer, config):
    """Return (Result, cloud bytes) of the node's full way: parse, World.step, serialize."""
    message = parse_pose_array(buffer)
    result = world.step(message.poses, config.dynamic_half_extents)
    return result, CloudWriter().serialize(result.contacts, message.sec, message.nanosec,
                                           config.frame_id)


def counts(result):
    """Return a result's counters, the stats that do not time."""
    keys = ('dynamic_bodies', 'static_bodies', 'compared', 'candidate_pairs', 'filtered_pairs',
            'sat_tests', 'reused')
    return tuple(result.stats[key] for key in keys)


@pytest.mark.parametrize('margin', [0.0, 0.05])
@pytest.mark.parametrize('half_extents', [np.full(3, 0.3),
                                          np.linspace(0.1, 0.5, 21).reshape(7, 3)])
def test_a_trackers_pose_arrays_are_answered_as_the_full_way(margin, half_extents):
    rng = np.random.default_rng(int(100 * margin))
    config = PoseConfig(half_extents.copy())
    world, reference = pose_scene(margin)
    lane, writer = PoseLane(), CloudWriter()
    first = pose_array_cdr(random_poses(rng, 7), frame_id='')
    full_way_answer(world, first, config)
    full_way_answer(reference, first, config)
    lane.learn(first, parse_pose_array(first), config)
    reported = reused = 0
    buffer = first
    for k in range(200):
        if k % 10 != 9:  # else the same poses again, with another stamp
            poses = random_poses(rng, 7)
        sec, nanosec = int(rng.integers(-2**31, 2**31)), int(rng.integers(0, 2**32))
        buffer = pose_array_cdr(poses, sec, nanosec, frame_id='')
        cloud, read, lane_sec, lane_nanosec = lane.answer(buffer, config, world, writer)
        result = lane.result(0.0, 1.0)
        assert result.phase_ms == (0.0, 1e3) or result.stats['reused']
        expected, expected_cloud = full_way_answer(reference, buffer, config)
        assert np.array_equal(result.contacts, expected.contacts)
        assert cloud == expected_cloud
        assert counts(result) == counts(expected)
        assert read.tobytes() == poses.tobytes() and (lane_sec, lane_nanosec) == (sec, nanosec)
        reported += len(result.contacts)
        reused += result.stats['reused']
    assert reported > 100 and reused == 20  # contacts among them: not vacuous
    # The World stepped by the lane keeps what a stepped one keeps: the same input is reused.
    again = world.step(parse_pose_array(buffer).poses, config.dynamic_half_extents)
    assert again.stats['reused'] and np.array_equal(again.contacts, expected.contacts)


def test_pose_arrays_the_lane_cannot_answer_go_the_full_way():
    rng = np.random.default_rng(5)
    config = PoseConfig(np.full(3, 0.3))
    world, _ = pose_scene(0.0)
    lane, writer = PoseLane(), CloudWriter()
    learned = pose_array_cdr(random_poses(rng, 7))
    assert lane.answer(learned, config, world, writer) is None  # nothing learned yet
    full_way_answer(world, learned, config)
    lane.learn(learned, parse_pose_array(learned), config)
    assert lane.answer(learned, config, world, writer) is not None
    assert lane.result(0.0, 0.0).stats['reused']  # the full way's input again
    assert lane.answer(learned, PoseConfig(np.full(3, 0.3)), world, writer) is None
    assert lane.answer(pose_array_cdr(random_poses(rng, 8)), config, world, writer) is None
    invalid = random_poses(rng, 7)
    invalid[3, 3:] = 0.0  # a zero quaternion: the World says why, the lane does not answer
    assert lane.answer(pose_array_cdr(invalid), config, world, writer) is None
    with pytest.raises(ValueError, match='body 3'):
        full_way_answer(world, pose_array_cdr(invalid), config)
    invalid[3, 3:] = (0.0, 0.0, 0.0, 1.0)
    invalid[5, 0] = np.nan
    assert lane.answer(pose_array_cdr(invalid), config, world, writer) is None
    # A scene change: the World gathers again on its next full step, then the lane answers.
    world.set_static(random_poses(rng, 2), np.full((2, 3), 0.2))
    assert lane.answer(learned, config, world, writer) is None
    full_way_answer(world, learned, config)
    assert lane.answer(learned, config, world, writer) is not None
    assert lane.result(0.0, 0.0).stats['reused']  # the full way's input again
    # A continuous World steps past the one pass: the full way only.
    world.continuous = True
    assert lane.answer(learned, config, world, writer) is None
