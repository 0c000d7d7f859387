"""The `~/markers` MarkerArray (doc/design.md) written as CDR bytes with numpy, not one by one.

rclpy converts a Marker object to CDR at ~13 µs each (130 ms at 10,000 bodies). Here every
marker of one kind (static cube, dynamic cube, contact arrow) has the same bytes but for its
stamp, id, pose, scale and colour: rclpy serialises one template marker of each kind once, the
offsets of those fields are found in its bytes by unique sentinel values, and a message is the
template tiled N times with the fields written as numpy columns.

Why tiling is exact: all of a marker's variable-length members are strings fixed per kind
(frame_id, ns) or empty sequences, and its last float64 (scale.z) is followed by a fixed tail of
4-byte members. So every marker ends at the same offset modulo 8 and the next one starts at the
same alignment: one template, with its leading padding, fits every position after the first
marker, whatever the frame_id. The first marker is the DELETEALL, serialised by rclpy too.

    writer = MarkerWriter('world')
    publisher.publish(writer.serialize(sec, nanosec, static_poses, static_half_extents,
                                       static_ids, poses, half_extents, contacts))
"""
import struct

import numpy as np
from rclpy.serialization import serialize_message
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from collision_node.pipeline.contacts import DYNAMIC

STATIC_COLOR = (0.6, 0.6, 0.6, 0.5)      # r g b a
FREE_COLOR = (0.2, 0.8, 0.2, 0.6)
COLLIDING_COLOR = (0.9, 0.1, 0.1, 0.8)
NEAR_COLOR = (1.0, 0.5, 0.0, 0.8)        # within the margin, not touching
NORMAL_COLOR = (1.0, 0.9, 0.0, 1.0)
GAP_COLOR = (1.0, 0.5, 0.0, 1.0)         # a near pair's arrow: closest point to closest point
NORMAL_ARROW_MIN_LENGTH = 0.05  # m; an arrow is max(depth, this) long, so shallow ones show
NORMAL_ARROW_WIDTH = 0.01       # m, shaft diameter; the head is twice as wide
# An arrow's normal this close to -x has no unique half-way rotation from +x.
OPPOSITE_NORM = 1e-9
# Byte offsets in a MarkerArray: the marker count follows the 4-byte encapsulation header, the
# first marker's stamp (int32 sec, uint32 nanosec) the count.
COUNT_OFFSET = 4
HEAD_STAMP_OFFSET = 8

# Sentinels the template's fields are set to so their offsets can be found in its bytes: no
# other 4- or 8-byte run of a serialised marker equals any of them.
_SENTINEL_ID = 0x5EC0_1D01
_SENTINEL_SEC = 0x5EC0_1D02
_SENTINEL_NANOSEC = 0x5EC0_1D03
_SENTINEL_POSE = tuple(1.0e9 + 0.125 * k for k in range(1, 8))      # x y z qx qy qz qw
_SENTINEL_SCALE = tuple(2.0e9 + 0.125 * k for k in range(1, 4))
_SENTINEL_COLOR = tuple(3.0e6 + 0.25 * k for k in range(1, 5))      # float32, exact

# The fields written per marker, with the sentinel bytes that locate them.
_FIELDS = (
    ('sec', '<i4', np.array(_SENTINEL_SEC, '<i4')),
    ('nanosec', '<u4', np.array(_SENTINEL_NANOSEC, '<u4')),
    ('id', '<i4', np.array(_SENTINEL_ID, '<i4')),
    ('pose', ('<f8', 7), np.array(_SENTINEL_POSE, '<f8')),
    ('scale', ('<f8', 3), np.array(_SENTINEL_SCALE, '<f8')),
    ('color', ('<f4', 4), np.array(_SENTINEL_COLOR, '<f4')),
)


class MarkerKind:
    """The serialised template of one kind of marker and a structured dtype over its fields.

    ``dtype`` has the template's size, with its leading alignment padding, and the fields
    ``sec nanosec id pose scale color`` at their offsets in it, so an array of N of them is N
    markers in a row, ready to be written column by column.
    """

    def __init__(self, frame_id, namespace, marker_type):
        marker = Marker(header=Header(frame_id=frame_id), ns=namespace, type=marker_type,
                        action=Marker.ADD, id=_SENTINEL_ID)
        marker.header.stamp.sec, marker.header.stamp.nanosec = _SENTINEL_SEC, _SENTINEL_NANOSEC
        position, orientation = marker.pose.position, marker.pose.orientation
        (position.x, position.y, position.z,
         orientation.x, orientation.y, orientation.z, orientation.w) = _SENTINEL_POSE
        marker.scale.x, marker.scale.y, marker.scale.z = _SENTINEL_SCALE
        marker.color = ColorRGBA(r=_SENTINEL_COLOR[0], g=_SENTINEL_COLOR[1],
                                 b=_SENTINEL_COLOR[2], a=_SENTINEL_COLOR[3])
        delete_all = _delete_all(frame_id)
        first, one, two = (serialize_message(MarkerArray(markers=[delete_all] + [marker] * k))
                           for k in range(3))
        if len(two) - len(one) != len(one) - len(first):
            raise RuntimeError('a %s marker takes different sizes at different positions; '
                               'it cannot be tiled' % namespace)
        template = bytearray(two[len(one):])  # the second copy, in the steady alignment
        padding = -len(one) % 4  # before the marker's first member, an int32
        template[:padding] = bytes(padding)  # padding bytes are not zeroed by rclpy
        names, formats, offsets = [], [], []
        for name, field_format, sentinel in _FIELDS:
            names.append(name)
            formats.append(field_format)
            offsets.append(_only_offset(template, sentinel.tobytes(), name))
        self.dtype = np.dtype({'names': names, 'formats': formats, 'offsets': offsets,
                               'itemsize': len(template)})
        self.template = np.frombuffer(bytes(template), np.uint8)

    def block(self, count):
        """``count`` copies of the template as an array of ``dtype``, fields still sentinels."""
        rows = np.empty((count, self.dtype.itemsize), np.uint8)
        rows[:] = self.template
        return rows.reshape(-1).view(self.dtype)


class MarkerWriter:
    """Writes the node's MarkerArray: DELETEALL, a cube per body, an arrow per contact.

    A colliding pair's arrow is its normal at the contact point, as long as the depth (at least
    NORMAL_ARROW_MIN_LENGTH); a near pair's goes from A's closest point to B's, exactly the gap.
    Dynamic cubes are red when they collide, orange when they are only near something.
    """

    def __init__(self, frame_id):
        self._head = np.frombuffer(
            serialize_message(MarkerArray(markers=[_delete_all(frame_id)])), np.uint8)
        self.static = MarkerKind(frame_id, 'static', Marker.CUBE)
        self.dynamic = MarkerKind(frame_id, 'dynamic', Marker.CUBE)
        self.normals = MarkerKind(frame_id, 'normals', Marker.ARROW)
        self._frame_id = frame_id
        self._body_groups = None  # [(MarkerKind, body indices)] of named bodies, or None

    def name_bodies(self, names):
        """Put dynamic body i's cube in namespace ``dynamic/<names[i]>`` (None: ``dynamic``).

        A robot's boxes are named by their links, so RViz lists (and hides) each link's
        boxes by name. A kind per name is made here, once per set of names.
        """
        if names is None:
            self._body_groups = None
            return
        names = np.asarray(names, dtype=object)
        self._body_groups = [
            (MarkerKind(self._frame_id, 'dynamic/' + name, Marker.CUBE),
             np.flatnonzero(names == name)) for name in dict.fromkeys(names)]

    def serialize(self, sec, nanosec, static_poses, static_half_extents, static_ids,
                  poses, half_extents, contacts):
        """CDR bytes of the MarkerArray for one tick.

        Static cubes have the ids ``static_ids`` (collider list indices); dynamic cubes the
        index of their pose; arrows the index of their contact. ``half_extents`` is (3,) or
        (D, 3); ``contacts`` a CONTACT_DTYPE or CLOUD_DTYPE array.
        """
        distance = contacts['distance'].astype(np.float64)
        near = distance > 0.0
        colliding, near_only = (np.zeros(len(poses), bool) for _ in range(2))
        for marked, rows in ((colliding, ~near), (near_only, near)):
            marked[contacts['id_a'][rows]] = True
            marked[contacts['id_b'][rows & (contacts['type_b'] == DYNAMIC)]] = True
        normals = np.stack([contacts['normal_x'], contacts['normal_y'], contacts['normal_z']],
                           axis=1).astype(np.float64)
        arrows = np.empty((len(contacts), 7))
        arrows[:, 0], arrows[:, 1], arrows[:, 2] = contacts['x'], contacts['y'], contacts['z']
        # A near pair's point is the middle of the gap: its arrow starts at A's closest point.
        arrows[near, :3] -= normals[near] * (0.5 * distance[near, None])
        arrows[:, 3:] = quaternions_turning_x_to(normals)
        arrow_scales = np.empty((len(contacts), 3))
        arrow_scales[:, 0] = np.where(near, distance,
                                      np.maximum(contacts['depth'], NORMAL_ARROW_MIN_LENGTH))
        arrow_scales[:, 1:] = (NORMAL_ARROW_WIDTH, 2.0 * NORMAL_ARROW_WIDTH)
        body_colors = np.where(colliding[:, None], COLLIDING_COLOR,
                               np.where(near_only[:, None], NEAR_COLOR, FREE_COLOR))

        head = self._head.copy()
        # int32 sec, uint32 nanosec: a stamp before 1970 (negative sec) is a valid stamp.
        head[HEAD_STAMP_OFFSET:HEAD_STAMP_OFFSET + 8] = np.frombuffer(
            struct.pack('<iI', sec, nanosec), np.uint8)
        parts = [head]
        groups = self._body_groups
        if groups is None or sum(len(bodies) for _, bodies in groups) != len(poses):
            bodies = [(self.dynamic, np.arange(len(poses)), poses, 2.0 * half_extents,
                       body_colors)]
        else:  # named bodies: a block per name
            sizes = np.broadcast_to(2.0 * np.asarray(half_extents), (len(poses), 3))
            bodies = [(kind, rows, poses[rows], sizes[rows], body_colors[rows])
                      for kind, rows in groups]
        for kind, ids, group_poses, scales, colors in (
                [(self.static, static_ids, static_poses, 2.0 * static_half_extents,
                  STATIC_COLOR)]
                + bodies
                + [(self.normals, np.arange(len(contacts)), arrows, arrow_scales,
                    np.where(near[:, None], GAP_COLOR, NORMAL_COLOR))]):
            block = kind.block(len(ids))
            block['sec'], block['nanosec'], block['id'] = sec, nanosec, ids
            block['pose'], block['scale'], block['color'] = group_poses, scales, colors
            parts.append(block.view(np.uint8))
        count = 1 + len(static_ids) + len(poses) + len(contacts)
        message = np.concatenate(parts)
        message[COUNT_OFFSET:COUNT_OFFSET + 4] = np.array([count], '<u4').view(np.uint8)
        return message.tobytes()


def _delete_all(frame_id):
    return Marker(header=Header(frame_id=frame_id), action=Marker.DELETEALL)


def _only_offset(data, pattern, name):
    at = data.find(pattern)
    if at < 0 or data.find(pattern, at + 1) >= 0:
        raise RuntimeError('cannot locate the marker field %r in its serialised template' % name)
    return at


def quaternions_turning_x_to(directions):
    """Return the shortest rotations (N, 4) x y z w from +x to the unit ``directions``.

    An ARROW marker points along its pose's x axis.
    """
    # Half-way formula: q = (x × d, 1 + x·d), normalised; it vanishes for d = -x, where any
    # half-turn about an axis normal to x does (z here).
    turns = np.zeros((len(directions), 4))
    turns[:, 1] = -directions[:, 2]
    turns[:, 2] = directions[:, 1]
    turns[:, 3] = 1.0 + directions[:, 0]
    norms = np.linalg.norm(turns, axis=1)
    opposite = norms < OPPOSITE_NORM
    turns[opposite] = (0.0, 0.0, 1.0, 0.0)
    norms[opposite] = 1.0
    return turns / norms[:, None]
