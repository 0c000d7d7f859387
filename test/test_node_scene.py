"""A world that changes, through real ROS: static_poses messages and SetParameters calls.

The room of ros_helpers (floor 0, wall 1, crate 2; five dynamic bodies of which body 3 floats
free at z = 3). The dynamic bodies keep their poses throughout, so every changed answer below
comes from a static change: the still-body shortcut must not hide it.
"""
import os
import random

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseArray
import numpy as np
from rcl_interfaces.srv import SetParameters, SetParametersAtomically
from rclpy.parameter import Parameter
from ros_helpers import check_room_contacts, COLLIDERS, EXPECTED, INPUT, room_poses, values

from collision_node.benchmarks.params_files import write_scene_files
from collision_node.pipeline.world import DYNAMIC, STATIC
from collision_node.ros.cdr import serialize_pose_array
from collision_node.ros.messages import cloud_to_contacts

DOMAIN_ID = random.Random(os.getpid() + 19).randint(1, 200)
STATIC_POSES = np.array([pose for pose, _ in COLLIDERS.values()])  # floor, wall, crate
ABOVE = [0.0, 0.0, 3.0, 0.0, 0.0, 0.0, 1.0]  # where body 3 floats


def ids(cloud):
    return [(int(c['id_a']), int(c['type_b']), int(c['id_b'])) for c in cloud_to_contacts(cloud)]


def expected_ids(expected):
    return [(id_a, type_b, id_b) for id_a, type_b, id_b, _, _ in expected]


class Scene:
    """The room's harness with a static_poses publisher and parameter service clients."""

    def __init__(self, room):
        self.room = room
        self.poses = room_poses()
        self.sec = 0
        self.statics = room.peer.create_publisher(PoseArray, 'static_poses', INPUT)
        room.wait_for(lambda: self.statics.get_subscription_count() == 1)

    def answer(self):
        """Publish the (unchanged) dynamic poses; return the answer's contact ids."""
        self.sec += 1
        self.room.publish(self.poses, sec=self.sec)
        return ids(self.room.answer(self.sec))

    def publish_static(self, poses, frame_id=''):
        self.statics.publish(serialize_pose_array(0, 0, frame_id, np.asarray(poses, float)))

    def status(self, condition):
        """Wait for a diagnostics status whose values meet ``condition``; return the values."""
        return values(self.room.status(lambda status: condition(values(status))))

    def call(self, service_type, name, parameters):
        client = self.room.peer.create_client(service_type, 'collision_node/' + name)
        self.room.wait_for(client.service_is_ready, 'the %s service' % name)
        request = service_type.Request(parameters=[
            Parameter(key, value=value).to_parameter_msg() for key, value in parameters])
        future = client.call_async(request)
        self.room.wait_for(future.done, 'the %s answer' % name)
        self.room.peer.destroy_client(client)
        return future.result()

    def set_each(self, *parameters):
        """Set the parameters one by one, as SetParameters (and `ros2 param set`) do."""
        return self.call(SetParameters, 'set_parameters', parameters).results

    def set_atomically(self, *parameters):
        return self.call(SetParametersAtomically, 'set_parameters_atomically',
                         parameters).result


def test_static_poses_move_the_colliders_and_bad_ones_are_refused(harness):
    scene = Scene(harness())
    assert scene.answer() == expected_ids(EXPECTED)
    moved = STATIC_POSES.copy()
    moved[2] = ABOVE  # the crate jumps onto body 3 and leaves body 4
    scene.publish_static(moved, frame_id='world')
    found = scene.status(lambda v: v['scene_version'] == '1')
    assert found['static_ids'] == 'floor:0 wall:1 crate:2'
    assert scene.answer() == [(0, STATIC, 0), (1, DYNAMIC, 2), (1, STATIC, 1), (3, STATIC, 2)]

    bad_quaternion = moved.copy()
    bad_quaternion[1, 3:] = 0.0
    nan = moved.copy()
    nan[0, 2] = np.nan
    for poses, frame_id, reason in (
            (moved[:2], '', 'static_poses: 2 poses for 3 static colliders'),
            (nan, '', 'static_poses: collider 0 (floor): pose has a NaN'),
            (bad_quaternion, '', 'static_poses: collider 1 (wall): quaternion norm'),
            (STATIC_POSES, 'map', "static_poses: frame_id 'map'")):
        scene.publish_static(poses, frame_id)
        status = scene.room.status(lambda s: reason in values(s)['last_rejection'])
        assert status.level == DiagnosticStatus.WARN and reason in status.message
        # The last valid static poses stay.
        assert scene.answer() == [(0, STATIC, 0), (1, DYNAMIC, 2), (1, STATIC, 1),
                                  (3, STATIC, 2)]
    # A disabled collider's pose is checked too (it may be enabled later) and kept.
    assert scene.set_each(('crate.enabled', False))[0].successful
    bad_quaternion = moved.copy()
    bad_quaternion[2, 3:] = 0.0
    scene.publish_static(bad_quaternion)
    scene.room.status(lambda s: 'collider 2 (crate): quaternion' in values(s)['last_rejection'])
    assert scene.answer() == [(0, STATIC, 0), (1, DYNAMIC, 2), (1, STATIC, 1)]
    assert scene.set_each(('crate.enabled', True))[0].successful
    assert scene.answer() == [(0, STATIC, 0), (1, DYNAMIC, 2), (1, STATIC, 1), (3, STATIC, 2)]
    scene.publish_static(STATIC_POSES)  # back: the room's own contacts, to the numbers
    scene.status(lambda v: v['scene_version'] == '4')
    scene.sec += 1
    scene.room.publish(scene.poses, sec=scene.sec)
    check_room_contacts(scene.room.answer(scene.sec), EXPECTED, scene.poses)


def test_set_parameters_move_add_and_remove_colliders_with_lasting_ids(harness):
    scene = Scene(harness(ignored_pairs=['d4 crate']))
    without_crate = [(0, STATIC, 0), (1, DYNAMIC, 2), (1, STATIC, 1)]
    assert scene.answer() == without_crate
    # Moved and resized by parameters while every body keeps its pose.
    assert scene.set_each(('crate.pose', [0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 1.0]))[0].successful
    assert scene.answer() == without_crate  # 0.4 m below body 3
    assert scene.set_each(('crate.half_extents', [0.5, 0.5, 0.95]))[0].successful
    assert scene.answer() == without_crate + [(3, STATIC, 2)]

    # A door added with ros2 param set's calls: its block first, then the list.
    results = scene.set_each(('door.pose', [0.0, 0.0, 3.1, 0.0, 0.0, 0.0, 1.0]),
                             ('door.half_extents', [0.2, 0.2, 0.05]),
                             ('static_colliders', ['floor', 'wall', 'crate', 'door']))
    assert all(result.successful for result in results), results
    found = scene.status(lambda v: v['static_ids'] == 'floor:0 wall:1 crate:2 door:3')
    version = int(found['scene_version'])
    assert version == 3
    assert scene.answer() == without_crate + [(3, STATIC, 2), (3, STATIC, 3)]
    # The wall goes and the crate is disabled in one call: the door keeps its id.
    result = scene.set_atomically(('static_colliders', ['floor', 'crate', 'door']),
                                  ('crate.enabled', False))
    assert result.successful, result.reason
    assert scene.answer() == [(0, STATIC, 0), (1, DYNAMIC, 2), (3, STATIC, 3)]
    scene.status(lambda v: v['static_ids'] == 'floor:0 crate:2 door:3'
                 and int(v['scene_version']) == version + 1)
    # static_poses now has three poses, in the new order; the wall is gone from it.
    scene.publish_static([STATIC_POSES[0], STATIC_POSES[2], ABOVE])
    scene.status(lambda v: int(v['scene_version']) == version + 2)
    assert scene.answer() == [(0, STATIC, 0), (1, DYNAMIC, 2), (3, STATIC, 3)]
    # The wall again: a new collider, a new id.
    result = scene.set_atomically(
        ('static_colliders', ['floor', 'crate', 'door', 'wall']),
        ('wall.pose', COLLIDERS['wall'][0]), ('wall.half_extents', COLLIDERS['wall'][1]))
    assert result.successful, result.reason
    assert scene.answer() == [(0, STATIC, 0), (1, DYNAMIC, 2), (1, STATIC, 4), (3, STATIC, 3)]

    # Refused whole, with the reason; nothing of the call changes.
    for parameters, words in (
            ([('static_colliders', ['floor', 'crate', 'door', 'wall', 'sofa']),
              ('broad_phase', 'grid')], "parameter 'sofa.pose': missing"),
            ([('static_colliders', ['floor', 'door', 'wall']), ('broad_phase', 'grid')],
             "'crate' is neither"),  # named in ignored_pairs
            ([('door.pose', [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]), ('broad_phase', 'grid')],
             "parameter 'door.pose': quaternion"),
            ([('door.half_extents', [0.1, -0.1, 0.1])], "parameter 'door.half_extents'"),
            ([('static_colliders', ['floor', 'floor'])], 'appears twice'),
            ([('door.colour', 'red')], 'undeclared')):
        result = scene.set_atomically(*parameters)
        assert not result.successful and words in result.reason, (parameters, result.reason)
    node = scene.room.node
    assert node.get_parameter('broad_phase').value == 'auto'
    assert node.get_parameter('static_colliders').value == ['floor', 'crate', 'door', 'wall']
    assert scene.answer() == [(0, STATIC, 0), (1, DYNAMIC, 2), (1, STATIC, 4), (3, STATIC, 3)]
    # The entry goes in the same call: then the crate may go.
    result = scene.set_atomically(('static_colliders', ['floor', 'door', 'wall']),
                                  ('ignored_pairs', ['d0 floor']))
    assert result.successful, result.reason
    assert scene.answer() == [(1, DYNAMIC, 2), (1, STATIC, 4), (3, STATIC, 3)]


def test_a_scene_from_files_comes_before_the_listed_colliders(harness, tmp_path):
    files = write_scene_files(tmp_path, [ABOVE, [50.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]],
                              [[0.3, 0.3, 0.3]] * 2, np.full((5, 3), 0.1),
                              names=['pillar', 'far'])
    scene = Scene(harness(**files))
    assert scene.room.node.get_parameter('static_colliders').value == [
        'pillar', 'far', 'floor', 'wall', 'crate']
    assert scene.status(lambda v: True)['static_ids'] == \
        'pillar:0 far:1 floor:2 wall:3 crate:4'
    assert scene.answer() == [(0, STATIC, 2), (1, DYNAMIC, 2), (1, STATIC, 3), (3, STATIC, 0),
                              (4, STATIC, 4)]
    moved = np.concatenate([[ABOVE, ABOVE], STATIC_POSES])  # five poses now: far comes too
    scene.publish_static(moved)
    scene.status(lambda v: v['scene_version'] == '1')
    assert scene.answer() == [(0, STATIC, 2), (1, DYNAMIC, 2), (1, STATIC, 3), (3, STATIC, 0),
                              (3, STATIC, 1), (4, STATIC, 4)]
