"""The joint_states lane: a driver's next message to its contacts in one compiled call.

A robot's driver publishes the same names in the same frame at a steady rate. The full way
for a message is five stages of Python (cdr.parse_joint_state, JointValues.merge, q,
World.check_joints, the cloud), and from a cold cache, as each input at 200 Hz meets it, they
took about 0.19 ms of the node's 0.23 ms (Intel Xeon VM of the README). Once a message has
gone the full way, :class:`JointLane` answers the next ones of its layout in one kernel: it
checks that the bytes from the frame_id to the end of the names are the ones already read,
reads the positions, merges them into the joint values and runs the robot's pass
(robot_pass.check_robot_states, the pass check_joints runs). The cloud is written as for
check_joints.

The lane never refuses: a message it cannot answer exactly as the full way would (another
layout, big-endian CDR, lengths or values the full way refuses, a joint still without a
value, a state the pass refuses, a continuous World, a scene past one pass) goes the full
way, which answers it or says why. ``test/test_joint_lane.py`` holds the lane to the full
way message by message.
"""
import math

import numpy as np

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.contacts import STATE_CONTACT_DTYPE
from collision_node.pipeline.robot import Robot
from collision_node.pipeline.robot_pass import check_robot_states
from collision_node.pipeline.warm_up import WARM_UP_ROBOT
from collision_node.pipeline.world import World
from collision_node.ros.cdr import CDR_LE, ENCAPSULATION_SIZE, MAX_JOINT_STATE_TRAILING_BYTES

# Body offset of the frame_id's length: the layout the lane compares starts there.
FRAME_ID_AT = 8
LITTLE_ENDIAN = np.frombuffer(CDR_LE, np.uint8)[0], np.frombuffer(CDR_LE, np.uint8)[1]


class JointLane:
    """The layout of the last message that went the full way, and the next ones' answers."""

    def __init__(self):
        self._layout = None  # the body bytes from the frame_id's length to the names' end
        self._names = None   # those names, as the JointValues merged them
        self._name_count = 0

    def learn(self, buffer, message, joints):
        """Take the layout of ``buffer``, merged the full way into ``joints`` (JointValues).

        ``message``: its cdr.JointStateView. A big-endian message, or one whose names the
        values did not take (no positions), leaves the lane without a layout.
        """
        self._layout = None
        if bytes(buffer[:2]) != CDR_LE or joints.merged_names != message.names:
            return
        start = ENCAPSULATION_SIZE + FRAME_ID_AT
        self._layout = np.frombuffer(buffer, np.uint8, message.names_end - FRAME_ID_AT,
                                     start).copy()
        self._names, self._name_count = joints.merged_names, len(message.names)

    def answer(self, buffer, joints, rows):
        """Return (contacts, pairs passed, SAT tests, sec, nanosec), or None: the full way.

        ``joints``: the JointValues the layout was learned with; ``rows``: the World's
        robot_pass() (None: the full way).
        """
        if rows is None or joints is None or self._layout is None \
                or joints.merged_names is not self._names:
            return None
        answered, contacts, passed, sat_tests, sec, nanosec = _answer(
            np.frombuffer(buffer, np.uint8), self._layout, self._name_count,
            *joints.merge_arrays(), *rows.kernel_arguments())
        return (contacts, passed, sat_tests, sec, nanosec) if answered else None


def compile_lane():
    """Compile the lane's kernel, or load it from numba's cache (a node's start)."""
    world = World()
    robot = Robot.from_urdf(WARM_UP_ROBOT)
    world.set_robot(robot)
    no_joints = np.zeros(0, np.int64)
    _answer(np.frombuffer(bytes(16), np.uint8), np.zeros(1, np.uint8), 1, no_joints, no_joints,
            np.zeros(robot.dof), np.zeros(robot.dof, np.bool_),
            *world.robot_pass().kernel_arguments())


@kernel
def _answer(message, layout, name_count, entries, joints, values, known, model_ints,
            model_floats, base_pose, pairs, keys, settings, floats, ints):
    """Answer a message of ``layout`` (JointLane.answer), or return answered = False.

    Reads as cdr.parse_joint_state reads a little-endian message, merges as
    JointValues.merge, then runs the robot's pass on the joint values.
    """
    size = message.shape[0] - ENCAPSULATION_SIZE
    if size < FRAME_ID_AT + layout.shape[0] or message[0] != LITTLE_ENDIAN[0] \
            or message[1] != LITTLE_ENDIAN[1]:
        return _full_way()
    body = message[ENCAPSULATION_SIZE:]
    for i in range(layout.shape[0]):
        if body[FRAME_ID_AT + i] != layout[i]:
            return _full_way()
    count, start, end = _float64_sequence(body, FRAME_ID_AT + layout.shape[0])
    if count != name_count or count == 0 or end > size:
        return _full_way()
    for _ in range(2):  # velocity, effort: only their lengths
        end = _float64_sequence(body, end)[2]
        if end > size:
            return _full_way()
    if size - end > MAX_JOINT_STATE_TRAILING_BYTES:
        return _full_way()
    positions = body[start:start + 8 * count].copy().view(np.float64)  # aligned, native
    for value in positions:
        if not math.isfinite(value):
            return _full_way()
    for i in range(entries.shape[0]):
        values[joints[i]] = positions[entries[i]]
        known[joints[i]] = True
    for joint_known in known:
        if not joint_known:
            return _full_way()
    sec, nanosec = _uint32(body, 0), _uint32(body, 4)
    sec = sec - (1 << 32) if sec >= 1 << 31 else sec  # an int32
    contacts, (passed, sat_tests), state, _, _, invalid = check_robot_states(
        values.reshape((1, values.shape[0])), model_ints, model_floats, base_pose, pairs, keys,
        settings, floats, ints, 0, 1, np.empty((0, 0, 3, 3)), np.empty((0, 0, 3)))
    if state >= 0 or invalid:
        return _full_way()
    return True, contacts, passed, sat_tests, sec, nanosec


@kernel
def _full_way():
    return False, np.empty(0, STATE_CONTACT_DTYPE), 0, 0, 0, 0


@kernel
def _float64_sequence(body, at):
    """Return a float64 sequence's (count, first byte, end) at body offset ``at``, as CDR."""
    at = (at + 3) // 4 * 4
    if at + 4 > body.shape[0]:
        return 0, at, body.shape[0] + 1  # truncated: an end past the body
    count = _uint32(body, at)
    at += 4
    if count:
        at = (at + 7) // 8 * 8
    return count, at, at + 8 * count


@kernel
def _uint32(body, at):
    return (np.int64(body[at]) | np.int64(body[at + 1]) << 8 | np.int64(body[at + 2]) << 16
            | np.int64(body[at + 3]) << 24)
