"""The managed node through its real lifecycle services and topics (doc/lifecycle.md).

Every transition goes through ``collision_node/change_state`` and every state is read through
``collision_node/get_state``, as a lifecycle manager or ``ros2 lifecycle`` does; inputs and
answers go through real pub/sub, parameters through the SetParameters service. The room of
ros_helpers gives hand-computed contacts; the stream test compares every answer with a
brute-force World. Nodes run in this process (one executor with the tester) or, for the
stream and the params file, as their own process.
"""
import os
import random
import subprocess
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseArray
from lifecycle_msgs.msg import Transition
import numpy as np
import pytest
from rcl_interfaces.srv import SetParameters
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.lifecycle import LifecyclePublisher
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_helpers import (BAD_YAML, check_room_contacts, COLLIDERS, EXPECTED, HALF, INPUT,
                         LifecycleClient, make_context, node_command, node_environment, POSITIONS,
                         REPO, room_poses, STATUS_NAME, values, write_params)
from sensor_msgs.msg import PointCloud2

from collision_node.benchmarks.params_files import write_scene_files
from collision_node.pipeline.world import DYNAMIC, STATIC, World
from collision_node.ros.cdr import serialize_pose_array
from collision_node.ros.lifetime import spin_until
from collision_node.ros.messages import cloud_to_contacts
from collision_node.tools.processes import stop_process

DOMAIN_ID = random.Random(os.getpid() + 32).randint(1, 200)
CONFIGURE, ACTIVATE = Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE
DEACTIVATE, CLEANUP = Transition.TRANSITION_DEACTIVATE, Transition.TRANSITION_CLEANUP
ABOVE = [0.0, 0.0, 3.0, 0.0, 0.0, 0.0, 1.0]  # where body 3 floats
PROCESS_TIMEOUT_S = 120.0  # a node process imports rclpy and numpy, then loads its kernels


def ids(cloud):
    return [(int(c['id_a']), int(c['type_b']), int(c['id_b'])) for c in cloud_to_contacts(cloud)]


def set_parameters(room, **parameters):
    """Set parameters through the node's SetParameters service, as `ros2 param set` does."""
    client = room.peer.create_client(SetParameters, 'collision_node/set_parameters')
    room.wait_for(client.service_is_ready, 'the set_parameters service')
    future = client.call_async(SetParameters.Request(parameters=[
        Parameter(name.replace('__', '.'), value=value).to_parameter_msg()
        for name, value in parameters.items()]))
    room.wait_for(future.done, 'the set_parameters answer')
    room.peer.destroy_client(client)
    return future.result().results


def test_the_default_start_answers_and_reports_active(harness):
    room = harness()
    assert room.lifecycle.state() == 'active'
    poses = room_poses()
    room.publish(poses, sec=1)
    check_room_contacts(room.answer(1), EXPECTED, poses)
    status = room.status(lambda s: values(s)['ticks'] != '0')
    assert status.level == DiagnosticStatus.OK, status.message
    assert values(status)['lifecycle_state'] == 'active'
    assert values(status)['ignored_inputs'] == '0'


def test_autostart_false_waits_until_configure_and_activate(harness):
    room = harness(autostart=False)
    assert room.lifecycle.state() == 'unconfigured'
    # Diagnostics in every state, saying that nothing is checked; no other endpoint yet.
    status = room.status()
    assert status.level == DiagnosticStatus.WARN
    assert status.message == 'unconfigured: not checking collisions'
    assert values(status)['lifecycle_state'] == 'unconfigured'
    assert room.peer.count_publishers('collisions') == 0
    assert room.poses.get_subscription_count() == 0
    assert room.node._world is None
    declared = set(vars(room.node))

    assert room.lifecycle.change(CONFIGURE)
    assert room.lifecycle.state() == 'inactive'
    assert set(vars(room.node)) == declared  # configure makes what __init__ declared, no more
    room.wait_connected()
    poses = room_poses()
    room.publish(poses, sec=1)  # configured but not active: counted, not answered
    status = room.status(lambda s: values(s)['ignored_inputs'] == '1')
    assert status.level == DiagnosticStatus.WARN
    assert status.message == 'inactive: not checking collisions, 1 inputs ignored'
    assert values(status)['lifecycle_state'] == 'inactive'

    assert room.lifecycle.change(ACTIVATE)
    assert room.lifecycle.state() == 'active'
    room.publish(poses, sec=2)
    check_room_contacts(room.answer(2), EXPECTED, poses)  # the first answer: never 1
    status = room.status(lambda s: values(s)['ticks'] != '0')
    assert status.level == DiagnosticStatus.OK
    assert values(status)['lifecycle_state'] == 'active'


def test_deactivate_stops_the_answers_and_activate_resumes_them(harness):
    room = harness()
    statics = room.peer.create_publisher(PoseArray, 'static_poses', INPUT)
    room.wait_for(lambda: statics.get_subscription_count() == 1)
    poses = room_poses()
    room.publish(poses, sec=1)
    check_room_contacts(room.answer(1), EXPECTED, poses)

    assert room.lifecycle.change(DEACTIVATE)
    assert room.lifecycle.state() == 'inactive'
    for sec in (2, 3, 4):
        room.publish(poses, sec=sec)
    status = room.status(lambda s: values(s)['ignored_inputs'] == '3')
    assert status.level == DiagnosticStatus.WARN and 'not checking' in status.message
    # The scene can still change: run-time parameters and static_poses; start-only parameters
    # stay read-only until cleanup.
    assert all(result.successful for result in set_parameters(room, wall__enabled=False))
    refused, = set_parameters(room, frame_id='map')
    assert not refused.successful and 'read-only' in refused.reason
    moved = np.array([pose for pose, _ in COLLIDERS.values()])
    moved[2] = ABOVE  # the crate jumps onto body 3 and leaves body 4
    statics.publish(serialize_pose_array(0, 0, 'world', moved))
    room.status(lambda s: values(s)['scene_version'] == '2')  # the wall, then the crate
    assert not room.clouds

    assert room.lifecycle.change(ACTIVATE)
    room.publish(poses, sec=5)
    assert ids(room.answer(5)) == [(0, STATIC, 0), (1, DYNAMIC, 2), (3, STATIC, 2)]
    status = room.status(lambda s: values(s)['ticks'] != '0')
    assert status.level == DiagnosticStatus.OK
    assert values(status)['ignored_inputs'] == '3' and values(status)['dropped_inputs'] == '0'
    assert not room.clouds  # 2, 3 and 4 were not kept for later


def test_cleanup_releases_the_world_and_configure_reads_the_parameters_again(harness):
    room = harness()
    poses = room_poses()
    room.publish(poses, sec=1)
    room.answer(1)
    assert room.lifecycle.change(DEACTIVATE) and room.lifecycle.change(CLEANUP)
    assert room.lifecycle.state() == 'unconfigured'
    room.wait_for(lambda: room.peer.count_publishers('collisions') == 0
                  and room.poses.get_subscription_count() == 0, 'the endpoints to go')
    assert room.node._world is None
    made = ('_subscription', '_collisions_publisher', '_markers_publisher', '_states_publisher',
            '_trajectory_publisher', '_cloud_writer', '_states_writer', '_marker_writer',
            '_tick_timer', '_pending', '_last_sequence')
    assert [name for name in made if getattr(room.node, name) is not None] == []
    # Unconfigured, a start-only parameter may be set; configure checks and applies it.
    assert all(result.successful for result in set_parameters(room, max_bodies=4))
    assert room.lifecycle.change(CONFIGURE) and room.lifecycle.change(ACTIVATE)
    room.wait_connected()
    room.publish(poses, sec=2)
    status = room.status(lambda s: values(s)['rejected_inputs'] == '1')
    assert values(status)['last_rejection'] == 'dynamic_poses: 5 poses exceed max_bodies 4'
    four = room_poses(POSITIONS[:4])
    room.publish(four, sec=3)
    check_room_contacts(room.answer(3), EXPECTED[:3], four)


def test_a_scene_file_is_read_again_by_each_configure(harness, tmp_path):
    files = write_scene_files(tmp_path, [ABOVE], [[0.3, 0.3, 0.3]], np.full((5, 3), HALF),
                              names=['pillar'])
    room = harness(**files)
    listed = list(COLLIDERS)
    assert room.node.get_parameter('static_colliders').value == ['pillar'] + listed
    poses = room_poses()
    room.publish(poses, sec=1)
    with_pillar = [(0, STATIC, 1), (1, DYNAMIC, 2), (1, STATIC, 2), (3, STATIC, 0),
                   (4, STATIC, 3)]
    assert ids(room.answer(1)) == with_pillar
    assert room.lifecycle.change(DEACTIVATE) and room.lifecycle.change(CLEANUP)
    assert room.node.get_parameter('static_colliders').value == listed
    assert room.lifecycle.change(CONFIGURE) and room.lifecycle.change(ACTIVATE)
    assert room.node.get_parameter('static_colliders').value == ['pillar'] + listed
    room.wait_connected()
    room.publish(poses, sec=2)
    assert ids(room.answer(2)) == with_pillar


@pytest.mark.parametrize('name, bad, good, reason', [
    ('broad_phase', 'bvh', 'grid', "unknown broad phase 'bvh'"),  # run time
    ('tick_rate_hz', -5.0, 0.0, 'must be in [0.0, 1000.0], got -5.0'),  # start-only
    # rclpy cannot declare it as a double: declared at its default, the error kept.
    ('input_timeout_s', 2, 0.0, 'must be of type double (write 1.0, not 1), got integer'),
    ('crate.pose', [-2.0, 0.0, 0.5, 0.0, 0.0, 0.0, 0.0], COLLIDERS['crate'][0], 'quaternion'),
])
def test_a_bad_parameter_fails_configure_and_the_node_lives_on(harness, name, bad, good, reason):
    room = harness(autostart=False, **{name: bad})
    assert not room.lifecycle.change(CONFIGURE)
    assert room.lifecycle.state() == 'unconfigured'
    status = room.status(lambda s: 'configure failed' in s.message)
    assert status.level == DiagnosticStatus.ERROR
    assert status.message.startswith(
        "unconfigured: not checking collisions; configure failed: parameter '%s': " % name)
    assert reason in status.message
    assert room.node._world is None and room.peer.count_publishers('collisions') == 0

    result, = set_parameters(room, **{name.replace('.', '__'): good})
    assert result.successful, result.reason
    assert room.lifecycle.change(CONFIGURE) and room.lifecycle.change(ACTIVATE)
    room.wait_connected()
    poses = room_poses()
    room.publish(poses, sec=1)
    check_room_contacts(room.answer(1), EXPECTED, poses)
    assert room.status(lambda s: values(s)['ticks'] != '0').level == DiagnosticStatus.OK


def test_every_input_is_gated_and_every_answer_is_a_lifecycle_publisher(harness):
    """The gate is one mechanism: a new input topic made by _create_input has it too."""
    node = harness().node
    subscriptions = list(node.subscriptions)
    assert sorted(s.topic_name.rsplit('/', 1)[1] for s in subscriptions) == [
        'check_states', 'check_trajectory', 'dynamic_poses', 'joint_states', 'robot_description',
        'robot_description_semantic', 'static_poses']
    assert all(getattr(s.callback, 'lifecycle_gated', False) for s in subscriptions)
    managed = {p.topic_name.rsplit('/', 1)[1]: isinstance(p, LifecyclePublisher)
               for p in node.publishers}
    assert managed == {'collisions': True, 'markers': True, 'state_collisions': True,
                       'trajectory_collisions': True, 'diagnostics': False,
                       'parameter_events': False}


def test_an_input_waiting_for_the_timer_is_ignored_at_deactivate(harness):
    room = harness(tick_rate_hz=0.01)  # a tick every 100 s: none comes during the test
    room.publish(room_poses(), sec=1)
    room.wait_for(lambda: room.node._pending is not None, 'the input to wait for the timer')
    assert room.lifecycle.change(DEACTIVATE)
    assert room.node._pending is None
    room.status(lambda s: values(s)['ignored_inputs'] == '1')
    assert room.lifecycle.change(ACTIVATE)
    assert room.node._pending is None and not room.clouds


def test_the_endpoints_watch_no_qos_events(harness):
    """Each watcher costs the executor ~4.5 µs on every wake-up (NO_PUBLISHER_EVENTS)."""
    room = harness()
    ours = [e for e in list(room.node.subscriptions) + list(room.node.publishers)
            if e.topic_name != '/parameter_events']  # rclpy's own
    names = {e.topic_name.rsplit('/', 1)[-1] for e in ours}
    assert {'dynamic_poses', 'static_poses', 'check_states', 'collisions', 'state_collisions',
            'diagnostics'} <= names
    assert all(e.event_handlers == [] for e in ours)


def test_main_loop_answers_until_shutdown_and_keeps_nothing_per_message(harness):
    room = harness()
    held = []  # callbacks the finalized future holds, at each input

    def publish_or_shut_down():
        held.append(len(room.node.finalized._callbacks))
        if len(held) <= 300:
            room.publish(room_poses(), sec=len(held))
        else:
            room.node.trigger_shutdown()

    room.peer.create_timer(0.001, publish_or_shut_down)
    spin_until(room.executor, room.node, room.node.finalized)  # main()'s loop
    assert room.node.finalized.done() and room.node._world is None  # the shutdown ran whole
    assert len(room.clouds) > 0
    # rclpy.spin_until_future_complete would hold one more at every wake-up of the executor.
    assert max(held) == 0


def test_shutdown_releases_everything_and_finalizes(harness):
    room = harness()
    assert not room.node.finalized.done()
    refused = room.node.set_parameters([Parameter('autostart', value=False)])[0]
    assert not refused.successful and 'read-only' in refused.reason
    assert room.lifecycle.change('shutdown')  # the label: from whichever state it is in
    assert room.lifecycle.state() == 'finalized'
    assert room.node.finalized.done()  # main() ends the process on it
    assert room.node._world is None
    room.wait_for(lambda: room.peer.count_publishers('collisions') == 0
                  and room.poses.get_subscription_count() == 0, 'the endpoints to go')
    status = room.status(lambda s: values(s)['lifecycle_state'] == 'finalized')
    assert status.level == DiagnosticStatus.WARN


# As their own process: the node started by its command line, spun by its own main().

def room_yaml(*lines):
    """Return a params file body with the room's colliders, and ``lines`` after them."""
    body = ['static_colliders: [%s]' % ', '.join(COLLIDERS),
            'dynamic:', '  half_extents: [%r, %r, %r]' % (HALF, HALF, HALF),
            'diagnostic_updater:', '  period: 0.1', 'input_timeout_s: 0.0']
    for name, (pose, extents) in COLLIDERS.items():
        body += ['%s:' % name, '  pose: %s' % pose, '  half_extents: %s' % extents]
    return '\n'.join(body + list(lines)) + '\n'


class Peer:
    """A test node in its own context, talking to a node process on the module's domain."""

    def __init__(self, input_depth=1):
        self.context = make_context(DOMAIN_ID)
        self.node = rclpy.create_node('lifecycle_tester', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        qos = QoSProfile(depth=input_depth, reliability=ReliabilityPolicy.RELIABLE)
        self.poses = self.node.create_publisher(PoseArray, 'dynamic_poses', qos)
        self.clouds, self.statuses = [], []
        self.node.create_subscription(PointCloud2, 'collisions', self.clouds.append, qos)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', lambda message: (
            self.statuses.extend(s for s in message.status if s.name == STATUS_NAME)), qos)
        self.lifecycle = LifecycleClient(self.node, self.wait_for)
        self.process = None

    def start(self, tmp_path, body):
        log = tmp_path / 'node.log'
        with open(log, 'w') as stream:
            self.process = subprocess.Popen(
                node_command('--params-file', write_params(tmp_path / 'p.yaml', body)),
                cwd=REPO, env=node_environment(DOMAIN_ID), stdout=stream,
                stderr=subprocess.STDOUT)
        self.log = log

    def wait_for(self, condition, what='condition', timeout_s=PROCESS_TIMEOUT_S):
        deadline = time.monotonic() + timeout_s
        while not condition():
            assert self.process is None or self.process.poll() is None, self.log.read_text()
            assert time.monotonic() < deadline, 'timed out waiting for %s' % what
            self.executor.spin_once(timeout_sec=0.01)

    def close(self):
        if self.process is not None:
            stop_process(self.process, 10.0)
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


@pytest.fixture
def peer():
    made = []

    def make(**options):
        made.append(Peer(**options))
        return made[-1]
    yield make
    for one in made:
        one.close()


def test_a_process_on_a_bad_params_file_waits_is_fixed_and_shuts_down(peer, tmp_path):
    tester = peer()
    tester.start(tmp_path, BAD_YAML['broad_phase'] + 'autostart: false\n')
    assert tester.lifecycle.state() == 'unconfigured'
    assert not tester.lifecycle.change(CONFIGURE)
    assert tester.lifecycle.state() == 'unconfigured'  # alive, and still answering
    assert tester.node.count_publishers('/collisions') == 0

    client = tester.node.create_client(SetParameters, 'collision_node/set_parameters')
    tester.wait_for(client.service_is_ready, 'the set_parameters service')
    future = client.call_async(SetParameters.Request(parameters=[
        Parameter('broad_phase', value='brute_force').to_parameter_msg()]))
    tester.wait_for(future.done, 'the set_parameters answer')
    assert future.result().results[0].successful
    assert tester.lifecycle.change(CONFIGURE) and tester.lifecycle.change(ACTIVATE)
    tester.wait_for(lambda: tester.poses.get_subscription_count() == 1
                    and tester.node.count_publishers('/collisions') == 1, 'the endpoints')
    # GOOD_YAML: frame map, body 0 (0.1 x 0.2 x 0.3) into the table, body 1 far away.
    tester.poses.publish(serialize_pose_array(7, 0, 'map', np.array([
        [0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 1.0], [5.0, 5.0, 5.0, 0.0, 0.0, 0.0, 1.0]])))
    tester.wait_for(lambda: tester.clouds, 'the answer')
    assert tester.clouds[0].header.stamp.sec == 7
    assert ids(tester.clouds[0]) == [(0, STATIC, 0)]

    assert tester.lifecycle.change('shutdown')
    assert tester.process.wait(PROCESS_TIMEOUT_S) == 0  # finalized: a clean exit
    log = tester.log.read_text()
    assert "configure failed: parameter 'broad_phase': unknown broad phase 'bvh'" in log
    assert 'Traceback' not in log


# A stream of distinct inputs with a deactivate and an activate in the middle, the node in its
# own process with its own executor. Every input gets its own random poses; the input queue
# (qos_overrides) and the tester's queues are as deep as the stream, so nothing is lost on the
# way and every input must be either answered, and correctly, or counted as ignored.
STREAM = 400
STREAM_PERIOD_S = 0.005  # between inputs
DEACTIVATE_AT, ACTIVATE_AT = 120, 260  # inputs sent before each request


def random_poses(rng, count):
    poses = np.empty((count, 7))
    poses[:, :3] = rng.uniform(-2.5, 2.5, (count, 3))
    quaternions = rng.normal(size=(count, 4))
    poses[:, 3:] = quaternions / np.linalg.norm(quaternions, axis=1, keepdims=True)
    return poses


def test_transitions_during_a_stream_lose_nothing_and_mix_nothing(peer, tmp_path):
    tester = peer(input_depth=STREAM)
    tester.start(tmp_path, room_yaml(
        'qos_overrides:', '  /dynamic_poses:', '    subscription:', '      depth: %d' % STREAM))
    # A status received: /diagnostics is matched too, so every tick of the stream is counted.
    tester.wait_for(lambda: tester.poses.get_subscription_count() == 1
                    and tester.node.count_publishers('/collisions') == 1 and tester.statuses,
                    'the node')
    assert tester.lifecycle.state() == 'active'
    rng = np.random.default_rng(32)
    inputs = [random_poses(rng, int(rng.integers(0, 12))) for _ in range(STREAM)]
    reference = World(broad_phase='brute_force')
    reference.set_static([pose for pose, _ in COLLIDERS.values()],
                         [extents for _, extents in COLLIDERS.values()])
    expected = [reference.step(poses, [HALF] * 3).contacts.copy() for poses in inputs]
    assert sum(map(len, expected)) > STREAM  # the answers differ from input to input

    sent = {}  # transition: inputs published when it was requested, and when it was answered
    transitions = {}
    for k, poses in enumerate(inputs):
        for name, at, transition in (('deactivate', DEACTIVATE_AT, DEACTIVATE),
                                     ('activate', ACTIVATE_AT, ACTIVATE)):
            if k == at:
                transitions[name] = tester.lifecycle.change_async(transition)
                sent[name] = (k, None)
        tester.poses.publish(serialize_pose_array(k, 0, 'world', poses))
        deadline = time.monotonic() + STREAM_PERIOD_S
        while time.monotonic() < deadline:
            tester.executor.spin_once(timeout_sec=STREAM_PERIOD_S / 5)
            for name, future in transitions.items():
                if future.done() and sent[name][1] is None:
                    sent[name] = (sent[name][0], k + 1)
        if k + 1 == ACTIVATE_AT:
            assert sent['deactivate'][1] is not None, 'deactivate took the whole inactive part'
    tester.wait_for(lambda: all(future.done() for future in transitions.values()), 'transitions')
    assert all(future.result().success for future in transitions.values())
    tester.wait_for(lambda: tester.clouds and tester.clouds[-1].header.stamp.sec == STREAM - 1,
                    'the answer to the last input')

    answered = [cloud.header.stamp.sec for cloud in tester.clouds]
    assert answered == sorted(set(answered)), 'answers out of order or twice'
    for cloud in tester.clouds:  # each answer is that of its own input
        contacts, want = cloud_to_contacts(cloud), expected[cloud.header.stamp.sec]
        for field in ('id_a', 'type_a', 'id_b', 'type_b'):
            np.testing.assert_array_equal(contacts[field], want[field])
        np.testing.assert_allclose(contacts['depth'], want['depth'], rtol=1e-6, atol=1e-5)
    ignored = sorted(set(range(STREAM)) - set(answered))
    first, last = ignored[0], ignored[-1]
    print('deactivate requested before input %d, answered before %d; activate %d, %d; '
          'ignored inputs %d..%d' % (*sent['deactivate'], *sent['activate'], first, last))
    # One run of ignored inputs: the node took the inputs in order, answering each whole until
    # the deactivate and again from the activate on. Inputs in flight at a switch may fall on
    # either side of it: those sent before the deactivate request, and the last one sent before
    # the activate request (the request may overtake it). Every other input sent while the node
    # was inactive is ignored, and every input sent after the activate's answer is answered.
    assert ignored == list(range(first, last + 1)), 'the gate opened or closed more than once'
    assert first <= sent['deactivate'][1] and last >= ACTIVATE_AT - 2
    assert last < sent['activate'][1]

    def counted():
        statuses = [values(status) for status in tester.statuses]
        return statuses and sum(int(v['ticks']) for v in statuses) == len(answered) \
            and statuses[-1]['ignored_inputs'] == str(len(ignored))
    tester.wait_for(counted, 'the diagnostics to count every input')
    final = values(tester.statuses[-1])
    assert (final['dropped_inputs'], final['rejected_inputs']) == ('0', '0')
    assert final['lifecycle_state'] == 'active'
