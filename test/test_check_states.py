"""check_states through real pub/sub: K states in one PoseArray, one state_collisions answer.

Every request gets exactly one answer with its stamp, in order, equal to World.check_states of
a World built like the node (which a World's steps of each state alone referee in
test_one_pass.py); a bad request gets no answer and a diagnostic naming the state and body at
fault; a thousand requests queued at once are all answered; the ticks on dynamic_poses are
unaffected; an inactive node answers none.
"""
import os
import random

from geometry_msgs.msg import PoseArray
from lifecycle_msgs.msg import Transition
import numpy as np
import pytest
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from ros_helpers import (_pose, check_room_contacts, COLLIDERS, EXPECTED, HALF, room_poses,
                         values)
from sensor_msgs.msg import PointCloud2

from collision_node.pipeline.world import World
from collision_node.ros.messages import cloud_to_contacts, STATE_CLOUD_DTYPE

DOMAIN_ID = random.Random(os.getpid() + 37).randint(1, 200)
BODIES = 5  # the room's dynamic bodies (ros_helpers.POSITIONS)
KEEP_ALL = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)


class Requests:
    """The tester's side of check_states: a request publisher and the answers it got."""

    def __init__(self, room):
        self.room = room
        self.publisher = room.peer.create_publisher(PoseArray, 'check_states', KEEP_ALL)
        self.answers = []
        room.peer.create_subscription(PointCloud2, 'state_collisions', self.answers.append,
                                      KEEP_ALL)
        room.wait_for(lambda: self.publisher.get_subscription_count() == 1
                      and room.peer.count_publishers('state_collisions') == 1)

    def send(self, states, sec, frame_id=''):
        message = PoseArray()
        message.header.stamp.sec, message.header.frame_id = sec, frame_id
        message.poses = [_pose(row) for row in np.asarray(states).reshape(-1, 7).tolist()]
        self.publisher.publish(message)

    def answer(self, sec):
        """Wait for the next answer; it must be stamped ``sec``."""
        self.room.wait_for(lambda: self.answers, 'state_collisions stamped %d' % sec)
        cloud = self.answers.pop(0)
        assert cloud.header.stamp.sec == sec
        return cloud


def room_world():
    world = World(broad_phase='brute_force')
    world.set_static([pose for pose, _ in COLLIDERS.values()],
                     [extents for _, extents in COLLIDERS.values()])
    return world


def random_states(rng, count):
    """``count`` states of the room's bodies: each shifted a little from the room's poses."""
    states = np.repeat(room_poses()[None], count, axis=0)
    states[:, :, :3] += rng.normal(0.0, 0.05, (count, BODIES, 3))
    return states


def expected(states):
    """Return the state_collisions points of ``states``, from a World like the node's."""
    contacts = room_world().check_states(states, [HALF] * 3).contacts
    points = np.empty(len(contacts), STATE_CLOUD_DTYPE)
    for name in STATE_CLOUD_DTYPE.names:
        points[name] = contacts[name]
    return points


@pytest.fixture
def room(harness):
    return harness(**{'check_states.bodies': BODIES})


def test_each_request_is_answered_with_every_state_in_order(room):
    requests = Requests(room)
    rng = np.random.default_rng(1)
    sent = {}
    for sec, count in enumerate((1, 4, 0, 17), start=10):
        sent[sec] = random_states(rng, count)
        requests.send(sent[sec], sec)
    for sec, states in sent.items():
        got = cloud_to_contacts(requests.answer(sec))
        assert got.dtype == STATE_CLOUD_DTYPE
        assert got.tobytes() == expected(states).tobytes()
        assert len(states) == 0 or len(got)  # the room's contacts: not vacuous
    status = room.status(lambda s: values(s)['states_checked'] != '0')
    assert int(values(status)['state_requests']) >= 1


def test_bad_requests_get_no_answer_and_a_diagnostic_naming_state_and_body(room):
    requests = Requests(room)
    states = random_states(np.random.default_rng(2), 4)
    nan = states.copy()
    nan[2, 3, 1] = np.nan
    zero_quaternion = states.copy()
    zero_quaternion[1, 0, 3:] = 0.0
    for sec, (bad, frame_id, reason) in enumerate((
            (nan, '', 'check_states: state 2: dynamic body 3: pose has a NaN'),
            (zero_quaternion, '', 'check_states: state 1: dynamic body 0: quaternion'),
            (states.reshape(-1, 7)[:7], '', '7 poses are not whole states of 5 bodies'),
            (states, 'map', "check_states: frame_id 'map' is not the node's")), start=20):
        requests.send(bad, sec, frame_id)
        status = room.status(lambda s: reason in values(s)['last_rejection'])
        assert int(values(status)['rejected_inputs']) >= 1
    requests.send(states, 30)  # the next good request is the next answer
    assert cloud_to_contacts(requests.answer(30)).tobytes() == expected(states).tobytes()


def test_a_request_past_max_bodies_is_refused(harness):
    room = harness(**{'check_states.bodies': BODIES, 'max_bodies': 10})
    requests = Requests(room)
    states = random_states(np.random.default_rng(3), 3)  # 15 poses
    requests.send(states, 40)
    room.status(lambda s: '15 poses exceed max_bodies 10' in values(s)['last_rejection'])
    requests.send(states[:2], 41)
    assert cloud_to_contacts(requests.answer(41)).tobytes() == expected(states[:2]).tobytes()


def test_one_size_for_all_needs_the_bodies_of_a_state(harness):
    room = harness()  # the room gives one size for all its bodies
    requests = Requests(room)
    requests.send(random_states(np.random.default_rng(4), 2), 50)
    room.status(lambda s: 'set check_states.bodies' in values(s)['last_rejection'])
    assert not requests.answers


def test_a_thousand_queued_requests_are_all_answered_in_order(room):
    requests = Requests(room)
    rng = np.random.default_rng(5)
    sent = [random_states(rng, int(rng.integers(0, 4))) for _ in range(1000)]
    for sec, states in enumerate(sent):  # all at once: they queue, none is dropped
        requests.send(states, sec)
    room.wait_for(lambda: len(requests.answers) == len(sent), 'a thousand answers',
                  timeout_s=120.0)
    clouds, requests.answers = requests.answers, []
    assert [cloud.header.stamp.sec for cloud in clouds] == list(range(len(sent)))
    got = [cloud_to_contacts(cloud) for cloud in clouds]
    want = [expected(states) for states in sent]
    assert all(g.tobytes() == w.tobytes() for g, w in zip(got, want))


def test_requests_between_ticks_leave_the_ticks_alone(room):
    requests = Requests(room)
    poses = room_poses()
    rng = np.random.default_rng(6)
    for sec in range(60, 66):
        room.publish(poses, sec)
        check_room_contacts(room.answer(sec), EXPECTED, poses)
        states = random_states(rng, 5)
        requests.send(states, sec)
        assert cloud_to_contacts(requests.answer(sec)).tobytes() == expected(states).tobytes()
    # The same input again after a request: the World reuses its last tick's answer.
    room.publish(poses, 70)
    check_room_contacts(room.answer(70), EXPECTED, poses)
    room.status(lambda s: values(s)['reused_result'] == 'true')


def test_an_inactive_node_answers_no_request(room):
    requests = Requests(room)
    states = random_states(np.random.default_rng(7), 3)
    room.lifecycle.change(Transition.TRANSITION_DEACTIVATE)
    requests.send(states, 80)
    room.status(lambda s: values(s)['lifecycle_state'] == 'inactive'
                and int(values(s)['ignored_inputs']) >= 1)
    room.lifecycle.change(Transition.TRANSITION_ACTIVATE)
    requests.send(states, 81)
    assert cloud_to_contacts(requests.answer(81)).tobytes() == expected(states).tobytes()
    assert not requests.answers  # the request sent while inactive was never answered
