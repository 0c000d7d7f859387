"""CDR bytes of the node's messages, read and written with numpy (no rclpy import).

rclpy's own conversion between CDR and Python message objects costs ~6 µs per pose; these
functions read and write the pose and point blocks as single numpy arrays instead.

Layout (plain CDR, XCDR1, as Fast DDS writes it for ROS 2): a 4-byte encapsulation header
(representation id, big-endian, then 2 option bytes), then the body. Every primitive is aligned
to its own size, counted from the start of the body. Strings are a uint32 length that includes
the terminating NUL, then the characters and the NUL. Padding bytes carry no meaning and are
not zeroed by rclpy, so the parser never looks at them.
"""
import functools
import operator
import struct
from typing import NamedTuple

import numpy as np

ENCAPSULATION_SIZE = 4
# Representation ids of plain CDR (XCDR1). XCDR2 (0x0006..0x000b) aligns float64 to 4 bytes,
# parameter-list CDR (0x0002, 0x0003) adds member headers: neither is the layout read here.
CDR_BE = b'\x00\x00'
CDR_LE = b'\x00\x01'
# A DDS payload may be padded at its end to a multiple of 4 (the option bytes count that
# padding); 7 also covers padding to the 8-byte alignment of float64. More is not padding.
MAX_TRAILING_BYTES = 7
# rclpy sizes a JointState as if its empty float64 sequences were aligned to 8 as well: up to
# 12 bytes follow the last one (measured over names, frame_id and sequence lengths); 4 more
# for a payload padded to a multiple of 4.
MAX_JOINT_STATE_TRAILING_BYTES = 16
POSE_FIELDS = 7  # x y z qx qy qz qw, as float64
POSE_SIZE = POSE_FIELDS * 8

# sensor_msgs/PointField datatype codes of the numpy scalar types a cloud may hold.
POINT_FIELD_DATATYPES = {
    np.dtype(np.int8): 1, np.dtype(np.uint8): 2, np.dtype('<i2'): 3, np.dtype('<u2'): 4,
    np.dtype('<i4'): 5, np.dtype('<u4'): 6, np.dtype('<f4'): 7, np.dtype('<f8'): 8,
}
# Per representation: the stamp and frame_id length, the pose count, a pose value.
_LAYOUTS = {CDR_LE: (struct.Struct('<iII'), struct.Struct('<I'), np.dtype('<f8')),
            CDR_BE: (struct.Struct('>iII'), struct.Struct('>I'), np.dtype('>f8'))}
INT32_RANGE = (-2**31, 2**31 - 1)
UINT32_RANGE = (0, 2**32 - 1)


class CdrError(ValueError):
    """A buffer that is not the CDR of the expected message; the text says what is wrong."""


class PoseArrayView(NamedTuple):
    """A parsed geometry_msgs/PoseArray: stamp, frame and poses (N, 7) x y z qx qy qz qw.

    ``poses`` is float64 in native byte order, C-contiguous and aligned, so numba kernels and
    ``np.require(poses, np.float64, ['C', 'A', 'W'])`` take it as it is, unless it is a
    read-only view. It is a view of the buffer when the pose block is little-endian and 8-byte
    aligned (writeable only if the buffer is: a view of ``bytes`` is read-only), else a
    writeable copy. rclpy's ``raw=True`` messages are ``bytes`` whose data start 8-byte
    aligned, which puts the pose block at 4 modulo 8 (after the encapsulation header): they
    get the copy, so exactly one copy of the poses is made on the way to the kernels.
    ``count_end``: the body offset after the pose count.
    """

    sec: int
    nanosec: int
    frame_id: str
    poses: np.ndarray
    count_end: int


def parse_pose_array(buffer):
    """Read a serialized geometry_msgs/PoseArray (e.g. from ``raw=True`` subscriptions).

    Accepts little- and big-endian plain CDR; any object with the buffer protocol.
    Raises CdrError saying why the buffer is not a PoseArray.
    """
    data, body, layout, sec, nanosec, frame_id, at = _header(buffer)
    _, count_format, value_type = layout
    size = len(body)
    count, poses_at = _count(body, at, count_format, 'pose')
    count_end = poses_at
    if count:
        poses_at = _aligned(poses_at, 8)
    end = poses_at + count * POSE_SIZE
    if end > size:
        raise CdrError('truncated: %d poses need %d body bytes, the buffer has %d'
                       % (count, end, size))
    if size - end > MAX_TRAILING_BYTES:
        raise CdrError('%d bytes follow the last of %d poses; at most %d may be padding'
                       % (size - end, count, MAX_TRAILING_BYTES))

    poses = np.frombuffer(data, dtype=value_type, count=count * POSE_FIELDS,
                          offset=ENCAPSULATION_SIZE + poses_at).reshape(count, POSE_FIELDS)
    if not (poses.dtype.isnative and poses.flags.aligned):
        poses = poses.astype(np.float64)  # a native, aligned, writeable copy
    return PoseArrayView(sec, nanosec, frame_id, poses, count_end)


class JointStateView(NamedTuple):
    """A parsed sensor_msgs/JointState: stamp, frame, names and positions (float64, native).

    ``names_block`` is the CDR of the name sequence: handed back to :func:`parse_joint_state`
    as ``previous``, a message with the same names (a driver's every message) reuses
    ``names`` without decoding a string. ``names_end``: the body offset after it.
    """

    sec: int
    nanosec: int
    frame_id: str
    names: tuple
    positions: np.ndarray
    names_block: bytes
    names_end: int


def parse_joint_state(buffer, previous=None):
    """Read a serialized sensor_msgs/JointState; its velocities and efforts are only checked.

    ``previous``: the JointStateView of the publisher's last message, or None. Accepts
    little- and big-endian plain CDR. Raises CdrError saying why the buffer is not a
    JointState.
    """
    data, body, layout, sec, nanosec, frame_id, at = _header(buffer)
    _, count_format, value_type = layout
    names_at = _aligned(at, 4)
    # The sequence's bytes hold its count and each string's length: the same bytes are the
    # same names.
    block = previous.names_block if previous is not None else b''
    if block and body[names_at:names_at + len(block)] == block:
        names, at = previous.names, names_at + len(block)
    else:
        names, at = _strings(body, names_at, count_format, 'name')
        block = bytes(body[names_at:at])
    names_end = at
    positions, at = _doubles(data, at, count_format, value_type, 'position')
    for field in ('velocity', 'effort'):
        at = _doubles(data, at, count_format, value_type, field)[1]
    if len(body) - at > MAX_JOINT_STATE_TRAILING_BYTES:
        raise CdrError('%d bytes follow the effort sequence; at most %d may be padding'
                       % (len(body) - at, MAX_JOINT_STATE_TRAILING_BYTES))
    if not (positions.dtype.isnative and positions.flags.aligned):
        positions = positions.astype(np.float64)  # a native, aligned, writeable copy
    return JointStateView(sec, nanosec, frame_id, names, positions, block, names_end)


def serialize_pose_array(sec, nanosec, frame_id, poses):
    """Little-endian CDR of a geometry_msgs/PoseArray; poses (N, 7) x y z qx qy qz qw.

    Padding is zeroed. Raises ValueError on a stamp out of range, a frame_id with a NUL, or
    poses of another shape.
    """
    poses = np.ascontiguousarray(poses, dtype='<f8')
    if poses.ndim != 2 or poses.shape[1] != POSE_FIELDS:
        raise ValueError('poses must have shape (N, 7) as x y z qx qy qz qw, got %s'
                         % (poses.shape,))
    writer = _Writer()
    writer.header(sec, nanosec, frame_id)
    writer.uint32(len(poses))
    if len(poses):
        writer.align(8)
    writer.append(_bytes_of(poses))
    return writer.tobytes()


def serialize_point_cloud(sec, nanosec, frame_id, points, is_dense=True):
    """Little-endian CDR of a sensor_msgs/PointCloud2 of height 1 holding ``points``.

    ``points`` is a 1-D structured array; each field becomes a PointField (name, offset,
    datatype from the field's little-endian scalar type, count 1) and its itemsize the
    point_step. Raises ValueError for other arrays.
    """
    points = np.asarray(points)
    if points.ndim != 1:
        raise ValueError('points must be a 1-D structured array, got shape %s'
                         % (points.shape,))
    head, tail = point_cloud_parts(sec, nanosec, frame_id, points.dtype, len(points), is_dense)
    return b''.join((head, _bytes_of(points), tail))


def point_cloud_parts(sec, nanosec, frame_id, dtype, width, is_dense=True):
    """Return the CDR bytes before and after the ``data`` of a cloud like serialize_point_cloud's.

    For writers that put the ``width`` points of ``dtype`` between them themselves.
    """
    fields = _point_fields(np.dtype(dtype))
    writer = _Writer()
    writer.header(sec, nanosec, frame_id)
    writer.uint32(1)  # height
    writer.uint32(width)
    writer.append(fields)  # 4-aligned at both ends, like the uint32 before it
    writer.uint8(0)  # is_bigendian
    writer.uint32(dtype.itemsize)  # point_step
    writer.uint32(dtype.itemsize * width)  # row_step
    writer.uint32(dtype.itemsize * width)  # length of data
    return writer.tobytes(), struct.pack('<B', bool(is_dense))


@functools.lru_cache(maxsize=8)  # a node publishes one point type: build its fields once
def _point_fields(dtype):
    """Write the PointField sequence describing ``dtype`` as if at a 4-aligned offset."""
    if dtype.names is None:
        raise ValueError('points must be a structured array, got dtype %s' % dtype)
    writer = _Writer()
    writer.uint32(len(dtype.names))
    for name in dtype.names:
        field_type, offset = dtype.fields[name][:2]
        if field_type not in POINT_FIELD_DATATYPES:
            raise ValueError('field %r has type %s; a PointField holds one little-endian '
                             'scalar: %s' % (name, field_type, ', '.join(
                                 str(t) for t in POINT_FIELD_DATATYPES)))
        writer.string(name)
        writer.uint32(offset)
        writer.uint8(POINT_FIELD_DATATYPES[field_type])
        writer.uint32(1)  # count
    return writer.body()


def _header(buffer):
    """Return the buffer's bytes, body, layout, stamp, frame_id and the body offset after it."""
    # A memoryview and struct, not numpy, for the header: a dozen small numpy calls cost
    # ~80 µs from a cold cache, as every input at a robot's rate comes (doc/benchmarks.md).
    data = memoryview(buffer).cast('B')
    if len(data) < ENCAPSULATION_SIZE:
        raise CdrError('%d bytes are too short for the 4-byte CDR encapsulation header'
                       % len(data))
    representation = bytes(data[:2])
    if representation not in _LAYOUTS:
        raise CdrError('unsupported CDR encapsulation 0x%s; expected plain CDR 0x0001 '
                       '(little-endian) or 0x0000 (big-endian)' % representation.hex())
    layout = _LAYOUTS[representation]
    stamp_and_length = layout[0]
    body = data[ENCAPSULATION_SIZE:]  # offsets count from the body's start
    if len(body) < stamp_and_length.size:
        raise CdrError('truncated: %d body bytes cannot hold the stamp and the frame_id '
                       'length (12 bytes)' % len(body))
    sec, nanosec, length = stamp_and_length.unpack_from(body, 0)
    frame_id = _string(body, stamp_and_length.size, length, 'frame_id')
    return data, body, layout, sec, nanosec, frame_id, stamp_and_length.size + length


def _string(body, start, length, what):
    if length == 0:
        raise CdrError('%s length 0: a CDR string holds at least its NUL' % what)
    end = start + length
    if end > len(body):
        raise CdrError('truncated: %s of %d bytes would end at body byte %d of %d'
                       % (what, length, end, len(body)))
    text = bytes(body[start:end - 1])
    if body[end - 1] != 0:
        raise CdrError('%s does not end with a NUL byte' % what)
    if b'\x00' in text:
        raise CdrError('%s holds a NUL byte before its end' % what)
    try:
        return text.decode('utf-8')
    except UnicodeDecodeError as error:
        raise CdrError('%s is not UTF-8: %s' % (what, error)) from None


def _count(body, at, count_format, what):
    """Return a sequence's length at body offset ``at`` (aligned here) and where it ends."""
    at = _aligned(at, 4)
    if at + 4 > len(body):
        raise CdrError('truncated: the %s count would end at body byte %d of %d'
                       % (what, at + 4, len(body)))
    return count_format.unpack_from(body, at)[0], at + 4


def _strings(body, at, count_format, what):
    """Return a sequence of strings at ``at`` as a tuple, and the body offset after it."""
    count, at = _count(body, at, count_format, what)
    if count > len(body) // 5:  # each string takes at least its length and its NUL
        raise CdrError('truncated: %d %s strings cannot fit in %d body bytes'
                       % (count, what, len(body)))
    texts = []
    for index in range(count):
        length, at = _count(body, at, count_format, '%s %d length' % (what, index))
        texts.append(_string(body, at, length, '%s %d' % (what, index)))
        at += length
    return tuple(texts), at


def _doubles(data, at, count_format, value_type, what):
    """Return a float64 sequence at body offset ``at`` (a view), and the offset after it."""
    body = data[ENCAPSULATION_SIZE:]
    count, at = _count(body, at, count_format, what)
    if count:
        at = _aligned(at, 8)
    end = at + 8 * count
    if end > len(body):
        raise CdrError('truncated: %d %s values need %d body bytes, the buffer has %d'
                       % (count, what, end, len(body)))
    return np.frombuffer(data, dtype=value_type, count=count,
                         offset=ENCAPSULATION_SIZE + at), end


def _bytes_of(array):
    """View the array's bytes without a copy (b''.join takes any contiguous buffer)."""
    return np.ascontiguousarray(array).reshape(-1).view(np.uint8)


def _aligned(offset, alignment):
    return -(-offset // alignment) * alignment


class _Writer:
    """A little-endian CDR body collected as a list of byte strings."""

    def __init__(self):
        self._parts = []
        self._size = 0  # body bytes so far: alignment counts from the body's start

    def append(self, part):
        self._parts.append(part)
        self._size += len(part)

    def align(self, alignment):
        self.append(bytes(_aligned(self._size, alignment) - self._size))

    def uint8(self, value):
        self.append(struct.pack('<B', value))

    def uint32(self, value):
        self.align(4)
        self.append(struct.pack('<I', value))

    def string(self, text):
        if '\x00' in text:
            raise ValueError('%r: a CDR string cannot hold a NUL character' % text)
        encoded = text.encode('utf-8')
        self.uint32(len(encoded) + 1)
        self.append(encoded + b'\x00')

    def header(self, sec, nanosec, frame_id):
        """Write std_msgs/Header, checking ranges so that struct never raises its own error."""
        for name, value, (low, high) in (('sec', sec, INT32_RANGE),
                                         ('nanosec', nanosec, UINT32_RANGE)):
            if not low <= operator.index(value) <= high:
                raise ValueError('stamp %s must be an integer in [%d, %d], got %r'
                                 % (name, low, high, value))
        self.align(4)
        self.append(struct.pack('<iI', sec, nanosec))
        self.string(frame_id)

    def body(self):
        return b''.join(self._parts)

    def tobytes(self):
        """Join the encapsulation header (CDR_LE, no options) and the body."""
        return b''.join([CDR_LE, b'\x00\x00'] + self._parts)
