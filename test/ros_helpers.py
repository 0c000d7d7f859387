"""Helpers shared by the tests that talk to the node through real ROS topics.

:class:`Harness` puts a CollisionNode and a test node ("tester") in one namespace and one
executor that the test spins until a condition holds (never a sleep that assumes a timing).
The room scene has hand-computed contacts. The params-file helpers write the YAML that
``--params-file`` reads, with one good file and a set of bad ones, each breaking one parameter.
"""
import itertools
import json
import os
import pathlib
import subprocess
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Pose, PoseArray
from lifecycle_msgs.srv import ChangeState, GetState
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import MarkerArray

from collision_node.pipeline.world import DYNAMIC, STATIC
from collision_node.ros.messages import cloud_to_contacts
from collision_node.ros.node import CollisionNode

REPO = pathlib.Path(__file__).resolve().parents[1]
TIMEOUT_S = 20.0
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
INPUT = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
STATUS_NAME = 'collision_node: collision_check'
# Axis-aligned scene, all dynamic boxes with half extents 0.1:
COLLIDERS = {  # name: (pose, half extents); ids 0, 1, 2 in this order
    'floor': ([0.0, 0.0, -0.5, 0.0, 0.0, 0.0, 1.0], [5.0, 5.0, 0.5]),    # top at z = 0
    'wall': ([2.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], [0.1, 5.0, 1.0]),      # x in [1.9, 2.1]
    'crate': ([-2.0, 0.0, 0.5, 0.0, 0.0, 0.0, 1.0], [0.5, 0.5, 0.5]),    # x in [-2.5, -1.5]
}
POSITIONS = [
    (0.0, 0.0, 0.08),   # 0: 0.02 into the floor
    (1.85, 0.0, 1.0),   # 1: 0.05 into the wall, 0.03 into body 2
    (1.68, 0.0, 1.0),   # 2
    (0.0, 0.0, 3.0),    # 3: free
    (-1.45, 0.0, 0.5),  # 4: 0.05 into the crate
]
# (id_a, type_b, id_b, depth, normal from A to B), in the cloud's order (id_a, type_b, id_b).
EXPECTED = [
    (0, STATIC, 0, 0.02, (0.0, 0.0, -1.0)),
    (1, DYNAMIC, 2, 0.03, (-1.0, 0.0, 0.0)),
    (1, STATIC, 1, 0.05, (1.0, 0.0, 0.0)),
    (4, STATIC, 2, 0.05, (-1.0, 0.0, 0.0)),
]
HALF = 0.1
FLOAT32_TOLERANCE = 1e-6  # m: the cloud holds float32; these coordinates are below 3 m


def room_overrides(**extra):
    overrides = {'static_colliders': list(COLLIDERS), 'dynamic.half_extents': [HALF] * 3,
                 'diagnostic_updater.period': 0.1, 'input_timeout_s': 0.0}
    for name, (pose, extents) in COLLIDERS.items():
        overrides['%s.pose' % name] = pose
        overrides['%s.half_extents' % name] = extents
    overrides.update(extra)
    return overrides


def room_poses(positions=POSITIONS):
    poses = np.zeros((len(positions), 7))
    poses[:, :3] = positions
    poses[:, 6] = 1.0
    return poses


def make_context(domain_id):
    """Start an rclpy context on its own DDS domain (call ``try_shutdown`` when done)."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    return context


class Harness:
    """A CollisionNode and a test node that talks to it, spun by the test.

    ``input_depth`` deepens the node's input queue (its ``qos_overrides`` parameter) and the
    tester's publisher alike, so that a burst of that many inputs reaches the node whole.
    ``namespace`` (default: a new one per harness) lets a test publish before the node exists. With
    ``autostart=False`` among the overrides the node waits unconfigured: ``lifecycle`` moves it.
    """

    counter = itertools.count()

    def __init__(self, context, input_depth=None, namespace=None, **overrides):
        # A namespace of its own: no stray message from an earlier case.
        self.namespace = namespace or 'case%d' % next(self.counter)
        input_qos = INPUT
        if input_depth is not None:
            overrides['qos_overrides./%s/dynamic_poses.subscription.depth'
                      % self.namespace] = input_depth
            input_qos = QoSProfile(depth=input_depth, reliability=ReliabilityPolicy.RELIABLE)
        self.node = CollisionNode(
            context=context, namespace=self.namespace,
            parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()])
        self.peer = rclpy.create_node('tester', namespace=self.namespace, context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.peer)
        self.poses = self.peer.create_publisher(PoseArray, 'dynamic_poses', input_qos)
        self.clouds, self.statuses, self.marker_arrays = [], [], []
        self.peer.create_subscription(PointCloud2, 'collisions', self.clouds.append, RELIABLE)
        self.peer.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics,
                                      RELIABLE)
        self.markers = None
        self.lifecycle = LifecycleClient(self.peer, self.wait_for)
        if overrides.get('autostart', True):
            self.wait_connected()

    def wait_connected(self):
        """Wait until the node's input and output topics are matched with the tester's."""
        self.wait_for(lambda: self.poses.get_subscription_count() == 1
                      and self.peer.count_publishers('collisions') == 1)

    def _on_diagnostics(self, message):
        self.statuses.extend(status for status in message.status if status.name == STATUS_NAME)

    def subscribe_markers(self):
        self.markers = self.peer.create_subscription(
            MarkerArray, 'collision_node/markers', self.marker_arrays.append, RELIABLE)

    def wait_for(self, condition, what='condition', timeout_s=TIMEOUT_S):
        deadline = time.monotonic() + timeout_s
        while not condition():
            assert time.monotonic() < deadline, 'timed out waiting for %s' % what
            self.executor.spin_once(timeout_sec=0.01)

    def publish(self, poses, sec, frame_id=''):
        message = PoseArray()
        message.header.stamp.sec, message.header.frame_id = sec, frame_id
        message.poses = [_pose(row) for row in np.asarray(poses).tolist()]
        self.poses.publish(message)

    def answer(self, sec):
        """Wait for the cloud stamped ``sec``; no other cloud may come before it."""
        self.wait_for(lambda: self.clouds, 'collisions stamped %d' % sec)
        cloud = self.clouds.pop(0)
        assert cloud.header.stamp.sec == sec
        return cloud

    def status(self, condition=lambda status: True):
        """Wait for a diagnostics status that meets ``condition`` and return it."""
        def found():
            while self.statuses:
                status = self.statuses.pop(0)
                if condition(status):
                    self.found = status
                    return True
            return False
        self.wait_for(found, 'a diagnostics status')
        return self.found

    def close(self):
        self.executor.shutdown()
        self.peer.destroy_node()
        self.node.destroy_node()


class LifecycleClient:
    """Calls a managed node's get_state and change_state services, as `ros2 lifecycle` does.

    ``spin_until(condition, what)`` spins the executor that holds ``peer`` until the condition
    holds (Harness.wait_for). The names are relative to the peer's namespace.
    """

    def __init__(self, peer, spin_until, node_name='collision_node'):
        self.spin_until = spin_until
        self.get_client = peer.create_client(GetState, node_name + '/get_state')
        self.change_client = peer.create_client(ChangeState, node_name + '/change_state')

    def state(self):
        """Return the node's state label (unconfigured, inactive, active, finalized)."""
        return self._call(self.get_client, GetState.Request()).current_state.label

    def change(self, transition):
        """Request a transition (a Transition id or label, e.g. 'configure'); return success."""
        return self._call(self.change_client, change_request(transition)).success

    def change_async(self, transition):
        """Request a transition and return the future of its ChangeState response."""
        self.spin_until(self.change_client.service_is_ready, 'the change_state service')
        return self.change_client.call_async(change_request(transition))

    def _call(self, client, request):
        self.spin_until(client.service_is_ready, 'the %s service' % client.srv_name)
        future = client.call_async(request)
        self.spin_until(future.done, 'the %s answer' % client.srv_name)
        return future.result()


def change_request(transition):
    """Return a ChangeState request for a Transition id, or for a label (any 'shutdown')."""
    request = ChangeState.Request()
    if isinstance(transition, str):
        request.transition.label = transition
    else:
        request.transition.id = transition
    return request


def _pose(row):
    pose = Pose()
    pose.position.x, pose.position.y, pose.position.z = row[:3]
    pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = row[3:]
    return pose


def values(status):
    return {item.key: item.value for item in status.values}


def check_room_contacts(cloud, expected, poses):
    assert cloud.header.frame_id == 'world'
    assert (cloud.height, cloud.width) == (1, len(expected))
    contacts = cloud_to_contacts(cloud)
    assert [(c['id_a'], c['type_b'], c['id_b']) for c in contacts] == [
        (id_a, type_b, id_b) for id_a, type_b, id_b, _, _ in expected]
    assert (contacts['type_a'] == DYNAMIC).all()
    for contact, (id_a, type_b, id_b, depth, normal) in zip(contacts, expected):
        assert contact['depth'] == pytest.approx(depth, abs=FLOAT32_TOLERANCE)
        np.testing.assert_allclose([contact['normal_x'], contact['normal_y'],
                                    contact['normal_z']], normal, atol=FLOAT32_TOLERANCE)
        # The contact point lies where the two (axis-aligned) boxes overlap.
        low_a, high_a = poses[id_a, :3] - HALF, poses[id_a, :3] + HALF
        if type_b == DYNAMIC:
            low_b, high_b = poses[id_b, :3] - HALF, poses[id_b, :3] + HALF
        else:
            center, extents = (np.array(v) for v in list(COLLIDERS.values())[id_b])
            low_b, high_b = center[:3] - extents, center[:3] + extents
        point = np.array([contact['x'], contact['y'], contact['z']])
        assert (point >= np.maximum(low_a, low_b) - FLOAT32_TOLERANCE).all()
        assert (point <= np.minimum(high_a, high_b) + FLOAT32_TOLERANCE).all()


def count_inputs(room, published, timeout_s=TIMEOUT_S):
    """Wait until every published input was checked, rejected or counted as dropped.

    Returns (ticks, dropped, rejected). Reads (and consumes) every status from the node's
    start on: ``ticks`` is per period, the other two are totals.
    """
    ticks, dropped, rejected = 0, 0, 0

    def all_counted():
        nonlocal ticks, dropped, rejected
        while room.statuses:
            found = values(room.statuses.pop(0))
            ticks += int(found['ticks'])
            dropped, rejected = int(found['dropped_inputs']), int(found['rejected_inputs'])
        return ticks + dropped + rejected == published
    room.wait_for(all_counted, 'ticks + dropped_inputs + rejected_inputs == %d' % published,
                  timeout_s)
    return ticks, dropped, rejected


def count_ticks_and_drops(room, published):
    """Wait until every published input was either checked or counted as dropped."""
    ticks, dropped, _ = count_inputs(room, published)
    return ticks, dropped


# Params files, as ``--ros-args --params-file`` reads them.

def write_params(path, body):
    path.write_text('collision_node:\n  ros__parameters:\n' + ''.join(
        '    %s\n' % line for line in body.strip('\n').split('\n')))
    return str(path)


GOOD_YAML = """
frame_id: map
broad_phase: brute_force
static_colliders: [table, shelf]
dynamic:
  half_extents: [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]
table:
  pose: [0.0, 0.0, 0.4, 0.0, 0.0, 0.0, 1.0]
  half_extents: [0.6, 0.4, 0.02]
shelf:
  pose: [1.2, 0.0, 1.0, 0.0, 0.0, 0.3826834, 0.9238795]
  half_extents: [0.2, 0.5, 1.0]
  enabled: false
"""
BAD_YAML = {  # name the error must name: the params file
    'shelf.half_extents': GOOD_YAML.replace('[0.2, 0.5, 1.0]', '[0.2, -0.5, 1.0]'),
    'table.pose': GOOD_YAML.replace('0.0, 0.4, 0.0, 0.0, 0.0, 1.0]', '0.0, 0.4, 0.0, 0.0, 1.0]'),
    'shelf.pose': GOOD_YAML.replace('  pose: [1.2, 0.0, 1.0, 0.0, 0.0, 0.3826834, 0.9238795]\n',
                                    ''),
    'broad_phase': GOOD_YAML.replace('brute_force', 'bvh'),
    'static_colliders': GOOD_YAML.replace('[table, shelf]', '[table, table]'),
    'tick_rate_hz': GOOD_YAML + 'tick_rate_hz: -5.0\n',
    'max_bodies': GOOD_YAML + 'max_bodies: 0\n',
    # An integer where a double is declared: rclpy's type check, reported with the name.
    'input_timeout_s': GOOD_YAML + 'input_timeout_s: 2\n',
    'dynamic.half_extents': GOOD_YAML.replace('0.5, 0.6]', '0.5]'),
    'ignored_pairs': GOOD_YAML + 'ignored_pairs: ["d0 sofa"]\n',
    # A double where an integer is declared: rclpy's type check, reported with the name.
    'table.collision_mask': GOOD_YAML.replace('table:\n', 'table:\n  collision_mask: 3.0\n'),
    'margin': GOOD_YAML + 'margin: -0.5\n',
    'static_scene_file': GOOD_YAML + 'static_scene_file: /nonexistent/scene.npz\n',
}


def node_environment(domain_id):
    """Return a node process's environment: the test's own domain, the package importable."""
    return dict(os.environ, ROS_DOMAIN_ID=str(domain_id), PYTHONUNBUFFERED='1',
                PYTHONPATH=os.pathsep.join(filter(None, [str(REPO),
                                                         os.environ.get('PYTHONPATH')])))


def node_command(*ros_arguments):
    """Return the command line that runs the node in a process of this Python."""
    return [sys.executable, '-m', 'collision_node.ros.node', '--ros-args', *ros_arguments]


def run_node(domain_id, params_file, timeout_s=120):
    """Run the node on ``params_file`` to its end (a bad file ends it at start)."""
    return subprocess.run(node_command('--params-file', params_file), cwd=REPO,
                          env=node_environment(domain_id), capture_output=True, text=True,
                          timeout=timeout_s)


def run_soak(domain_id, json_path, *arguments, timeout_s=900):
    """Run collision_soak as a process; return its result and its summary (a dict)."""
    done = subprocess.run(
        [sys.executable, '-m', 'collision_node.benchmarks.collision_soak', '--json',
         str(json_path), *arguments], cwd=REPO, env=node_environment(domain_id),
        capture_output=True, text=True, timeout=timeout_s)
    summary = json.loads(pathlib.Path(json_path).read_text()) if done.returncode in (0, 1) \
        else None
    return done, summary
