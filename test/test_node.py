"""The node through real ROS topics: PoseArray in, collisions, markers and diagnostics out.

The node and a test node share one executor that the test spins until a condition holds (never
a sleep that assumes a timing). Expected contacts come from hand-computed depths and normals of
axis-aligned boxes, and from a brute-force World for the larger scene.
"""
import os
import random
import time

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
import pytest
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from ros_helpers import (check_room_contacts, count_ticks_and_drops, EXPECTED, HALF, POSITIONS,
                         room_poses, values)
from visualization_msgs.msg import Marker

from collision_node.pipeline import scenes
from collision_node.pipeline.world import DYNAMIC, World
from collision_node.ros.cdr import serialize_pose_array
from collision_node.ros.messages import cloud_to_contacts
from collision_node.ros.node import MARKER_PERIOD_S

DOMAIN_ID = random.Random(os.getpid() + 1).randint(1, 200)


def test_contacts_stamp_frame_and_diagnostics(harness):
    room = harness()
    poses = room_poses()
    room.publish(poses, sec=41, frame_id='world')
    cloud = room.answer(41)
    check_room_contacts(cloud, EXPECTED, poses)
    assert [f.name for f in cloud.fields] == ['x', 'y', 'z', 'normal_x', 'normal_y', 'normal_z',
                                              'depth', 'id_a', 'type_a', 'id_b', 'type_b',
                                              'distance', 'toi']

    status = room.status(lambda s: values(s)['ticks'] != '0')
    assert status.level == DiagnosticStatus.OK, status.message
    assert status.hardware_id == 'none'
    found = values(status)
    for key in ('broad_phase', 'dynamic_bodies', 'static_bodies', 'still_bodies',
                'candidate_pairs', 'sat_tests', 'colliding_pairs', 'compared', 'ticks', 'rate_hz',
                'dropped_inputs', 'rejected_inputs', 'last_rejection'):
        assert key in found
    for stage in ('parse', 'broad', 'narrow', 'output', 'publish', 'total'):
        for statistic in ('last', 'median', 'p99', 'max'):
            assert float(found['%s_ms_%s' % (stage, statistic)]) >= 0.0
    assert float(found['total_ms_max']) >= float(found['narrow_ms_max'])
    assert (found['dynamic_bodies'], found['static_bodies'], found['colliding_pairs']) == (
        '5', '3', '4')
    assert found['broad_phase'] in ('brute_force', 'sphere', 'octree', 'kd_tree',
                                    'sweep_and_prune', 'grid')
    assert found['rejected_inputs'] == '0' and found['last_rejection'] == ''


def test_empty_frame_id_and_unchanged_input_are_answered(harness):
    room = harness()
    poses = room_poses()
    room.publish(poses, sec=1)  # an empty frame_id means the node's frame
    check_room_contacts(room.answer(1), EXPECTED, poses)
    room.publish(poses, sec=2)  # the same poses again: the World reuses its result
    check_room_contacts(room.answer(2), EXPECTED, poses)
    assert values(room.status(lambda s: values(s)['ticks'] != '0'))  # still ticking
    room.publish(np.zeros((0, 7)), sec=3)
    assert room.answer(3).width == 0  # published even when nothing collides


@pytest.mark.parametrize('case', ['NaN pose', 'bad quaternion', 'other frame', 'too many',
                                  'sizes for other count', 'not CDR'])
def test_rejected_input_is_reported_and_not_answered(harness, case):
    poses = room_poses()
    overrides, frame_id, reason = {}, 'world', None
    if case == 'NaN pose':
        poses[3, 1] = np.nan
        reason = 'dynamic_poses: body 3: pose has a NaN'
    elif case == 'bad quaternion':
        poses[2, 3:] = 0.0
        reason = 'dynamic_poses: body 2: quaternion'
    elif case == 'other frame':
        frame_id, reason = 'map', "dynamic_poses: frame_id 'map'"
    elif case == 'too many':
        overrides, reason = {'max_bodies': 4}, '5 poses exceed max_bodies 4'
    elif case == 'sizes for other count':
        overrides = {'dynamic.half_extents': [HALF] * 12}
        reason = 'dynamic.half_extents sizes 4 bodies, the input has 5 poses'
    room = harness(**overrides)
    if case == 'not CDR':
        room.poses.publish(b'\x00\x07\x00\x00' + bytes(16))
        reason = 'encapsulation'
    else:
        room.publish(poses, sec=7, frame_id=frame_id)
    status = room.status(lambda s: values(s)['rejected_inputs'] == '1')
    assert status.level == DiagnosticStatus.WARN
    assert reason in values(status)['last_rejection'] and reason in status.message

    good = room_poses(POSITIONS[:4])  # the next valid input is answered, and only it
    room.publish(good, sec=8)
    check_room_contacts(room.answer(8), EXPECTED[:3], good)
    assert not room.clouds


@pytest.mark.parametrize('threads', [1, 2])
def test_large_input_against_brute_force(harness, threads):
    scene = scenes.uniform(20000, seed=5)  # 10,000 dynamic boxes: a 560 KB PoseArray
    poses = scene.dynamic_poses(0.7)
    names = ['s%d' % i for i in range(len(scene.static_poses))][:50]
    # Two threads: the grid and the SAT run in several chunks at this size.
    overrides = {'static_colliders': names, 'threads': threads, 'dynamic.half_extents':
                 scene.dynamic_half_extents.ravel().tolist()}
    for i, name in enumerate(names):
        overrides['%s.pose' % name] = scene.static_poses[i].tolist()
        overrides['%s.half_extents' % name] = scene.static_half_extents[i].tolist()
    room = harness(**overrides)
    room.poses.publish(serialize_pose_array(9, 5, 'world', poses))
    cloud = room.answer(9)
    assert cloud.header.stamp.nanosec == 5
    reference = World(broad_phase='brute_force')
    reference.set_static(scene.static_poses[:50], scene.static_half_extents[:50])
    expected = reference.step(poses, scene.dynamic_half_extents).contacts
    contacts = cloud_to_contacts(cloud)
    assert len(expected) > 1000
    for field in ('id_a', 'type_a', 'id_b', 'type_b'):
        np.testing.assert_array_equal(contacts[field], expected[field])
    for field in ('x', 'y', 'z', 'normal_x', 'normal_y', 'normal_z', 'depth', 'distance'):
        np.testing.assert_allclose(contacts[field], expected[field], rtol=1e-6, atol=1e-5)


def test_run_time_parameters(harness):
    room = harness(**{'crate.enabled': False})
    poses = room_poses()
    room.publish(poses, sec=1)
    without_crate = [c for c in EXPECTED if c[2] != 2 or c[1] == DYNAMIC]
    check_room_contacts(room.answer(1), without_crate, poses)

    node = room.node
    result = node.set_parameters([Parameter('crate.enabled', value=True)])[0]
    assert result.successful, result.reason
    room.publish(poses, sec=2)
    check_room_contacts(room.answer(2), EXPECTED, poses)  # the crate keeps id 2

    for name, value, words in (('broad_phase', 'bvh', 'unknown broad phase'),
                               ('octree.max_depth', 11, 'depth'),
                               ('frame_id', 'map', 'read-only'),
                               ('static_colliders', ['floor', 'floor'], 'twice'),
                               ('wall.pose', [0.0] * 7, 'unit quaternion'),
                               ('crate.enabled', 1, 'type')):
        result = node.set_parameters([Parameter(name, value=value)])[0]
        assert not result.successful and words in result.reason, (name, result.reason)
    assert node.get_parameter('broad_phase').value == 'auto'
    assert node.set_parameters([Parameter('octree.max_depth', value=3)])[0].successful
    assert node.set_parameters([Parameter('octree.leaf_cooldown_ticks', value=0)])[0].successful

    # Through the parameter service, as `ros2 param set` does it.
    client = room.peer.create_client(SetParameters, 'collision_node/set_parameters')
    room.wait_for(client.service_is_ready, 'the parameter service')
    future = client.call_async(SetParameters.Request(parameters=[
        Parameter('broad_phase', value='sphere').to_parameter_msg(),
        Parameter('sphere_prefilter', value=False).to_parameter_msg()]))
    room.wait_for(future.done, 'the parameter service answer')
    assert all(result.successful for result in future.result().results)
    room.statuses.clear()
    room.publish(poses, sec=3)
    check_room_contacts(room.answer(3), EXPECTED, poses)
    assert values(room.status(lambda s: values(s)['ticks'] != '0'))['broad_phase'] == 'sphere'


def test_continuous_sees_a_body_pass_through_the_wall(harness):
    room = harness(continuous=True)
    before = room_poses()
    before[3, :3] = (1.5, 0.0, 1.5)  # body 3 in front of the wall (x in [1.9, 2.1]) ...
    after = before.copy()
    after[3, 0] = 2.5  # ... and behind it one input later: it went through
    room.publish(before, sec=1)
    check_room_contacts(room.answer(1), EXPECTED, before)
    room.publish(after, sec=2)
    contacts = cloud_to_contacts(room.answer(2))
    keys = [(int(c['id_a']), int(c['type_b']), int(c['id_b'])) for c in contacts]
    assert keys == sorted([c[:3] for c in EXPECTED] + [(3, 1, 1)])
    crossing = contacts[keys.index((3, 1, 1))]
    # Its front face (x = 1.6) reaches the wall after 0.3 m of its 1 m.
    assert crossing['depth'] == 0.0 and 0.3 - 1e-3 <= crossing['toi'] <= 0.3
    others = np.delete(contacts, keys.index((3, 1, 1)))
    assert (others['toi'] == 0.0).all()  # touching already at the previous input
    status = values(room.status(lambda s: values(s)['swept_pairs'] == '1'))
    assert status['continuous'] == 'on' and status['continuous_discrete_ticks'] == '1'
    room.publish(after[:3], sec=3)
    assert cloud_to_contacts(room.answer(3))['toi'].tolist() == [1.0, 1.0, 1.0]
    status = values(room.status(lambda s: values(s)['dynamic_bodies'] == '3'))
    assert status['continuous'] == 'discrete (pose count changed from 5 to 3)'
    assert status['continuous_discrete_ticks'] == '2'


def test_timer_mode_checks_the_newest_input(harness):
    room = harness(tick_rate_hz=20.0)
    poses = room_poses()
    room.publish(poses, sec=11)
    check_room_contacts(room.answer(11), EXPECTED, poses)
    # Inputs the timer never checked are counted: replaced ones and queue overwrites alike.
    for sec in (12, 13, 14):
        room.publish(poses, sec=sec)
    room.wait_for(lambda: room.clouds and room.clouds[-1].header.stamp.sec == 14, 'stamp 14')
    ticks, dropped = count_ticks_and_drops(room, 4)
    assert ticks == 1 + len(room.clouds)
    check_room_contacts(room.clouds[-1], EXPECTED, poses)


def test_dropped_inputs_count_queue_overwrites(harness):
    room = harness()
    poses = room_poses()
    # A gap in the sequence numbers counts once one message came through (earlier ones may
    # have been published before the node subscribed: never meant for it).
    for sec in range(11):  # 10 messages before the node can take one: depth 1 keeps few
        room.publish(poses, sec=sec)
        if sec == 0:
            room.wait_for(lambda: room.clouds, 'the first answer')
    room.wait_for(lambda: room.clouds[-1].header.stamp.sec == 10, 'stamp 10')
    ticks, dropped = count_ticks_and_drops(room, 11)
    assert ticks == len(room.clouds) and dropped > 0
    stamps = [cloud.header.stamp.sec for cloud in room.clouds]
    assert stamps == sorted(stamps)


def test_no_input_is_an_error(harness):
    room = harness(input_timeout_s=0.3)
    assert 'no valid input' in room.status(lambda s: s.level == DiagnosticStatus.ERROR).message
    room.publish(room_poses(), sec=1)
    room.answer(1)
    room.status(lambda s: s.level == DiagnosticStatus.OK)


def test_only_rejected_inputs_is_an_error_that_says_why(harness):
    room = harness(input_timeout_s=0.3)
    poses = room_poses()
    poses[1, 0] = np.nan
    room.publish(poses, sec=1)
    room.status(lambda s: values(s)['rejected_inputs'] == '1')
    status = room.status(lambda s: s.level == DiagnosticStatus.ERROR)
    silent_s, reason = status.message.split(' s; ')
    assert silent_s.startswith('no valid input for ')
    assert reason == '1 inputs rejected, last: dynamic_poses: body 1: pose has a NaN or Inf value'


def test_markers_only_while_subscribed(harness):
    room = harness()
    built = []
    writer = room.node._marker_writer
    serialize = writer.serialize

    def counting_serialize(*args):
        built.append(serialize(*args))
        return built[-1]
    writer.serialize = counting_serialize
    poses = room_poses()
    room.publish(poses, sec=1)
    room.answer(1)
    assert not built

    room.subscribe_markers()
    room.wait_for(lambda: room.markers.get_publisher_count() == 1)
    time.sleep(MARKER_PERIOD_S)  # the node asks for subscribers at most once a period
    room.publish(poses, sec=2)
    room.answer(2)
    room.wait_for(lambda: room.marker_arrays, 'markers')
    markers = room.marker_arrays[-1].markers
    assert markers[0].action == Marker.DELETEALL
    by_namespace = {}
    for marker in markers[1:]:
        assert marker.action == Marker.ADD and marker.header.stamp.sec == 2
        by_namespace.setdefault(marker.ns, []).append(marker)
    assert sorted(by_namespace) == ['dynamic', 'normals', 'static']
    assert [m.id for m in by_namespace['static']] == [0, 1, 2]
    assert all(m.type == Marker.CUBE for m in by_namespace['static'] + by_namespace['dynamic'])
    dynamic = {m.id: m for m in by_namespace['dynamic']}
    assert sorted(dynamic) == [0, 1, 2, 3, 4]
    assert dynamic[0].scale.x == pytest.approx(2 * HALF)
    assert dynamic[1].pose.position.x == pytest.approx(1.85)
    colors = {i: (m.color.r, m.color.g, m.color.b) for i, m in dynamic.items()}
    assert colors[0] == colors[1] == colors[2] == colors[4] != colors[3]  # 3 is free
    static_color = by_namespace['static'][0].color
    assert (static_color.r, static_color.g, static_color.b) not in colors.values()
    arrows = by_namespace['normals']
    assert len(arrows) == len(EXPECTED) and all(m.type == Marker.ARROW for m in arrows)
    for arrow, (_, _, _, depth, normal) in zip(sorted(arrows, key=lambda m: m.id), EXPECTED):
        q = arrow.pose.orientation
        x_axis = [1 - 2 * (q.y * q.y + q.z * q.z), 2 * (q.x * q.y + q.z * q.w),
                  2 * (q.x * q.z - q.y * q.w)]  # first column of the rotation matrix
        np.testing.assert_allclose(x_axis, normal, atol=1e-6)

    room.peer.destroy_subscription(room.markers)
    room.wait_for(lambda: room.node._markers_publisher.get_subscription_count() == 0)
    count = len(built)
    room.publish(poses, sec=3)
    room.answer(3)
    assert len(built) == count
