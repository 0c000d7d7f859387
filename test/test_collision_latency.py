"""collision_latency end to end (tiny plan), and 100,000 poses through ROS to a node process.

Timing targets live in the benchmark's printed numbers; these tests check that it runs, that
its numbers are consistent, and that the largest input the node accepts gets through.
"""
import json
import os
import random
import subprocess
import sys
import time

import numpy as np
import rclpy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import PointCloud2

from collision_node.benchmarks import collision_latency
from collision_node.pipeline.world import World
from collision_node.ros.cdr import serialize_pose_array
from collision_node.ros.messages import cloud_to_contacts

DOMAIN_ID = random.Random(os.getpid() + 7).randint(1, 200)
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_tiny_run_prints_tables_and_consistent_json(tmp_path):
    path = tmp_path / 'latency.json'
    done = subprocess.run(
        [sys.executable, '-m', 'collision_node.benchmarks.collision_latency', '--tiny', '--json',
         str(path), '--domain-id', str(DOMAIN_ID)], cwd=REPO, capture_output=True, text=True,
        timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    for title in ('PoseArray in → collisions out', 'Arm:', 'Joint states:', 'Floor:', 'Tick:',
                  'Output:',
                  'Skip what a scene', 'Sphere', 'Gaps:'):
        assert title in done.stdout
    results = json.loads(path.read_text())
    row, = results['latency']
    assert (row['bodies'], row['poses'], row['statics'], row['rate_hz']) == (100, 100, 0, 20)
    assert 0 < row['answered'] <= row['sent'] == 20
    assert 0 < row['latency_ms_median'] <= row['latency_ms_p99'] <= row['latency_ms_max']
    # The node's own figures came back over /diagnostics.
    assert row['dynamic_bodies'] == '100' and row['static_bodies'] == '0'
    for stage in ('parse', 'broad', 'narrow', 'output', 'publish'):
        assert 0.0 <= row[stage + '_ms_median'] <= row['total_ms_max']
    # The arm scene: the node and the echo took turns on the same inputs.
    # And the Panda from its URDF, joint_states in: the same against its echo.
    for key in ('arm', 'joint_states'):
        arm = results[key]
        assert arm['sent'] > 0 and arm['sent'] % arm['turns'] == 0  # as many in each turn
        for who in ('node', 'echo'):
            assert 0 < arm[who + '_answered'] <= arm['sent']
            assert len(arm[who + '_turn_medians_ms']) == arm['turns']
            assert 0 < arm[who + '_ms_median'] <= arm[who + '_ms_p99'] <= arm[who + '_ms_max']
        assert arm['added_ms'] == arm['node_ms_median'] - arm['echo_ms_median']
        assert 'Target: %s through ROS' % key in done.stdout
    # The node's callback in this process: the arm, then the uniform scene, every stage timed.
    assert [(r['scene'], r['bodies']) for r in results['tick']] == [
        ('arm (config/arm.yaml)', 7), ('uniform 64 (32 static)', 32)]
    for r in results['tick']:
        assert r['inputs'] == 50 and r['us_per_input'] > 0
        # Both scenes are small: their inputs are read, checked and written in one kernel
        # (ros/lanes.py), narrow, and only the markers (none here) would be output.
        assert 0 < r['narrow_us'] <= r['total_us'] and 0 <= r['output_us'] <= r['total_us']
    # The echo answered the same inputs, and reports no stages.
    floor, = results['floor']
    assert (floor['bodies'], floor['rate_hz'], floor['threads']) == (100, 20, None)
    assert 0 < floor['answered'] <= floor['sent'] == 20
    assert 0 < floor['latency_ms_median'] <= floor['latency_ms_p99'] <= floor['latency_ms_max']
    assert floor['total_ms_median'] is None
    assert [r['what'].split(':')[0] for r in results['skips']] == [
        'no dynamic bodies', 'identical input', 'bodies at rest', 'static colliders',
        'disabled colliders', 'diagnostics']
    assert all(r['needed_ms'] > 0 and r['skipped_ms'] > 0 for r in results['skips'])
    for r in results['sphere']:
        assert r['sat_tests_on'] <= r['candidate_pairs']
    assert [r['before_tick'] for r in results['gaps']] == [
        name for name, _, _ in collision_latency.GAPS]
    for r in results['gaps']:
        assert r['bodies'] == 200
        assert 0.0 < r['broad_ms'] <= r['total_ms'] and 0.0 < r['narrow_ms'] <= r['total_ms']


def test_100000_poses_through_ros(tmp_path):
    """5.6 MB PoseArrays, reliable QoS, Fast DDS defaults: every one answered, exactly."""
    frames, static_poses, static_extents, extents = collision_latency.scene_input(100000, False)
    params_path = str(tmp_path / 'params.yaml')
    collision_latency.write_params_file(params_path, collision_latency.node_parameters(
        static_poses, static_extents, extents, broad_phase='grid'))
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    client = collision_latency.Client(context)
    process, log = collision_latency.start_node(params_path, DOMAIN_ID)
    try:
        data = serialize_pose_array(0, 0, 'world', frames[1])
        assert len(data) > 5.6e6
        collision_latency.wait_ready(client, process, log, data, 1, time.perf_counter())
        clouds = []
        client.node.create_subscription(PointCloud2, 'collisions', clouds.append,
                                        collision_latency.OUTPUT_QOS, raw=True)
        for k in range(3):  # one at a time: the depth-1 queue keeps only the newest
            client.send(data, 2, k)
            assert client.wait(lambda: (2, k) in client.received, 60.0), 'no answer to %d' % k
        assert client.wait(lambda: len(clouds) >= 3, 10.0)
    finally:
        collision_latency.stop_node(process, log)
        client.close()
        context.try_shutdown()
    contacts = cloud_to_contacts(deserialize_message(clouds[-1], PointCloud2))
    expected = World(broad_phase='grid').step(frames[1], extents).contacts
    assert len(expected) > 50000
    for field in ('id_a', 'type_a', 'id_b', 'type_b'):
        np.testing.assert_array_equal(contacts[field], expected[field])
    for field in ('x', 'y', 'z', 'depth'):
        np.testing.assert_allclose(contacts[field], expected[field], rtol=1e-6, atol=1e-4)
