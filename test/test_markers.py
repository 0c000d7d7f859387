"""The numpy-written MarkerArray against the same markers built one by one with rclpy.

The reference builds each Marker object by hand from the doc/design.md description (DELETEALL,
then static cubes, dynamic cubes coloured by whether they collide, one arrow per contact) and
rclpy deserialises the writer's bytes; the two messages must be equal field for field.
"""
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from collision_node.pipeline import scenes
from collision_node.pipeline.world import DYNAMIC, World
from collision_node.ros import markers
from collision_node.ros.markers import MarkerWriter


def color(rgba):
    r, g, b, a = rgba
    return ColorRGBA(r=r, g=g, b=b, a=a)


def marker(header, namespace, marker_type, marker_id, pose, scale, rgba):
    built = Marker(header=header, ns=namespace, type=marker_type, action=Marker.ADD,
                   id=int(marker_id), color=color(rgba))
    p, o = built.pose.position, built.pose.orientation
    p.x, p.y, p.z, o.x, o.y, o.z, o.w = (float(v) for v in pose)
    built.scale.x, built.scale.y, built.scale.z = (float(v) for v in scale)
    return built


def reference(frame_id, sec, nanosec, static_poses, static_extents, static_ids, poses, extents,
              contacts, arrow_orientations):
    """Build the MarkerArray marker by marker (arrow orientations are checked elsewhere)."""
    header = Header(frame_id=frame_id)
    header.stamp.sec, header.stamp.nanosec = sec, nanosec
    colliding = set()
    for contact in contacts:
        colliding.add(int(contact['id_a']))
        if contact['type_b'] == DYNAMIC:
            colliding.add(int(contact['id_b']))
    built = [Marker(header=header, action=Marker.DELETEALL)]
    for pose, extent, collider in zip(static_poses, static_extents, static_ids):
        built.append(marker(header, 'static', Marker.CUBE, collider, pose, 2 * extent,
                            markers.STATIC_COLOR))
    extents = np.broadcast_to(extents, (len(poses), 3))
    for body, (pose, extent) in enumerate(zip(poses, extents)):
        built.append(marker(header, 'dynamic', Marker.CUBE, body, pose, 2 * extent,
                            markers.COLLIDING_COLOR if body in colliding
                            else markers.FREE_COLOR))
    for k, contact in enumerate(contacts):
        pose = [contact['x'], contact['y'], contact['z']] + list(arrow_orientations[k])
        length = max(contact['depth'], markers.NORMAL_ARROW_MIN_LENGTH)
        built.append(marker(header, 'normals', Marker.ARROW, k, pose,
                            [length, markers.NORMAL_ARROW_WIDTH, 2 * markers.NORMAL_ARROW_WIDTH],
                            markers.NORMAL_COLOR))
    return MarkerArray(markers=built)


def x_axis(q):
    """First column of the rotation matrix of the unit quaternion x y z w."""
    x, y, z, w = q
    return [1 - 2 * (y * y + z * z), 2 * (x * y + z * w), 2 * (x * z - y * w)]


def scene_case(bodies, seed, disabled_every=0):
    scene = scenes.uniform(bodies, seed=seed)
    static_ids = np.arange(len(scene.static_poses))
    if disabled_every:  # disabled colliders keep their list index as marker id
        static_ids = static_ids[static_ids % disabled_every != 0]
    world = World(broad_phase='brute_force')
    world.set_static(scene.static_poses[static_ids], scene.static_half_extents[static_ids],
                     static_ids)
    poses = scene.dynamic_poses(0.4)
    contacts = world.step(poses, scene.dynamic_half_extents).contacts
    return (scene.static_poses[static_ids], scene.static_half_extents[static_ids], static_ids,
            poses, scene.dynamic_half_extents, contacts)


@pytest.mark.parametrize('frame_id', ['w', 'map', 'world', 'odom_12', 'a' * 13])
@pytest.mark.parametrize('bodies, disabled_every', [(0, 0), (2, 0), (300, 0), (300, 3)])
def test_markers_deserialise_to_the_reference(frame_id, bodies, disabled_every):
    case = scene_case(bodies, seed=bodies + len(frame_id), disabled_every=disabled_every)
    contacts = case[-1]
    assert bodies < 300 or len(contacts) > 10  # the larger scene has arrows to check
    data = MarkerWriter(frame_id).serialize(1234, 567, *case)
    got = deserialize_message(data, MarkerArray)
    arrows = got.markers[len(got.markers) - len(contacts):]
    orientations = [(m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z,
                     m.pose.orientation.w) for m in arrows]
    # Through rclpy's CDR too, so the colours are float32 on both sides.
    expected_data = serialize_message(reference(frame_id, 1234, 567, *case, orientations))
    expected = deserialize_message(expected_data, MarkerArray)
    assert len(got.markers) == len(expected.markers)
    for index, (mine, theirs) in enumerate(zip(got.markers, expected.markers)):
        assert mine == theirs, index
    assert len(data) == len(expected_data)  # padding aside, the bytes are rclpy's
    for contact, q in zip(contacts, orientations):
        assert np.linalg.norm(q) == pytest.approx(1.0)
        np.testing.assert_allclose(x_axis(q), [contact['normal_x'], contact['normal_y'],
                                               contact['normal_z']], atol=1e-12)


@pytest.mark.parametrize('sec, nanosec', [(-5, 7), (-2**31, 999999999), (2**31 - 1, 0)])
def test_every_marker_carries_the_input_stamp_negative_too(sec, nanosec):
    data = MarkerWriter('world').serialize(sec, nanosec, *scene_case(40, seed=9))
    got = deserialize_message(data, MarkerArray).markers
    assert len(got) > 1
    assert {(m.header.stamp.sec, m.header.stamp.nanosec) for m in got} == {(sec, nanosec)}


def test_one_size_for_all_bodies_and_float32_contacts():
    static_poses, static_extents, static_ids, poses, extents, contacts = scene_case(100, 4)
    cloud_like = contacts.astype([(name, '<f4' if contacts.dtype[name].kind == 'f' else '<u4')
                                  for name in contacts.dtype.names])
    data = MarkerWriter('world').serialize(1, 2, static_poses, static_extents, static_ids,
                                           poses, np.array([0.1, 0.2, 0.3]), cloud_like)
    got = deserialize_message(data, MarkerArray).markers
    dynamic = [m for m in got if m.ns == 'dynamic']
    assert [m.id for m in dynamic] == list(range(len(poses)))
    assert {(m.scale.x, m.scale.y, m.scale.z) for m in dynamic} == {(0.2, 0.4, 0.6)}
    arrows = [m for m in got if m.ns == 'normals']
    assert [m.pose.position.x for m in arrows] == [float(x) for x in cloud_like['x']]


@pytest.mark.parametrize('normal', [(1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, -1.0, 0.0),
                                    (-1.0, 1e-12, 0.0), (0.6, 0.0, -0.8)])
def test_arrows_point_along_the_normal_even_opposite_to_x(normal):
    turns = markers.quaternions_turning_x_to(np.array([normal]))
    assert np.linalg.norm(turns[0]) == pytest.approx(1.0)
    np.testing.assert_allclose(x_axis(turns[0]), normal, atol=1e-9)
