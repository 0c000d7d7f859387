"""The `collisions` cloud against a naive per-point build of the layout in doc/design.md."""
import struct

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

from collision_node.pipeline.contacts import STATE_CONTACT_DTYPE
from collision_node.pipeline.world import CONTACT_DTYPE
from collision_node.ros.messages import (CLOUD_DTYPE, cloud_to_contacts, CloudWriter,
                                         contacts_to_cloud, contacts_to_points,
                                         serialize_collisions)

FLOAT_NAMES = ['x', 'y', 'z', 'normal_x', 'normal_y', 'normal_z', 'depth', 'distance', 'toi']
ID_NAMES = ['id_a', 'type_a', 'id_b', 'type_b']
# The point as doc/design.md specifies it: the fields added later (distance, toi) come last.
POINT_NAMES = FLOAT_NAMES[:7] + ID_NAMES + ['distance', 'toi']
POINT_STEP = 52
# (name, offset, datatype, count) of each field.
EXPECTED_FIELDS = [(name, 4 * i, PointField.FLOAT32 if name in FLOAT_NAMES else PointField.UINT32,
                    1) for i, name in enumerate(POINT_NAMES)]


def random_contacts(rng, count):
    contacts = np.zeros(count, CONTACT_DTYPE)
    for name in FLOAT_NAMES:
        contacts[name] = rng.normal(size=count) * 10.0 ** rng.integers(-6, 4, count)
    for name in ID_NAMES:
        contacts[name] = rng.integers(0, 2**32, count, dtype=np.uint64)
    return contacts


def naive_cloud_data(contacts):
    """Pack the points one at a time with struct."""
    def value(contact, name):
        return float(contact[name]) if name in FLOAT_NAMES else int(contact[name])
    return b''.join(struct.pack('<7f4I2f', *(value(c, name) for name in POINT_NAMES))
                    for c in contacts)


def stamped_header(frame_id='world'):
    header = Header(frame_id=frame_id)
    header.stamp.sec, header.stamp.nanosec = 1234, 5678
    return header


@pytest.mark.parametrize('count', [0, 1, 7, 1000])
def test_cloud_has_the_documented_layout(count):
    contacts = random_contacts(np.random.default_rng(count), count)
    header = stamped_header()
    cloud = contacts_to_cloud(contacts, header)
    assert cloud.header == header
    assert (cloud.height, cloud.width, cloud.point_step, cloud.row_step) == (
        1, count, POINT_STEP, POINT_STEP * count)
    assert cloud.is_dense and not cloud.is_bigendian
    assert [(f.name, f.offset, f.datatype, f.count) for f in cloud.fields] == EXPECTED_FIELDS
    assert bytes(cloud.data) == naive_cloud_data(contacts)


@pytest.mark.parametrize('count', [0, 1, 7, 1000])
def test_round_trip_through_ros_serialisation(count):
    contacts = random_contacts(np.random.default_rng(count + 1), count)
    cloud = deserialize_message(serialize_message(contacts_to_cloud(contacts, Header())),
                                PointCloud2)
    points = cloud_to_contacts(cloud)
    assert points.dtype.names == tuple(POINT_NAMES)
    assert points.shape == (count,)
    for name in FLOAT_NAMES:
        assert points.dtype[name] == np.float32
        np.testing.assert_array_equal(points[name], contacts[name].astype(np.float32))
    for name in ID_NAMES:
        assert points.dtype[name] == np.uint32
        np.testing.assert_array_equal(points[name], contacts[name])
    # A cloud read back goes out again unchanged.
    assert bytes(contacts_to_cloud(points, Header()).data) == bytes(cloud.data)


def test_contacts_are_copied_out_of_the_message():
    cloud = contacts_to_cloud(random_contacts(np.random.default_rng(2), 3), Header())
    before = bytes(cloud.data)
    cloud_to_contacts(cloud)['x'] = 99.0
    assert bytes(cloud.data) == before


def test_world_contacts_become_a_cloud():
    from collision_node import World  # the real producer of contacts
    world = World(broad_phase='brute_force')
    world.set_static([[0, 0, 0, 0, 0, 0, 1]], [1, 1, 1])
    result = world.step([[1.5, 0, 0, 0, 0, 0, 1], [2.2, 0, 0, 0, 0, 0, 1]], [0.6, 0.6, 0.6])
    assert len(result.contacts) == 2
    cloud = contacts_to_cloud(result.contacts, Header())
    assert bytes(cloud.data) == naive_cloud_data(result.contacts)


@pytest.mark.parametrize('count', [0, 1, 25, 2000])
def test_serialize_collisions_is_the_cloud_rclpy_serialises(count):
    contacts = random_contacts(np.random.default_rng(count + 3), count)
    for frame_id in ['', 'w', 'world', 'base_link']:
        ours = serialize_collisions(contacts, 1234, 5678, frame_id)
        reference = serialize_message(contacts_to_cloud(contacts, stamped_header(frame_id)))
        assert len(ours) == len(reference)
        assert deserialize_message(ours, PointCloud2) == deserialize_message(reference,
                                                                             PointCloud2)
        ours_array, reference_array = (np.frombuffer(b, np.uint8) for b in (ours, reference))
        differing = np.flatnonzero(ours_array != reference_array)
        assert np.all(ours_array[differing] == 0)  # rclpy leaves its padding uninitialised


def test_cloud_writer_reused_for_other_sizes_and_layouts():
    # One writer keeps its buffer: a smaller cloud after a larger one must not carry bytes of
    # it; cloud-typed and strided contacts take the numpy path, World contacts the kernel.
    rng = np.random.default_rng(6)
    writer = CloudWriter()
    for contacts in (random_contacts(rng, 300), random_contacts(rng, 5),
                     contacts_to_points(random_contacts(rng, 40)), random_contacts(rng, 60)[::3],
                     random_contacts(rng, 0)):
        reference = serialize_message(contacts_to_cloud(contacts, stamped_header()))
        ours = writer.serialize(contacts, 1234, 5678, 'world')
        assert deserialize_message(ours, PointCloud2) == deserialize_message(reference,
                                                                             PointCloud2)
        assert ours[-len(contacts) * POINT_STEP - 1:-1] == naive_cloud_data(contacts)


def test_a_writer_of_state_contacts_writes_the_collisions_cloud_without_their_state():
    # The node answers joint_states with World.check_joints: contacts that carry their state.
    writer = CloudWriter(STATE_CONTACT_DTYPE, CONTACT_DTYPE.names)
    for count in (7, 0, 30):
        contacts = random_contacts(np.random.default_rng(count), count)
        with_state = np.zeros(count, STATE_CONTACT_DTYPE)
        for name in CONTACT_DTYPE.names:
            with_state[name] = contacts[name]
        with_state['state'] = 3
        ours = writer.serialize(with_state, 1234, 5678, 'world')
        reference = serialize_message(contacts_to_cloud(contacts, stamped_header()))
        assert deserialize_message(ours, PointCloud2) == deserialize_message(reference,
                                                                             PointCloud2)
        assert ours[-count * POINT_STEP - 1:-1] == naive_cloud_data(contacts)


def test_contacts_to_points_keeps_the_order_of_the_cloud():
    contacts = random_contacts(np.random.default_rng(4), 50)
    points = contacts_to_points(contacts)
    assert points.dtype == CLOUD_DTYPE and CLOUD_DTYPE.itemsize == POINT_STEP
    assert points.tobytes() == naive_cloud_data(contacts)


def valid_cloud():
    return contacts_to_cloud(random_contacts(np.random.default_rng(5), 4), Header())


def with_fields(fields):
    cloud = valid_cloud()
    cloud.fields = [PointField(name=n, offset=o, datatype=d, count=c) for n, o, d, c in fields]
    return cloud


def with_changes(**changes):
    cloud = valid_cloud()
    for name, value in changes.items():
        setattr(cloud, name, value)
    return cloud


XYZ_FIELDS = [('x', 0, PointField.FLOAT32, 1), ('y', 4, PointField.FLOAT32, 1),
              ('z', 8, PointField.FLOAT32, 1)]


@pytest.mark.parametrize('cloud, reason', [
    (with_fields(XYZ_FIELDS), 'fields'),
    (with_fields(EXPECTED_FIELDS[:-1]), 'fields'),
    (with_fields(EXPECTED_FIELDS + [('extra', POINT_STEP, PointField.UINT32, 1)]), 'fields'),
    (with_fields([('X',) + EXPECTED_FIELDS[0][1:]] + EXPECTED_FIELDS[1:]), 'fields'),
    (with_fields([EXPECTED_FIELDS[1], EXPECTED_FIELDS[0]] + EXPECTED_FIELDS[2:]), 'fields'),
    (with_fields(EXPECTED_FIELDS[:6] + [('depth', 24, PointField.FLOAT64, 1)]
                 + EXPECTED_FIELDS[7:]), 'fields'),
    (with_fields(EXPECTED_FIELDS[:-2] + [('distance', 44, PointField.FLOAT32, 2)]
                 + EXPECTED_FIELDS[-1:]), 'fields'),
    (with_changes(is_bigendian=True), 'big-endian'),
    (with_changes(point_step=POINT_STEP + 4, row_step=4 * (POINT_STEP + 4)), 'point_step'),
    (with_changes(row_step=POINT_STEP * 3), 'row_step'),
    (with_changes(width=5, row_step=POINT_STEP * 5), 'data bytes'),
    (with_changes(height=2), 'data bytes'),
])
def test_clouds_that_are_not_collisions_clouds_are_rejected(cloud, reason):
    with pytest.raises(ValueError, match=reason):
        cloud_to_contacts(cloud)


def test_cloud_to_contacts_wants_a_point_cloud():
    with pytest.raises(TypeError, match='PointCloud2'):
        cloud_to_contacts(Header())


@pytest.mark.parametrize('contacts, reason', [
    (np.zeros((3, 11)), 'structured'),
    (np.zeros((2, 2), CONTACT_DTYPE), '1-D'),
    (np.zeros(3, [(name, 'f8') for name in FLOAT_NAMES]), 'fields'),
    (np.zeros(3, [(name, 'f8') for name in FLOAT_NAMES] + [(name, 'i8') for name in ID_NAMES]),
     'unsigned'),
    (np.zeros(3, [(name, 'u4') for name in POINT_NAMES]), 'float'),
])
def test_other_arrays_are_not_contacts(contacts, reason):
    with pytest.raises(ValueError, match=reason):
        contacts_to_cloud(contacts, Header())
    with pytest.raises(ValueError, match=reason):
        serialize_collisions(contacts, 0, 0, 'world')
