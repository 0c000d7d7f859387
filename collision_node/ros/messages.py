"""The `collisions` and `state_collisions` clouds (doc/design.md): contacts to and from clouds.

One point per reported pair, height 1, little-endian, dense, point_step 48: FLOAT32
``x y z normal_x normal_y normal_z depth``, UINT32 ``id_a type_a id_b type_b``, then FLOAT32
``distance`` and ``toi``, packed in that order (fields added later come last, so a reader that
finds fields by name or offset keeps working). A `state_collisions` cloud (World.check_states'
answer) has the same points with one more field last, UINT32 ``state``. The points are written
and read as one numpy block, never point by point.

    contacts = cloud_to_contacts(msg)   # structured array, fields as in the cloud
"""
import array
import struct

import numpy as np
from sensor_msgs.msg import PointCloud2, PointField

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.contacts import CONTACT_DTYPE, STATE_CONTACT_DTYPE
from collision_node.ros.cdr import ENCAPSULATION_SIZE, point_cloud_parts, POINT_FIELD_DATATYPES


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
_STAMP_OFFSET = ENCAPSULATION_SIZE
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
    """Compile the clouds' kernel, or load it from numba's cache."""
    contacts = np.zeros(1, CONTACT_DTYPE)
    contacts.flags.writeable = False  # as World.step returns them
    CloudWriter().serialize(contacts, 0, 0, '')


class CloudWriter:
    """Writes clouds of contacts of one dtype as CDR bytes, into one buffer kept call to call.

    Contacts of ``contact_dtype`` (CONTACT_DTYPE: the World's steps; STATE_CONTACT_DTYPE: its
    check_states) are narrowed to the cloud's points by one kernel, straight into the buffer:
    0.05 ms for 10,000 contacts where numpy's field-by-field cast and a join took 0.33 ms. A
    kept buffer also spares the page faults of a fresh one.
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
        native = isinstance(contacts, np.ndarray) and contacts.ndim == 1 \
            and contacts.dtype == self._contact_dtype
        if not native:
            contacts, cloud_dtype = _checked_contacts(contacts)
            if cloud_dtype != self._cloud_dtype:
                raise ValueError('contacts with fields %s, this writer writes %s'
                                 % (contacts.dtype.names, self._cloud_dtype.names))
        cloud_dtype = self._cloud_dtype
        count = len(contacts)
        head = self._head_bytes(frame_id)
        size = len(head) + cloud_dtype.itemsize * count + len(_TAIL)
        if len(self._buffer) < size:
            self._buffer = np.zeros(size, np.uint8)
        buffer = self._buffer[:size]
        buffer[:len(head)] = head
        # The head changes from cloud to cloud only in the stamp, the width, row_step and
        # the data's length (the last two words of the head): patched in place.
        try:
            struct.pack_into('<iI', buffer, _STAMP_OFFSET, sec, nanosec)
        except struct.error:
            point_cloud_parts(sec, nanosec, frame_id, cloud_dtype, 0)  # raises, saying why
            raise
        struct.pack_into('<I', buffer, self._width_offset, count)
        struct.pack_into('<II', buffer, len(head) - 8, cloud_dtype.itemsize * count,
                         cloud_dtype.itemsize * count)
        points = buffer[len(head):size - len(_TAIL)].view(cloud_dtype)
        if native and contacts.flags.c_contiguous:
            row_words = contacts.dtype.itemsize // 4
            point_words = cloud_dtype.itemsize // 4
            _narrow_contacts(contacts.view(np.float64).reshape(count, row_words // 2),
                             contacts.view(np.uint32).reshape(count, row_words),
                             points.view(np.float32).reshape(count, point_words),
                             points.view(np.uint32).reshape(count, point_words),
                             self._is_float, self._contact_words, self._point_words)
        else:
            points[:] = contacts_to_points(contacts)
        buffer[size - len(_TAIL):] = _TAIL
        return buffer.tobytes()

    def _head_bytes(self, frame_id):
        """Return the head of a cloud of no points in ``frame_id`` (built once per frame)."""
        if self._head is None or self._head[0] != frame_id:
            head, tail = point_cloud_parts(0, 0, frame_id, self._cloud_dtype, 0)
            assert tail == bytes(_TAIL)
            # The width follows the stamp, the frame_id (a CDR string, then 4-aligned) and
            # the height.
            frame_end = _STAMP_OFFSET + 8 + 4 + len(frame_id.encode('utf-8')) + 1
            self._width_offset = 4 + -(-(frame_end - 4) // 4) * 4 + 4
            self._head = (frame_id, np.frombuffer(head, np.uint8))
        return self._head[1]


@kernel
def _narrow_contacts(floats, words, point_floats, point_words, is_float, contact_word,
                     point_word):
    """Contacts (as float64 and uint32 words) to cloud points (as float32 and uint32 words)."""
    for i in range(floats.shape[0]):
        for f in range(len(is_float)):
            if is_float[f]:
                point_floats[i, point_word[f]] = np.float32(floats[i, contact_word[f] // 2])
            else:
                point_words[i, point_word[f]] = words[i, contact_word[f]]


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
