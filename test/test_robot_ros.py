"""The robot through real pub/sub: a model, joint_states in, collisions out, whole trajectories.

The Panda of example-robot-data in the room of ros_helpers, its base 1.3 m along x so that it
reaches the wall. Every answer is compared with a World built in the test like the node's
(its check_joints and check_trajectory, which test_robot_world.py referees); the model comes
from the parameters (one node shared by most tests) or from transient-local topics published
before and after the node starts.
"""
import os
import random
import sysconfig

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseArray
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)
from rclpy.serialization import deserialize_message
from ros_helpers import COLLIDERS, Harness, room_overrides, room_poses, values
from sensor_msgs.msg import JointState, PointCloud2
from std_msgs.msg import String
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
from visualization_msgs.msg import MarkerArray

from collision_node import Robot, World
from collision_node.pipeline.contacts import CONTACT_DTYPE
from collision_node.pipeline.warm_up import WARM_UP_ROBOT
from collision_node.ros.joints import JointInputError, JointValues
from collision_node.ros.markers import MarkerWriter
from collision_node.ros.messages import CLOUD_DTYPE, cloud_to_contacts, STATE_CLOUD_DTYPE
from collision_node.ros.params import ParameterError

DOMAIN_ID = random.Random(os.getpid() + 36).randint(1, 200)
PREFIX = os.path.join(sysconfig.get_paths()['purelib'], 'cmeel.prefix')
PANDA = os.path.join(PREFIX, 'share', 'example-robot-data', 'robots', 'panda_description')
URDF = open(os.path.join(PANDA, 'urdf', 'panda.urdf')).read()
SRDF = open(os.path.join(PANDA, 'srdf', 'panda.srdf')).read()
BASE = [1.3, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]  # the wall (x from 1.9) within reach
ARM = ['panda_joint%d' % i for i in range(1, 8)]
GRIPPER = ['panda_finger_joint1', 'panda_finger_joint2']  # the second one mimics the first
KEEP_ALL = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
BEST_EFFORT = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)


@pytest.fixture(scope='module')
def panda():
    return Robot.from_urdf(URDF, srdf=SRDF, package_paths=[os.path.join(PREFIX, 'share')])


def node_world(robot):
    """Return a World as the node builds it from room_overrides, with the robot."""
    world = World()
    world.set_static([pose for pose, _ in COLLIDERS.values()],
                     [extents for _, extents in COLLIDERS.values()])
    world.set_robot(robot, BASE)
    return world


class RobotPeer:
    """The tester's side: joint_states from an arm and a gripper, trajectory requests.

    The arm's publisher is reliable, the gripper's best effort: the node must match both.
    """

    def __init__(self, room):
        self.room = room
        peer = room.peer
        self.arm = peer.create_publisher(JointState, 'joint_states', RELIABLE)
        self.gripper = peer.create_publisher(JointState, 'joint_states', BEST_EFFORT)
        self.requests = peer.create_publisher(JointTrajectory, 'check_trajectory', KEEP_ALL)
        self.answers = []
        peer.create_subscription(PointCloud2, 'trajectory_collisions', self.answers.append,
                                 KEEP_ALL)
        room.wait_for(lambda: self.arm.get_subscription_count() == 1
                      and self.gripper.get_subscription_count() == 1
                      and self.requests.get_subscription_count() == 1
                      and peer.count_publishers('trajectory_collisions') == 1,
                      'reliable and best-effort joint_states publishers matched')

    def joints(self, publisher, names, positions, sec):
        message = JointState(name=list(names), position=[float(p) for p in positions])
        message.header.stamp.sec = sec
        publisher.publish(message)

    def state(self, q, sec):
        """Publish the whole robot's q (dof,) from the arm publisher."""
        self.joints(self.arm, ARM + GRIPPER[:1], q, sec)

    def trajectory(self, joint_names, points, sec):
        message = JointTrajectory(joint_names=list(joint_names), points=[
            JointTrajectoryPoint(positions=[float(p) for p in point]) for point in points])
        message.header.stamp.sec = sec
        self.requests.publish(message)

    def answer(self, sec):
        self.room.wait_for(lambda: self.answers, 'trajectory_collisions stamped %d' % sec)
        cloud = self.answers.pop(0)
        assert cloud.header.stamp.sec == sec
        return cloud


def as_points(contacts, dtype):
    points = np.empty(len(contacts), dtype)
    for name in dtype.names:
        points[name] = contacts[name]
    return points


def assert_points_equal(got, want):
    assert got.dtype == want.dtype and len(got) == len(want)
    for name in want.dtype.names:
        np.testing.assert_array_equal(got[name], want[name], err_msg=name)


def joints_answer(world, q):
    """Return the collisions points the node must send for q: check_joints, no state."""
    return as_points(world.check_joints(q).contacts, CLOUD_DTYPE)


def random_q(robot, rng, count):
    limits = robot.joint_limits
    return rng.uniform(limits[:, 0], limits[:, 1], (count, robot.dof))


def rejection(room, text):
    return room.status(lambda s: text in values(s)['last_rejection'])


@pytest.fixture(scope='module')
def robot_room(context):
    """Make the node with the Panda from its parameters (meshes through package_paths)."""
    room = Harness(context, **room_overrides(**{
        'robot_description': URDF, 'robot_description_semantic': SRDF,
        'robot_description_package_paths': [os.path.join(PREFIX, 'share')],
        'robot_base_pose': BASE}))
    room.robot = RobotPeer(room)
    yield room
    room.close()


def test_joint_values_merge_partial_messages_by_name():
    joints = JointValues(['a', 'b', 'c'])
    assert joints.missing == ['a', 'b', 'c']
    joints.merge(['b', 'x'], [2.0, 7.0])  # x is not a joint: ignored
    joints.merge(['a'], [])  # no positions (a velocity-only message): nothing changes
    assert joints.missing == ['a', 'c']
    with pytest.raises(JointInputError, match='no joint_states value yet for a, c'):
        joints.q()
    joints.merge(['c', 'a'], [3.0, 1.0])
    np.testing.assert_array_equal(joints.q(), [1.0, 2.0, 3.0])
    for names, positions, reason in ((['a', 'b'], [1.0], '2 names but 1 positions'),
                                     (['a', 'b'], [1.0, np.inf], "joint 'b': position inf")):
        with pytest.raises(JointInputError, match=reason):
            joints.merge(names, positions)
    np.testing.assert_array_equal(joints.q(), [1.0, 2.0, 3.0])  # a refused message changes nothing
    kept = JointValues(['c', 'd'], previous=joints)  # a new model keeps the shared joints
    assert kept.missing == ['d']
    np.testing.assert_array_equal(
        joints.waypoints(['c'], [[5.0], [6.0]]), [[1.0, 2.0, 5.0], [1.0, 2.0, 6.0]])
    for names, points, reason in ((['c', 'z'], [[1.0, 2.0]], r"joint_names\[1\] 'z' is not"),
                                  (['c', 'c'], [[1.0, 2.0]], 'given twice'),
                                  (['a', 'b'], [[1.0, 2.0], [1.0]], 'waypoint 1: 1 positions'),
                                  (['a', 'b'], [[1.0, 2.0], [1.0, np.nan]],
                                   "waypoint 1: joint 'b': position nan")):
        with pytest.raises(JointInputError, match=reason):
            joints.waypoints(names, points)
    with pytest.raises(JointInputError, match="joint 'd' is not in joint_names and has no"):
        kept.waypoints(['c'], [[0.0]])
    joints.merge(('a', 'x', 'a'), [4.0, 5.0, 6.0])  # a name given twice: its last value
    names = ('c', 'b')
    for positions in ([7.0, 8.0], [9.0, 10.0]):  # the same names again, the same object
        joints.merge(names, positions)
    np.testing.assert_array_equal(joints.q(), [6.0, 10.0, 9.0])
    joints.merge(['b'], [11.0])  # other names after them
    np.testing.assert_array_equal(joints.q(), [6.0, 11.0, 9.0])


def test_markers_name_each_box_by_its_link():
    writer = MarkerWriter('world')
    writer.name_bodies(['base', 'a_long_link_name', 'base'])
    poses = np.zeros((3, 7))
    poses[:, 0], poses[:, 6] = np.arange(3), 1.0
    contacts = np.zeros(1, CONTACT_DTYPE)
    contacts['normal_x'] = 1.0
    markers = deserialize_message(writer.serialize(
        4, 5, np.array([[0.0, 0, 0, 0, 0, 0, 1]]), np.ones((1, 3)), np.array([9]), poses,
        np.full(3, 0.1), contacts), MarkerArray).markers
    assert [(m.ns, m.id, m.pose.position.x) for m in markers[2:5]] == [
        ('dynamic/base', 0, 0.0), ('dynamic/base', 2, 2.0), ('dynamic/a_long_link_name', 1, 1.0)]
    assert markers[1].ns == 'static' and markers[5].ns == 'normals'
    assert all(m.header.stamp.sec == 4 for m in markers)


def test_model_from_parameters_lists_each_box_link(robot_room, panda):
    status = robot_room.status(lambda s: values(s)['box_links'] != '')
    found = values(status)
    assert found['robot'] == '8 joints, 17 boxes'
    assert found['box_links'] == ' '.join('%d:%s' % item for item in enumerate(panda.box_links))
    assert found['missing_joints'] == ' '.join(panda.joint_names)


def test_partial_joint_states_from_two_publishers_are_merged(robot_room, panda):
    world, peer = node_world(panda), robot_room.robot
    arm, gripper = random_q(panda, np.random.default_rng(1), 2)
    peer.joints(peer.arm, ARM, arm[:7], 100)  # the gripper has no value yet: no answer
    status = robot_room.status(lambda s: values(s)['missing_joints'] == 'panda_finger_joint1')
    assert status.level == DiagnosticStatus.WARN and 'panda_finger_joint1' in status.message
    assert not robot_room.clouds
    peer.joints(peer.gripper, GRIPPER, [gripper[7], gripper[7]], 101)  # best effort
    q = np.concatenate([arm[:7], gripper[7:]])
    assert_points_equal(cloud_to_contacts(robot_room.answer(101)), joints_answer(world, q))
    peer.joints(peer.arm, ARM, gripper[:7], 102)  # the gripper keeps its value
    assert_points_equal(cloud_to_contacts(robot_room.answer(102)), joints_answer(world, gripper))
    status = robot_room.status(lambda s: values(s)['missing_joints'] == '')
    assert int(values(status)['dynamic_bodies']) == 17


def test_each_joint_state_is_answered_as_check_joints(robot_room, panda):
    world, peer = node_world(panda), robot_room.robot
    states = random_q(panda, np.random.default_rng(2), 30)
    states[:, 0] = np.linspace(-2.8, 2.8, len(states))  # turning: into the wall and back
    answers = []
    for sec, q in enumerate(states, start=200):
        peer.state(q, sec)
        cloud = robot_room.answer(sec)
        assert cloud.header.frame_id == 'world'
        got = cloud_to_contacts(cloud)
        assert_points_equal(got, joints_answer(world, q))
        answers.append(got)
    floor, wall = 0, 1  # static ids; link0 stands on the floor
    assert all(floor in a['id_b'][a['type_b'] == 1] for a in answers)
    assert any(wall in a['id_b'][a['type_b'] == 1] for a in answers)  # not vacuous


def test_bad_joint_states_are_refused_and_not_answered(robot_room, panda):
    peer = robot_room.robot
    q = random_q(panda, np.random.default_rng(3), 1)[0]
    peer.state(q, 300)
    robot_room.answer(300)
    for sec, (names, positions, reason) in enumerate((
            (ARM, q[:6], 'joint_states: 7 names but 6 positions'),
            (ARM, [np.nan] + list(q[1:7]), "joint_states: joint 'panda_joint1': position nan")),
            start=301):
        peer.joints(peer.arm, names, positions, sec)
        status = rejection(robot_room, reason)
        assert int(values(status)['rejected_inputs']) >= 1
    peer.state(q, 310)  # the next good one is the next answer
    robot_room.answer(310)


def test_trajectories_are_answered_once_each_in_order(robot_room, panda):
    world, peer = node_world(panda), robot_room.robot
    rng = np.random.default_rng(4)
    current = random_q(panda, rng, 1)[0]
    peer.state(current, 400)
    robot_room.answer(400)
    sent = {}
    for sec, count in enumerate((2, 1, 0, 6), start=401):
        waypoints = random_q(panda, rng, count)
        peer.trajectory(ARM + GRIPPER[:1], waypoints, sec)
        sent[sec] = waypoints
    # A partial one: only joints 2 and 4 move, the others keep their joint_states values.
    partial = rng.uniform(-1.0, 1.0, (4, 2))
    peer.trajectory(['panda_joint4', 'panda_joint2'], partial, 405)
    full = np.tile(current, (4, 1))
    full[:, 3], full[:, 1] = partial[:, 0], partial[:, 1]
    sent[405] = full
    for sec, waypoints in sent.items():
        got = cloud_to_contacts(peer.answer(sec))
        assert got.dtype == STATE_CLOUD_DTYPE
        want = world.check_trajectory(waypoints.reshape(-1, panda.dof)).contacts
        assert_points_equal(got, as_points(want, STATE_CLOUD_DTYPE))
        assert len(waypoints) == 0 or len(got)  # the floor at least: not vacuous
    robot_room.wait_for(lambda: robot_room.statuses, 'a status')
    assert not peer.answers  # once each


def test_bad_trajectories_get_no_answer_and_a_reason(robot_room, panda):
    peer = robot_room.robot
    good = random_q(panda, np.random.default_rng(5), 3)
    nan = good.copy()
    nan[2, 4] = np.nan
    for sec, (names, points, reason) in enumerate((
            (ARM + ['elbow'], good, "check_trajectory: joint_names[7] 'elbow' is not a joint"),
            (ARM + GRIPPER[:1], [good[0], good[1][:5]],
             'check_trajectory: waypoint 1: 5 positions'),
            (ARM + GRIPPER[:1], nan, "check_trajectory: waypoint 2: joint 'panda_joint5': "
                                     'position nan')), start=500):
        peer.trajectory(names, points, sec)
        rejection(robot_room, reason)
    world = node_world(panda)
    peer.trajectory(ARM + GRIPPER[:1], good, 510)
    assert_points_equal(cloud_to_contacts(peer.answer(510)),
                        as_points(world.check_trajectory(good).contacts, STATE_CLOUD_DTYPE))


def test_pose_arrays_are_refused_while_a_robot_is_loaded(robot_room):
    robot_room.publish(room_poses(), 600)
    rejection(robot_room, 'dynamic_poses: refused while a robot model is loaded')
    requests = robot_room.peer.create_publisher(PoseArray, 'check_states', KEEP_ALL)
    robot_room.wait_for(lambda: requests.get_subscription_count() == 1)
    requests.publish(PoseArray())
    rejection(robot_room, 'check_states: refused while a robot model is loaded')
    assert not robot_room.clouds


def test_a_continuous_node_sweeps_the_robot_between_joint_states(robot_room, panda):
    # Continuous on, each message is a step of the boxes, swept since the message before;
    # off, the robot's pass checks the state alone (the tests above).
    node, peer = robot_room.node, robot_room.robot
    world = node_world(panda)
    world.continuous = True
    states = random_q(panda, np.random.default_rng(4), 8)
    states[:, 0] = np.linspace(-2.8, 2.8, len(states))  # through the wall between messages
    assert node.set_parameters([Parameter('continuous', value=True)])[0].successful
    try:
        swept = 0
        for sec, q in enumerate(states, start=650):
            expected = world.step(world.robot_poses(q)[0], panda.half_extents).contacts
            peer.state(q, sec)
            got = cloud_to_contacts(robot_room.answer(sec))
            if sec > 650:  # the first one sweeps from the node's last step, if any
                assert_points_equal(got, as_points(expected, CLOUD_DTYPE))
                swept += len(got) > len(joints_answer(world, q))
        assert swept  # some pair touched only between two messages: not vacuous
    finally:
        assert node.set_parameters([Parameter('continuous', value=False)])[0].successful


def test_a_bad_model_parameter_stops_the_start_naming_it(context):
    bad = URDF.replace('link5.stl', 'link55.stl')
    with pytest.raises(ParameterError, match="parameter 'robot_description': link 'panda_link5': "
                                             "mesh '.*link55.stl' not found"):
        Harness(context, **room_overrides(**{
            'robot_description': bad,
            'robot_description_package_paths': [os.path.join(PREFIX, 'share')]}))


def test_models_from_topics_before_and_after_the_start(context, panda, monkeypatch):
    monkeypatch.setenv('AMENT_PREFIX_PATH', PREFIX)  # package:// through the ament index
    namespace = 'robot_topics'
    publisher = context_node(context, namespace)
    urdf = publisher.create_publisher(String, 'robot_description', LATCHED)
    srdf = publisher.create_publisher(String, 'robot_description_semantic', LATCHED)
    urdf.publish(String(data=URDF))  # before the node exists: kept for it
    srdf.publish(String(data=SRDF))
    room = Harness(context, namespace=namespace, **room_overrides(robot_base_pose=BASE))
    try:
        room.executor.add_node(publisher)
        status = room.status(lambda s: values(s)['box_links'] != '')
        assert values(status)['robot'] == '8 joints, 17 boxes'
        peer = RobotPeer(room)
        # No answer, and a WARN naming the missing joints, until every joint has a value.
        peer.joints(peer.arm, ARM, np.zeros(7), 700)
        status = room.status(lambda s: values(s)['missing_joints'] == 'panda_finger_joint1')
        assert status.level == DiagnosticStatus.WARN
        assert 'no answer until joint_states gives panda_finger_joint1' in status.message
        peer.trajectory(ARM, [np.zeros(7)], 701)  # the finger left out has no value
        rejection(room, "check_trajectory: joint 'panda_finger_joint1' is not in joint_names")
        assert not room.clouds and not peer.answers
        # A bad model is refused and the Panda stays.
        urdf.publish(String(data=URDF.replace('link5.stl', 'link55.stl')))
        status = room.status(lambda s: 'link55.stl' in values(s)['robot_refused'])
        assert values(status)['robot'] == '8 joints, 17 boxes'
        assert "robot_description: link 'panda_link5': mesh" in values(status)['last_rejection']
        urdf.publish(String(data='<robot name="broken">'))
        room.status(lambda s: values(s)['robot_refused'].startswith('robot_description: '))
        peer.joints(peer.gripper, GRIPPER[:1], [0.01], 702)
        q = np.zeros(8)
        q[7] = 0.01
        assert_points_equal(cloud_to_contacts(room.answer(702)),
                            joints_answer(node_world(panda), q))
        # A new robot after the start replaces it (its URDF refused with the Panda's SRDF
        # until no SRDF comes): its joints have no values yet.
        srdf.publish(String(data=''))
        urdf.publish(String(data=WARM_UP_ROBOT))
        status = room.status(lambda s: values(s)['robot'].endswith('boxes')
                             and values(s)['robot'] != '8 joints, 17 boxes')
        warm_up = Robot.from_urdf(WARM_UP_ROBOT)
        assert values(status)['box_links'] == ' '.join(
            '%d:%s' % item for item in enumerate(warm_up.box_links))
        assert values(status)['missing_joints'] == ' '.join(warm_up.joint_names)
    finally:
        room.close()
        publisher.destroy_node()


def context_node(context, namespace):
    import rclpy
    return rclpy.create_node('model_publisher', namespace=namespace, context=context)
