"""collision_node.ros.cdr against rclpy's own (de)serialisation, the independent reference."""
import struct

from geometry_msgs.msg import Point, Pose, PoseArray, Quaternion
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState, PointCloud2, PointField
from std_msgs.msg import Header

from collision_node.ros.cdr import (CdrError, parse_joint_state, parse_pose_array,
                                    serialize_point_cloud, serialize_pose_array)

LETTERS = 'abcdefghijklmnopq'
UTF8_FRAMES = ['wörld', 'カメラ_link', '\U0001f916', 'é' * 7]


def random_poses(rng, count):
    """Random float64 bit patterns: NaN payloads, infinities, -0.0 and subnormals included."""
    return rng.integers(0, 2**64, size=(count, 7), dtype=np.uint64).view(np.float64)


def pose_list(poses):
    return [Pose(position=Point(x=float(x), y=float(y), z=float(z)),
                 orientation=Quaternion(x=float(qx), y=float(qy), z=float(qz), w=float(qw)))
            for x, y, z, qx, qy, qz, qw in poses]


def pose_array(sec, nanosec, frame_id, poses, poses_as_list=None):
    msg = PoseArray()
    msg.header.stamp.sec = sec
    msg.header.stamp.nanosec = nanosec
    msg.header.frame_id = frame_id
    msg.poses = pose_list(poses) if poses_as_list is None else poses_as_list
    return msg


def poses_of(msg):
    return np.array([(p.position.x, p.position.y, p.position.z, p.orientation.x,
                      p.orientation.y, p.orientation.z, p.orientation.w)
                     for p in msg.poses], dtype=np.float64).reshape(-1, 7)


def assert_same_bits(actual, expected):
    assert actual.shape == expected.shape
    np.testing.assert_array_equal(np.ascontiguousarray(actual).view(np.uint64),
                                  np.ascontiguousarray(expected).view(np.uint64))


def assert_parsed_as(view, msg):
    assert (view.sec, view.nanosec, view.frame_id) == (
        msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id)
    assert_same_bits(view.poses, poses_of(msg))


def naive_pose_array_cdr(order, sec, nanosec, frame_id, poses):
    """Write PoseArray CDR field by field with struct, in byte order '<' or '>'."""
    out = bytearray(b'\x00\x01\x00\x00' if order == '<' else b'\x00\x00\x00\x00')

    def put(fmt, *values):  # aligned to the item's size, counted after the 4-byte header
        out.extend(bytes(-(len(out) - 4) % struct.calcsize(fmt)))
        out.extend(struct.pack(order + fmt, *values))

    text = frame_id.encode() + b'\x00'
    put('i', sec)
    put('I', nanosec)
    put('I', len(text))
    out.extend(text)
    put('I', len(poses))
    for value in poses.ravel():
        put('d', value)
    return bytes(out)


@pytest.mark.parametrize('count', [0, 1, 1000, 12000])
def test_parse_matches_rclpy_for_every_frame_id_length(count):
    rng = np.random.default_rng(count)
    poses = random_poses(rng, count)
    poses_as_list = pose_list(poses)  # built once: frame ids only change the padding
    for length in range(17):
        sec, nanosec = int(rng.integers(-2**31, 2**31)), int(rng.integers(0, 2**32))
        msg = pose_array(sec, nanosec, LETTERS[:length], poses, poses_as_list)
        view = parse_pose_array(serialize_message(msg))
        assert (view.sec, view.nanosec, view.frame_id) == (sec, nanosec, LETTERS[:length])
        assert_same_bits(view.poses, poses)


@pytest.mark.parametrize('frame_id', UTF8_FRAMES)
def test_parse_reads_utf8_frame_ids(frame_id):
    msg = pose_array(5, 6, frame_id, random_poses(np.random.default_rng(1), 2))
    assert_parsed_as(parse_pose_array(serialize_message(msg)), msg)


@pytest.mark.parametrize('sec, nanosec', [(-2**31, 0), (2**31 - 1, 2**32 - 1), (0, 999999999)])
def test_parse_reads_extreme_stamps(sec, nanosec):
    msg = pose_array(sec, nanosec, 'map', np.ones((1, 7)))
    assert_parsed_as(parse_pose_array(serialize_message(msg)), msg)


def test_poses_from_bytes_are_a_native_aligned_writeable_copy():
    buffer = serialize_message(pose_array(1, 2, 'abc', np.arange(21.0).reshape(3, 7)))
    poses = parse_pose_array(buffer).poses
    assert poses.dtype == np.float64 and poses.dtype.isnative
    assert poses.flags.c_contiguous and poses.flags.aligned and poses.flags.writeable
    assert not np.shares_memory(poses, np.frombuffer(buffer, np.uint8))
    np.testing.assert_array_equal(poses, np.arange(21.0).reshape(3, 7))


def test_poses_of_an_aligned_buffer_are_a_view():
    message = serialize_message(pose_array(1, 2, 'abc', np.arange(21.0).reshape(3, 7)))
    storage = np.zeros(len(message) // 8 + 2, np.uint64).view(np.uint8)
    # 4 bytes in, the body (and with it the 8-aligned pose block) starts 8-aligned.
    buffer = storage[4:4 + len(message)]
    buffer[:] = np.frombuffer(message, np.uint8)
    poses = parse_pose_array(buffer).poses
    assert np.shares_memory(poses, storage)
    assert poses.flags.aligned and poses.flags.writeable
    np.testing.assert_array_equal(poses, np.arange(21.0).reshape(3, 7))
    read_only = parse_pose_array(memoryview(buffer).toreadonly()).poses
    assert np.shares_memory(read_only, storage) and not read_only.flags.writeable


@pytest.mark.parametrize('make', [bytes, bytearray, memoryview,
                                  lambda b: np.frombuffer(b, np.uint8)])
def test_parse_accepts_any_byte_buffer(make):
    msg = pose_array(3, 4, 'odom', random_poses(np.random.default_rng(2), 4))
    assert_parsed_as(parse_pose_array(make(serialize_message(msg))), msg)


@pytest.mark.parametrize('count', [0, 1, 3])
def test_big_endian_cdr_reads_as_rclpy_reads_it(count):
    rng = np.random.default_rng(count)
    for length in range(9):
        poses = random_poses(rng, count)
        little = naive_pose_array_cdr('<', -7, 8, LETTERS[:length], poses)
        big = naive_pose_array_cdr('>', -7, 8, LETTERS[:length], poses)
        assert big != little
        for buffer in (little, big):  # rclpy reading both proves the naive writer right
            assert_parsed_as(parse_pose_array(buffer), deserialize_message(buffer, PoseArray))
        assert parse_pose_array(big).poses.dtype.isnative


def test_every_truncation_of_small_messages_is_rejected():
    rng = np.random.default_rng(3)
    for length in range(9):
        for count in (0, 1, 2):
            buffer = serialize_message(pose_array(1, 2, LETTERS[:length],
                                                  random_poses(rng, count)))
            for cut in range(len(buffer)):
                with pytest.raises(CdrError):
                    parse_pose_array(buffer[:cut])


def test_random_truncations_of_a_large_message_are_rejected():
    rng = np.random.default_rng(4)
    buffer = serialize_message(pose_array(1, 2, 'world', random_poses(rng, 12000)))
    cuts = list(rng.integers(0, len(buffer), 100)) + [len(buffer) - k for k in (1, 8, 56)]
    for cut in cuts:
        with pytest.raises(CdrError, match='truncated|too short'):
            parse_pose_array(buffer[:cut])


@pytest.mark.parametrize('count', [0, 2])
def test_up_to_seven_trailing_bytes_are_padding_more_are_rejected(count):
    msg = pose_array(1, 2, 'abc', random_poses(np.random.default_rng(5), count))
    buffer = serialize_message(msg)
    for extra in range(1, 8):
        assert_parsed_as(parse_pose_array(buffer + b'\xa5' * extra), msg)
    for extra in (8, 56, 1000):
        with pytest.raises(CdrError, match='follow the last'):
            parse_pose_array(buffer + bytes(extra))


# Offsets in a PoseArray with frame_id 'abc' and 2 poses: 4-byte encapsulation header, then
# sec 4, nanosec 8, frame_id length 12, 'abc\0' 16..19, count 20, padding 24, poses 28.
SMALL = serialize_message(pose_array(1, 2, 'abc', np.arange(14.0).reshape(2, 7)))


def patched(offset, replacement, buffer=SMALL):
    return buffer[:offset] + replacement + buffer[offset + len(replacement):]


@pytest.mark.parametrize('buffer, reason', [
    (b'', 'too short'),
    (b'\x00\x01\x00', 'too short'),
    (SMALL[:15], 'truncated'),
    (patched(0, b'\x00\x02'), 'encapsulation'),
    (patched(0, b'\x00\x03'), 'encapsulation'),
    (patched(0, b'\x00\x07'), 'encapsulation'),
    (patched(0, b'\x01\x00'), 'encapsulation'),
    (patched(0, b'\xff\xff'), 'encapsulation'),
    (patched(12, struct.pack('<I', 0)), 'length 0'),
    (patched(12, struct.pack('<I', 2**32 - 1)), 'truncated'),
    (patched(12, struct.pack('<I', 5)), 'NUL'),
    (patched(12, struct.pack('<I', 3)), 'NUL'),
    (patched(19, b'x'), 'does not end with a NUL'),
    (patched(17, b'\x00'), 'NUL byte before its end'),
    (patched(17, b'\xff'), 'not UTF-8'),
    (patched(20, struct.pack('<I', 2**32 - 1)), 'truncated'),
    (patched(20, struct.pack('<I', 3)), 'truncated'),
    (patched(20, struct.pack('<I', 1)), 'follow the last'),
    (patched(20, struct.pack('<I', 0)), 'follow the last'),
])
def test_garbled_messages_are_rejected_with_a_reason(buffer, reason):
    with pytest.raises(CdrError, match=reason):
        parse_pose_array(buffer)


def test_option_bytes_and_padding_bytes_are_ignored():
    expected = deserialize_message(SMALL, PoseArray)
    for buffer in (patched(2, b'\x12\x34'), patched(24, b'\xde\xad\xbe\xef')):
        assert_parsed_as(parse_pose_array(buffer), expected)


def test_random_mutations_parse_as_rclpy_reads_them_or_are_rejected():
    """A parse that succeeds must give what rclpy's deserializer gives, bit for bit."""
    rng = np.random.default_rng(6)
    parsed = rejected = 0
    for length in range(6):
        for count in (0, 1, 3):
            original = serialize_message(pose_array(
                int(rng.integers(-2**31, 2**31)), int(rng.integers(0, 2**32)),
                LETTERS[:length], random_poses(rng, count)))
            for _ in range(150):
                buffer = bytearray(original)
                header_end = min(len(buffer), 28)  # half the mutations hit the header
                for _ in range(rng.integers(1, 4)):
                    end = header_end if rng.random() < 0.5 else len(buffer)
                    buffer[rng.integers(0, end)] = rng.integers(0, 256)
                try:
                    view = parse_pose_array(bytes(buffer))
                except CdrError:
                    rejected += 1
                    continue
                assert_parsed_as(view, deserialize_message(bytes(buffer), PoseArray))
                parsed += 1
    assert parsed > 500 and rejected > 500  # both branches were really exercised


def assert_same_cdr_but_padding(ours, reference, message_type):
    """Equal length, rclpy reads ours back, and the bytes differ only in our zero padding.

    rclpy leaves padding uninitialised, so a byte-for-byte comparison would test garbage.
    """
    assert len(ours) == len(reference)
    assert deserialize_message(ours, message_type) == deserialize_message(reference,
                                                                          message_type)
    ours_array, reference_array = (np.frombuffer(b, np.uint8) for b in (ours, reference))
    differing = np.flatnonzero(ours_array != reference_array)
    assert np.all(ours_array[differing] == 0)
    return differing


@pytest.mark.parametrize('count', [0, 1, 5, 1000])
def test_serialize_pose_array_matches_rclpy(count):
    rng = np.random.default_rng(7)
    poses = rng.normal(size=(count, 7)) * 1e3
    for frame_id in [LETTERS[:length] for length in range(10)] + UTF8_FRAMES:
        msg = pose_array(-4, 999, frame_id, poses)
        ours = serialize_pose_array(-4, 999, frame_id, poses)
        differing = assert_same_cdr_but_padding(ours, serialize_message(msg), PoseArray)
        assert len(differing) <= 7  # at most 3 after the frame_id, 4 before the poses
        assert_parsed_as(parse_pose_array(ours), msg)


def test_serialize_pose_array_keeps_every_bit():
    poses = random_poses(np.random.default_rng(8), 50)
    view = parse_pose_array(serialize_pose_array(0, 0, 'x', poses))
    assert_same_bits(view.poses, poses)


@pytest.mark.parametrize('arguments, reason', [
    ((0, 0, 'a', np.zeros((3, 6))), 'shape'),
    ((0, 0, 'a', np.zeros(7)), 'shape'),
    ((2**31, 0, 'a', np.zeros((1, 7))), 'sec'),
    ((0, -1, 'a', np.zeros((1, 7))), 'nanosec'),
    ((0, 2**32, 'a', np.zeros((1, 7))), 'nanosec'),
    ((0, 0, 'a\x00b', np.zeros((1, 7))), 'NUL'),
])
def test_serialize_pose_array_rejects_invalid_input(arguments, reason):
    with pytest.raises(ValueError, match=reason):
        serialize_pose_array(*arguments)


# Every PointField datatype once, at offsets with gaps, and a trailing gap in the point.
POINT_DTYPE = np.dtype({
    'names': ['int8', 'uint8', 'int16', 'uint16', 'int32', 'uint32', 'float32', 'float64'],
    'formats': ['i1', 'u1', '<i2', '<u2', '<i4', '<u4', '<f4', '<f8'],
    'offsets': [0, 1, 2, 6, 8, 12, 16, 24],
    'itemsize': 40})
POINT_DATATYPES = [PointField.INT8, PointField.UINT8, PointField.INT16, PointField.UINT16,
                   PointField.INT32, PointField.UINT32, PointField.FLOAT32, PointField.FLOAT64]


@pytest.mark.parametrize('count', [0, 1, 5, 300])
def test_serialize_point_cloud_matches_rclpy(count):
    rng = np.random.default_rng(count)
    points = np.zeros(count, POINT_DTYPE)
    for name in POINT_DTYPE.names:
        points[name] = rng.integers(0, 100, count)
    fields = [PointField(name=name, offset=POINT_DTYPE.fields[name][1], datatype=datatype,
                         count=1) for name, datatype in zip(POINT_DTYPE.names, POINT_DATATYPES)]
    for frame_id in [LETTERS[:length] for length in range(5)] + UTF8_FRAMES[:1]:
        for is_dense in (True, False):
            msg = PointCloud2(header=Header(frame_id=frame_id), height=1, width=count,
                              fields=fields, is_bigendian=False, point_step=40,
                              row_step=40 * count, data=points.tobytes(), is_dense=is_dense)
            msg.header.stamp.sec, msg.header.stamp.nanosec = 17, 18
            ours = serialize_point_cloud(17, 18, frame_id, points, is_dense)
            assert_same_cdr_but_padding(ours, serialize_message(msg), PointCloud2)


@pytest.mark.parametrize('points, reason', [
    (np.zeros(3), 'structured'),
    (np.zeros(3, [('x', '>f4')]), 'little-endian'),
    (np.zeros(3, [('x', '<f4', (3,))]), 'little-endian'),
    (np.zeros(3, [('x', 'c8')]), 'little-endian'),
    (np.zeros((2, 2), [('x', '<f4')]), '1-D'),
    (np.zeros(2, [('x\x00', '<f4')]), 'NUL'),
])
def test_serialize_point_cloud_rejects_other_arrays(points, reason):
    with pytest.raises(ValueError, match=reason):
        serialize_point_cloud(0, 0, 'map', points)


# -- sensor_msgs/JointState ----------------------------------------------------------------

def joint_state(frame_id, names, positions, velocities=(), efforts=()):
    msg = JointState()
    msg.header.stamp.sec, msg.header.stamp.nanosec = -3, 4
    msg.header.frame_id = frame_id
    msg.name = list(names)
    msg.position = [float(value) for value in positions]
    msg.velocity = [float(value) for value in velocities]
    msg.effort = [float(value) for value in efforts]
    return msg


def assert_joint_state_as(view, msg):
    assert (view.sec, view.nanosec, view.frame_id) == (
        msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id)
    assert view.names == tuple(msg.name)
    assert_same_bits(view.positions, np.array(msg.position, np.float64))
    assert view.positions.dtype.isnative and view.positions.flags.aligned


@pytest.mark.parametrize('count', [0, 1, 2, 9])
def test_joint_state_parses_as_rclpy_reads_it(count):
    rng = np.random.default_rng(20 + count)
    for frame_length in range(4):
        names = [LETTERS[:k % 6] + UTF8_FRAMES[k % 4] * (k % 2) for k in range(count)]
        for lengths in ((count, 0, 0), (count, count, count), (0, count, 0), (count, 1, 3)):
            values = [rng.normal(size=n) for n in lengths]
            buffer = serialize_message(joint_state(LETTERS[:frame_length], names, *values))
            expected = deserialize_message(buffer, JointState)
            assert_joint_state_as(parse_joint_state(buffer), expected)


def test_joint_state_reuses_the_names_of_the_previous_message_only_when_they_are_the_same():
    first = parse_joint_state(serialize_message(joint_state('', ['a', 'bc'], [1.0, 2.0])))
    same = parse_joint_state(serialize_message(joint_state('', ['a', 'bc'], [3.0, 4.0])), first)
    assert same.names is first.names and list(same.positions) == [3.0, 4.0]
    for names in (['a', 'bd'], ['a'], ['a', 'bc', 'e'], ['bc', 'a']):
        other = parse_joint_state(serialize_message(joint_state('x', names, range(len(names)))),
                                  first)
        assert other.names == tuple(names)


def test_every_truncation_of_a_joint_state_is_rejected():
    buffer = serialize_message(joint_state('base', ['j1', 'joint_2'], [0.5, -1.0], [1.0],
                                           [2.0, 3.0]))
    for cut in range(len(buffer)):
        with pytest.raises(CdrError):
            parse_joint_state(buffer[:cut])
    with pytest.raises(CdrError, match='follow the effort'):
        parse_joint_state(buffer + bytes(24))


def test_a_joint_state_claiming_more_names_than_fit_is_rejected_before_reading_them():
    buffer = bytearray(serialize_message(joint_state('', ['a'], [1.0])))
    struct.pack_into('<I', buffer, 4 + 16, 2**31)  # the name count, after an empty frame_id
    with pytest.raises(CdrError, match='name strings cannot fit'):
        parse_joint_state(bytes(buffer))
