"""The `collisions` and `state_collisions` clouds (doc/design.md): contacts to and from clouds.

One point per reported pair, height 1, little-endian, dense, point_step 48: FLOAT32
``x y z normal_x normal_y normal_z depth``, UINT32 ``id_a type_a id_b type_b``, then FLOAT32
``distance`` and ``toi``, packed in that order (fields added later come last, so a reader that
finds fields by name or offset keeps working). A `state_collisions` cloud (World.check_states'
answer) has the same points with one more field last, UINT32 ``state``. The points are written
by one compiled loop and read as one numpy block, never by a Python loop over points.

    contacts = cloud_to_contacts(msg)   # structured array, fields as in the cloud
"""
import array

import numpy as np
from sensor_msgs.msg import PointCloud2, PointField

from collision_node.pipeline._jit import inlined_kernel, kernel
from collision_node.pipeline.contacts import CONTACT_DTYPE, STATE_CONTACT_DTYPE
from collision_node.pipeline.flat_views import copy_into
from collision_node.ros.cdr import (ENCAPSULATION_SIZE, INT32_RANGE, point_cloud_parts,
                                    POINT_FIELD_DATATYPES, UINT32_RANGE)


def _cloud_dtype(contact_dtype, names=None):
    """Return the points of contacts of ``contact_dtype``: the contacts' fields, then state.

    ``names``: the fields the points keep, of those (default: all of them).
    """
    names = names or list(CONTACT_DTYPE.names) + [
        name for name in contact_dtype.names if name not in CONTACT_DTYPE.names]
    # Floats narrow to float32 as doc/design.md fixes (a step of 0.06 mm at 1 km from the
    # origin), ids stay uint32.
    return np.dtype([(name, '<f4' if contact_dtype[name].kind == 'f' else '<u4')
                     for name in names])


def _fields(cloud_dtype):
    """Return (name, offset, datatype, count) of each PointField of ``cloud_dtype`` points."""
    return tuple((name, cloud_dtype.fields[name][1], POINT_FIELD_DATATYPES[cloud_dtype[name]], 1)
                 for name in cloud_dtype.names)


# A cloud's CDR bytes: the stamp right after the 4-byte encapsulation header; after the data,
# one byte, is_dense (true).
STAMP_OFFSET = ENCAPSULATION_SIZE
_TAIL = np.ones(1, np.uint8)
CLOUD_DTYPE = _cloud_dtype(CONTACT_DTYPE)
CLOUD_FIELDS = _fields(CLOUD_DTYPE)
STATE_CLOUD_DTYPE = _cloud_dtype(STATE_CONTACT_DTYPE)
STATE_CLOUD_FIELDS = _fields(STATE_CLOUD_DTYPE)
_CLOUDS = {CLOUD_FIELDS: CLOUD_DTYPE, STATE_CLOUD_FIELDS: STATE_CLOUD_DTYPE}


def contacts_to_points(contacts):
    """Cast contacts (the World's, or a cloud's) to a new array of their cloud's points."""
    contacts, cloud_dtype = _checked_contacts(contacts)
    points = np.empty(len(contacts), cloud_dtype)
    for name in cloud_dtype.names:
        points[name] = contacts[name]
    return points


def contacts_to_cloud(contacts, header):
    """Build the `collisions` (or `state_collisions`) PointCloud2: width 0 when nothing collides.

    ``header`` (std_msgs/Header) is used as is. Raises ValueError for other arrays.
    """
    points = contacts_to_points(contacts)
    cloud = PointCloud2(
        header=header, height=1, width=len(points),
        fields=[PointField(name=name, offset=offset, datatype=datatype, count=count)
                for name, offset, datatype, count in _fields(points.dtype)],
        is_bigendian=False, point_step=points.dtype.itemsize,
        row_step=points.dtype.itemsize * len(points), is_dense=True)
    # Copied as one block: the constructor would copy ``data`` twice, and the setter tests
    # each byte of anything but an array.array when ROS_PYTHON_CHECK_FIELDS=1.
    data = array.array('B')
    data.frombytes(points.view(np.uint8))
    cloud.data = data
    return cloud


def serialize_collisions(contacts, sec, nanosec, frame_id):
    """CDR bytes of :func:`contacts_to_cloud`'s message, for ``publisher.publish(bytes)``."""
    return CloudWriter().serialize(contacts, sec, nanosec, frame_id)


def compile_writer():
    """Compile the clouds' kernel, or load it from numba's cache.

    Its two variants: the bytes of read-only contacts (a World's answers) and of writable ones.
    """
    contacts = np.zeros(1, CONTACT_DTYPE)
    CloudWriter().serialize(contacts, 0, 0, '')
    contacts.flags.writeable = False
    CloudWriter().serialize(contacts, 0, 0, '')


class CloudWriter:
    """Writes clouds of contacts of one dtype as CDR bytes, into one buffer kept call to call.

    Contacts of ``contact_dtype`` (CONTACT_DTYPE: the World's steps; STATE_CONTACT_DTYPE: its
    check_states) are narrowed to the cloud's points by one kernel, straight into the buffer:
    0.05 ms for 10,000 contacts where numpy's field-by-field cast and a join took 0.33 ms. The
    same kernel patches the head (stamp, width, lengths): a small cloud took 7.8 µs with them
    patched from Python and the contacts viewed as words by numpy, 4.7 µs so (warm, Intel
    Xeon). A kept buffer also spares the page faults of a fresh one.
    """

    def __init__(self, contact_dtype=CONTACT_DTYPE, fields=None):
        """Write contacts of ``contact_dtype``, their ``fields`` (default: all) per point."""
        self._buffer = np.zeros(0, np.uint8)
        self._head = None  # (frame_id, the CDR bytes before the points, for width 0)
        self._contact_dtype = contact_dtype
        self._cloud_dtype = _cloud_dtype(contact_dtype, fields)
        # The kernel reads a contact row as 32-bit words: a float64 field starts at word
        # offset // 4 (as half of a float64 word offset // 8), a uint32 field at offset // 4.
        # Each cloud field is 4 bytes at word offset // 4 of its point.
        assert contact_dtype.itemsize % 8 == 0 and all(
            contact_dtype.fields[name][1] % contact_dtype[name].itemsize == 0
            for name in contact_dtype.names)  # every float64 field is 8-aligned in the row
        names = self._cloud_dtype.names
        self._is_float = np.array([contact_dtype[name].kind == 'f' for name in names])
        self._contact_words = np.array([contact_dtype.fields[name][1] // 4 for name in names])
        self._point_words = np.array([self._cloud_dtype.fields[name][1] // 4
                                      for name in names])

    def serialize(self, contacts, sec, nanosec, frame_id):
        """Return :func:`serialize_collisions`'s bytes (this writer's cloud)."""
        # The World's own contacts skip the field-by-field check: their dtype is the one this
        # writer was made for (about 40 Python steps less on every input).
        if not (isinstance(contacts, np.ndarray) and contacts.ndim == 1
                and contacts.dtype == self._contact_dtype):
            contacts, cloud_dtype = _checked_contacts(contacts)
            if cloud_dtype != self._cloud_dtype:
                raise ValueError('contacts with fields %s, this writer writes %s'
                                 % (contacts.dtype.names, self._cloud_dtype.names))
            native = np.zeros(len(contacts), self._contact_dtype)
            for name in contacts.dtype.names:  # float32 to float64 and back: exact
                native[name] = contacts[name]
            contacts = native
        elif not contacts.flags.c_contiguous:
            contacts = np.ascontiguousarray(contacts)
        if not (INT32_RANGE[0] <= sec <= INT32_RANGE[1]
                and UINT32_RANGE[0] <= nanosec <= UINT32_RANGE[1]):
            point_cloud_parts(sec, nanosec, frame_id, self._cloud_dtype, 0)  # raises, says why
        writing = self.writing(frame_id, len(contacts))
        size = write_cloud(writing, sec, nanosec, np.frombuffer(contacts, np.uint8))
        return writing[0][:size].tobytes()

    def writing(self, frame_id, points):
        """Return the writing kernel's first argument, for clouds of up to ``points`` points.

        (buffer, head, width offset, contact row size, and the fields' is_float, contact
        words, point words, point size, tail): the buffer holds such a cloud in ``frame_id``.
        """
        head = self._head_bytes(frame_id)
        point_size = self._cloud_dtype.itemsize
        size = len(head) + point_size * points + len(_TAIL)
        if len(self._buffer) < size:
            self._buffer = np.zeros(size, np.uint8)
        return (self._buffer, head, self._width_offset, self._contact_dtype.itemsize,
                self._is_float, self._contact_words, self._point_words, point_size, _TAIL)

    def _head_bytes(self, frame_id):
        """Return the head of a cloud of no points in ``frame_id`` (built once per frame)."""
        if self._head is None or self._head[0] != frame_id:
            head, tail = point_cloud_parts(0, 0, frame_id, self._cloud_dtype, 0)
            assert tail == bytes(_TAIL)
            # The width follows the stamp, the frame_id (a CDR string, then 4-aligned) and
            # the height.
            frame_end = STAMP_OFFSET + 8 + 4 + len(frame_id.encode('utf-8')) + 1
            self._width_offset = 4 + -(-(frame_end - 4) // 4) * 4 + 4
            self._head = (frame_id, np.frombuffer(head, np.uint8))
        return self._head[1]


@kernel
def write_cloud(writing, sec, nanosec, rows):
    """Write a cloud of the contacts' bytes ``rows`` into ``writing``'s buffer; return its size.

    ``writing``: CloudWriter.writing's tuple. Its head is the CDR before the points of a cloud
    of none, in which the stamp, the width, row_step and the data's length (its last two
    words) are patched. Contacts as float64 and uint32 words to points as float32 and uint32
    words: field f is word ``contact_word[f]`` of a row, word ``point_word[f]`` of a point.
    """
    buffer, head, width_at, row_size, is_float, contact_word, point_word, point_size, tail = \
        writing
    count = rows.shape[0] // row_size
    data = count * point_size
    at = head.shape[0]
    copy_into(buffer[:at], head)
    _put_uint32(buffer, STAMP_OFFSET, sec & 0xFFFFFFFF)  # an int32, two's complement
    _put_uint32(buffer, STAMP_OFFSET + 4, nanosec)
    _put_uint32(buffer, width_at, count)
    _put_uint32(buffer, at - 8, data)
    _put_uint32(buffer, at - 4, data)
    floats, words = rows.view(np.float64), rows.view(np.uint32)
    point = np.empty(point_size // 4, np.float32)
    point_words, point_bytes = point.view(np.uint32), point.view(np.uint8)
    for k in range(count):
        first = k * row_size // 4  # the row's first word
        for f in range(is_float.shape[0]):
            if is_float[f]:
                point[point_word[f]] = np.float32(floats[(first + contact_word[f]) // 2])
            else:
                point_words[point_word[f]] = words[first + contact_word[f]]
        copy_into(buffer[at:at + point_size], point_bytes)
        at += point_size
    copy_into(buffer[at:at + tail.shape[0]], tail)
    return at + tail.shape[0]


@inlined_kernel
def _put_uint32(buffer, at, value):
    for byte in range(4):
        buffer[at + byte] = (value >> (8 * byte)) & 0xFF


def cloud_to_contacts(msg):
    """Read a `collisions` (or `state_collisions`) PointCloud2 into a new structured array.

    Its dtype is the cloud's points (CLOUD_DTYPE, or STATE_CLOUD_DTYPE with ``state``). Raises
    ValueError saying how the cloud differs from those clouds.
    """
    if not isinstance(msg, PointCloud2):
        raise TypeError('expected a sensor_msgs/PointCloud2, got %s' % type(msg).__name__)
    fields = tuple((f.name, f.offset, f.datatype, f.count) for f in msg.fields)
    if fields not in _CLOUDS:
        raise ValueError('not a collisions cloud: fields (name, offset, datatype, count) are '
                         '%s, expected %s (or with state last)' % (fields, CLOUD_FIELDS))
    cloud_dtype = _CLOUDS[fields]
    if msg.is_bigendian:
        raise ValueError('not a collisions cloud: it is big-endian')
    if msg.point_step != cloud_dtype.itemsize:
        raise ValueError('not a collisions cloud: point_step %d, expected %d'
                         % (msg.point_step, cloud_dtype.itemsize))
    if msg.row_step != msg.width * msg.point_step:
        raise ValueError('inconsistent cloud: row_step %d is not width %d x point_step %d'
                         % (msg.row_step, msg.width, msg.point_step))
    if len(msg.data) != msg.height * msg.row_step:
        raise ValueError('inconsistent cloud: %d data bytes, height %d x row_step %d expected'
                         % (len(msg.data), msg.height, msg.row_step))
    return np.frombuffer(msg.data, cloud_dtype).copy()


def _checked_contacts(contacts):
    """Return the contacts as an array and the dtype of their cloud's points."""
    contacts = np.asarray(contacts)
    names = set(contacts.dtype.names or ())
    cloud_dtype = STATE_CLOUD_DTYPE if 'state' in names else CLOUD_DTYPE
    if contacts.ndim != 1 or names != set(cloud_dtype.names):
        raise ValueError('contacts must be a 1-D structured array with the fields %s (and '
                         'state), got dtype %s, shape %s' % (CLOUD_DTYPE.names, contacts.dtype,
                                                             contacts.shape))
    for name in cloud_dtype.names:
        # Unsigned ids only: a negative id would wrap to a large uint32 without a word.
        if contacts.dtype[name].kind != cloud_dtype[name].kind:
            raise ValueError('contacts field %r has type %s, expected a %s type'
                             % (name, contacts.dtype[name],
                                'float' if cloud_dtype[name].kind == 'f' else 'unsigned'))
    return contacts, cloud_dtype
