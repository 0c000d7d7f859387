"""The console tools, run as processes: pose_publisher, collision_monitor and collision_demo."""
import os
import queue
import random
import re
import signal
import subprocess
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseArray
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header

from collision_node.pipeline.scenes import make_scene
from collision_node.ros.cdr import parse_pose_array
from collision_node.ros.messages import CLOUD_DTYPE, contacts_to_cloud
from collision_node.tools.collision_monitor import format_status

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOMAIN_ID = random.randint(1, 200)  # this module's own DDS domain: no cross-talk
TOOL_TIMEOUT_S = 60.0  # a process start imports rclpy and numpy: seconds on a busy machine
LISTENING = 'collision_monitor: listening to 1 collisions publisher(s); waiting up to %g s ' \
    'for an answer'
RELIABLE = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                      reliability=ReliabilityPolicy.RELIABLE)


def tool_environment():
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID), PYTHONUNBUFFERED='1')
    env['PYTHONPATH'] = os.pathsep.join(filter(None, [REPO, env.get('PYTHONPATH')]))
    return env


def start_tool(module, *arguments):
    return subprocess.Popen(
        [sys.executable, '-m', 'collision_node.tools.' + module, *arguments],
        env=tool_environment(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def run_tool(module, *arguments):
    return subprocess.run(
        [sys.executable, '-m', 'collision_node.tools.' + module, *arguments],
        env=tool_environment(), capture_output=True, text=True, timeout=TOOL_TIMEOUT_S)


@pytest.fixture(scope='module')
def ros():
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    node = rclpy.create_node('test_tools', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    yield node, executor
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown(context=context)


def spin_until(executor, done, timeout_s=TOOL_TIMEOUT_S, every=None):
    """Spin until ``done()``; ``every()`` runs between spins (e.g. to publish)."""
    deadline = time.monotonic() + timeout_s
    while not done() and time.monotonic() < deadline:
        if every is not None:
            every()
        executor.spin_once(timeout_sec=0.05)
    return done()


def receive_poses(ros, count, *arguments):
    """Run pose_publisher with ``arguments``; the parsed PoseArrays it sent, in order."""
    node, executor = ros
    received = []
    # Transient-local, as the publisher's --count runs: no message is lost to the order in
    # which the two ends discover each other.
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=count,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    subscription = node.create_subscription(
        PoseArray, 'dynamic_poses', received.append, qos, raw=True)
    try:
        process = start_tool('pose_publisher', '--count', str(count),
                             '--wait-for-subscriber', *arguments)
        spin_until(executor, lambda: len(received) >= count)
        _, errors = process.communicate(timeout=TOOL_TIMEOUT_S)
    finally:
        node.destroy_subscription(subscription)
    assert process.returncode == 0, errors
    assert len(received) == count, 'received %d of %d messages' % (len(received), count)
    return [parse_pose_array(buffer) for buffer in received]


def test_pose_publisher_sends_the_scene_as_it_is_at_each_stamp(ros):
    rate = 20.0
    messages = receive_poses(ros, 8, '--scene', 'room', '--bodies', '12', '--seed', '3',
                             '--rate', str(rate))
    scene = make_scene('room', 12, 3)
    stamps = np.array([m.sec * 10**9 + m.nanosec for m in messages])
    times = (stamps - stamps[0]) * 1e-9  # the scene's clock starts at the first message
    for message, time_s in zip(messages, times):
        assert message.frame_id == 'world'
        np.testing.assert_allclose(message.poses, scene.dynamic_poses(time_s), rtol=0,
                                   atol=1e-12)
    assert np.all(np.diff(times) > 0)
    # The rate is a timer's: loose bounds, the machine is shared.
    assert 0.5 / rate < np.median(np.diff(times)) < 2.0 / rate
    assert not np.allclose(messages[0].poses, messages[-1].poses), 'the scene should move'


@pytest.mark.parametrize('shape, count, order', [
    ((3, 4, 7), 5, [0, 1, 2, 0, 1]),   # a sequence, cycled
    ((5, 7), 2, [0, 0]),               # one frame, repeated
])
def test_pose_publisher_sends_npy_frames_exactly(ros, tmp_path, shape, count, order):
    frames = np.random.default_rng(7).normal(size=shape)
    path = tmp_path / 'frames.npy'
    np.save(path, frames)
    messages = receive_poses(ros, count, '--npy', str(path), '--rate', '50',
                             '--frame-id', 'map')
    frames = frames.reshape(-1, frames.shape[-2], 7)
    for message, k in zip(messages, order):
        assert message.frame_id == 'map'
        np.testing.assert_array_equal(message.poses, frames[k])


@pytest.mark.parametrize('content, arguments, complaint', [
    (np.zeros((4, 6)), [], 'expected (N, 7) or (T, N, 7)'),
    (np.zeros((2, 3, 4, 7)), [], 'expected (N, 7) or (T, N, 7)'),
    (np.zeros((0, 4, 7)), [], 'T >= 1'),
    (np.array([['a'] * 7]), [], 'expected real numbers'),
    (None, ['--rate', '0'], '--rate must be positive'),
    (None, ['--count', '0'], '--count must be at least 1'),
    (None, ['--scene', 'nowhere'], "invalid choice: 'nowhere'"),
])
def test_pose_publisher_refuses_bad_input_with_a_reason(tmp_path, content, arguments,
                                                        complaint):
    if content is not None:
        np.save(tmp_path / 'bad.npy', content)
        arguments = ['--npy', str(tmp_path / 'bad.npy')] + arguments
    result = run_tool('pose_publisher', *arguments)
    assert result.returncode == 2
    assert complaint in result.stderr


def test_pose_publisher_refuses_a_missing_file():
    result = run_tool('pose_publisher', '--npy', '/nonexistent/poses.npy')
    assert result.returncode == 2
    assert 'cannot read /nonexistent/poses.npy' in result.stderr


def run_monitor_once(ros, cloud, status, stale_status=None, *arguments):
    """Publish ``cloud`` and ``status`` until ``collision_monitor --once`` exits.

    ``stale_status``, if given, is published alone first, until the monitor has heard it
    (its subscriptions matched, reliable), as a node's status before its first answer.
    Returns the monitor's exit status, its output and its errors.
    """
    node, executor = ros
    cloud_publisher = node.create_publisher(PointCloud2, 'collisions', RELIABLE)
    diagnostics_publisher = node.create_publisher(DiagnosticArray, '/diagnostics',
                                                  RELIABLE)
    process = start_tool('collision_monitor', '--once', *arguments)
    last_sent = [0.0]
    stale_sent = [0]

    def publish():
        if time.monotonic() - last_sent[0] < 0.2:
            return
        last_sent[0] = time.monotonic()
        matched = cloud_publisher.get_subscription_count() > 0 \
            and diagnostics_publisher.get_subscription_count() > 0
        if stale_status is not None and stale_sent[0] < 3:
            diagnostics_publisher.publish(DiagnosticArray(header=cloud.header,
                                                          status=[stale_status]))
            stale_sent[0] += matched  # counted once the monitor is sure to receive it
            return
        if cloud is not None:
            cloud_publisher.publish(cloud)
        if status is not None:
            diagnostics_publisher.publish(DiagnosticArray(header=cloud.header, status=[status]))

    try:
        spin_until(executor, lambda: process.poll() is not None, every=publish)
        output, errors = process.communicate(timeout=TOOL_TIMEOUT_S)
    finally:
        process.kill()
        node.destroy_publisher(cloud_publisher)
        node.destroy_publisher(diagnostics_publisher)
    return process.returncode, output, errors


def monitor_status(level=DiagnosticStatus.WARN, message='a tick took longer than the input '
                   'period', name='collision_node: collision_check'):
    return DiagnosticStatus(
        level=level, name=name, message=message, hardware_id='none',
        values=[KeyValue(key='broad_phase', value='brute_force'),
                KeyValue(key='colliding_pairs', value='2'),
                KeyValue(key='last_rejection', value='dynamic body 1: pose has a NaN or Inf '
                         'value, said at length to pass the width of a terminal line')])


def monitor_cloud():
    contacts = np.zeros(2, CLOUD_DTYPE)
    contacts[0] = (0.125, -0.5, 1.25, 0.0, 0.0, 1.0, 0.0125, 0, 0, 3, 0, -0.0125, 1.0)
    contacts[1] = (2.0, 1.5, 0.75, 1.0, 0.0, 0.0, 0.25, 3, 0, 1, 1, -0.25, 1.0)
    header = Header(frame_id='world')
    header.stamp.sec, header.stamp.nanosec = 12, 500_000_000
    return contacts_to_cloud(contacts, header)


def test_collision_monitor_prints_the_contacts_and_the_status(ros):
    code, output, errors = run_monitor_once(ros, monitor_cloud(), monitor_status())
    assert code == 0, errors

    lines = output.splitlines()
    collisions = [line for line in lines if line.startswith('collisions')]
    assert len(collisions) == 1, output
    assert "collisions at 12.500 in 'world': 2 pairs" in collisions[0]
    assert 'd0-d3 0.0125 m at (0.125, -0.500, 1.250) n (0.000, 0.000, 1.000)' in collisions[0]
    assert 'd3-s1 0.25 m at (2.000, 1.500, 0.750) n (1.000, 0.000, 0.000)' in collisions[0]
    status = lines[lines.index(collisions[0]) + 1:]
    assert status == [
        'diagnostics WARN collision_node: collision_check: a tick took longer than the input '
        'period',
        '    broad_phase=brute_force',
        '    colliding_pairs=2',
        '    last_rejection=dynamic body 1: pose has a NaN or Inf value, said at length to pass '
        'the width of a terminal line']


def test_collision_monitor_once_prints_the_status_after_the_answer(ros):
    stale = monitor_status(DiagnosticStatus.ERROR, 'no valid input for 8 s')
    fresh = monitor_status(DiagnosticStatus.OK, '1 ticks at 1.0 Hz')
    code, output, errors = run_monitor_once(ros, monitor_cloud(), fresh, stale)
    assert code == 0, errors
    assert 'ERROR' not in output
    assert [line for line in output.splitlines() if line.startswith('diagnostics')] == [
        'diagnostics OK collision_node: collision_check: 1 ticks at 1.0 Hz']


def test_collision_monitor_once_skips_other_nodes_statuses(ros):
    other = monitor_status(name='battery_monitor: charge')
    code, output, errors = run_monitor_once(ros, monitor_cloud(), other, None, '--timeout', '3')
    assert code == 1 and 'diagnostics' not in output
    assert errors.splitlines() == [
        LISTENING % 3,
        'collision_monitor: no status of the node after the collisions message within 3 s']


def test_collision_monitor_once_gives_up_after_its_timeout(ros):
    started = time.monotonic()
    code, output, errors = run_monitor_once(ros, None, None, None, '--timeout', '2')
    assert code == 1 and output == ''
    assert errors.splitlines() == [
        LISTENING % 2,
        'collision_monitor: no collisions message within 2 s of matching its publisher (did '
        'an input reach collision_node?)']
    assert time.monotonic() - started < 2.0 + TOOL_TIMEOUT_S / 2  # a process start on top


def test_collision_monitor_once_gives_up_without_a_publisher():
    """No node in the domain: the wait counts from the monitor's start."""
    started = time.monotonic()
    done = run_tool('collision_monitor', '--once', '--timeout', '2', '--ros-args', '-r',
                    'collisions:=/no_node_publishes_this')
    assert done.returncode == 1 and done.stdout == ''
    assert done.stderr == 'collision_monitor: no collisions publisher matched within 2 s (is ' \
        'collision_node running, in this ROS domain?)\n'
    assert time.monotonic() - started < 2.0 + TOOL_TIMEOUT_S / 2


def test_collision_monitor_once_waits_from_the_publishers_match(ros):
    """A node that starts late (compiling its kernels) is waited for: the timeout restarts."""
    node, executor = ros
    process = start_tool('collision_monitor', '--once', '--timeout', '3')
    assert spin_until(executor, lambda: node.count_subscribers('/collisions') > 0)
    spin_until(executor, lambda: False, timeout_s=2.0)  # most of the wait, no publisher
    cloud_publisher = node.create_publisher(PointCloud2, 'collisions', RELIABLE)
    matched = time.monotonic()
    try:
        spin_until(executor, lambda: process.poll() is not None)
        output, errors = process.communicate(timeout=TOOL_TIMEOUT_S)
    finally:
        process.kill()
        node.destroy_publisher(cloud_publisher)
    assert process.returncode == 1
    assert errors.splitlines()[0] == LISTENING % 3
    assert time.monotonic() - matched > 2.5  # 3 s from the match, not 1 s


def test_collision_monitor_writes_a_line_break_in_a_value_as_backslash_n():
    status = DiagnosticStatus(level=DiagnosticStatus.WARN, name='n: collision_check',
                              message="1 inputs rejected, last: frame_id 'a\nb'",
                              values=[KeyValue(key='last_rejection', value="frame_id 'a\nb'")])
    assert format_status(status).split('\n') == [
        "WARN n: collision_check: 1 inputs rejected, last: frame_id 'a\\nb'",
        "    last_rejection=frame_id 'a\\nb'"]


def test_collision_monitor_reports_a_cloud_it_cannot_read(ros):
    cloud = PointCloud2(header=Header(frame_id='world'), height=1, width=0, point_step=12)
    code, output, errors = run_monitor_once(ros, cloud, monitor_status())
    assert code == 0, errors
    assert 'collisions: unreadable cloud: not a collisions cloud: fields' in output


def started_pids(output):
    return [int(line.rsplit('pid ', 1)[1].rstrip(')')) for line in output.splitlines()
            if line.startswith('started ')]


def assert_stopped(pids):
    for pid in pids:
        with pytest.raises(ProcessLookupError):  # the demo waited for it: no zombie either
            os.kill(pid, 0)


def test_demo_prints_a_summary_every_second_until_ctrl_c():
    demo = start_tool('demo')
    lines = queue.Queue()
    reader = threading.Thread(target=lambda: [lines.put(line) for line in demo.stdout])
    reader.start()
    output, ticking = [], []
    deadline = time.monotonic() + 180.0  # a cold numba cache compiles for a minute or two
    try:
        while len(ticking) < 4 and time.monotonic() < deadline:
            try:
                line = lines.get(timeout=1.0)
            except queue.Empty:
                continue
            output.append(line)
            if 'ticks/s' in line and line.split()[0] != '0.0':
                ticking.append(line)
        demo.send_signal(signal.SIGINT)
        demo.wait(TOOL_TIMEOUT_S)
    finally:
        demo.kill()
        reader.join()
    output = ''.join(output + list(lines.queue))
    assert len(ticking) == 4, output + demo.stderr.read()
    assert demo.returncode == 0, output + demo.stderr.read()
    # The room: 40 moving boxes and the 6 static colliders of config/default.yaml.
    assert re.fullmatch(r' *[0-9.]+ ticks/s \| 46 bodies \| [0-9]+ collisions \| 0 near \| '
                        r'tick ms median [0-9.]+ p99 [0-9.]+ \| broad phase \w+'
                        r'( \| (WARN|ERROR): .*)?\n',
                        ticking[-1]), ticking[-1]
    # The first ticking period may have started before the first input: not a full one.
    rates = [float(line.split()[0]) for line in ticking[1:]]
    assert all(10.0 < rate < 60.0 for rate in rates), rates  # the publisher sends 30 Hz
    pids = started_pids(output)
    assert len(pids) == 2 and output.count('stopped ') == 2, output
    assert_stopped(pids)


def test_demo_stops_by_itself_after_its_duration():
    started = time.monotonic()
    result = run_tool('demo', '--duration', '3', '--bodies', '5')
    elapsed = time.monotonic() - started
    assert result.returncode == 0, result.stdout + result.stderr
    assert elapsed < 3.0 + 2 * 5.0 + 10.0  # the children's stop timeouts, process start
    pids = started_pids(result.stdout)
    assert len(pids) == 2, result.stdout
    assert_stopped(pids)


def test_demo_refuses_a_missing_params_file():
    result = run_tool('demo', '--params-file', '/nonexistent.yaml')
    assert result.returncode == 2
    assert '--params-file /nonexistent.yaml: no such file' in result.stderr
    assert 'started' not in result.stdout


def test_demo_stops_and_says_so_when_the_node_fails(tmp_path):
    params = tmp_path / 'bad.yaml'
    params.write_text('collision_node:\n  ros__parameters:\n    broad_phase: no_such_phase\n')
    result = run_tool('demo', '--params-file', str(params), '--duration', '60')
    assert result.returncode == 1, result.stdout + result.stderr
    assert 'collision_node stopped unexpectedly with exit code 2' in result.stdout
    assert 'broad_phase' in result.stderr  # the node's own message names the parameter
    assert_stopped(started_pids(result.stdout))
