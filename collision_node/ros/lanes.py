"""Lanes: a publisher's next message of a known layout read (and answered) in one kernel.

A publisher sends the same header at a steady rate: a driver's joint_states name the same
joints in the same frame, a tracker's PoseArray holds as many poses in the same frame. The
full way for a message is stages of Python (cdr.py's parsers, the node's checks, then the
World), and from a cold cache, as each input at 200 Hz meets it, they were most of the node's
latency over an echo node (Intel Xeon VM of the README: 0.19 ms of 0.23 ms for joint_states).
Once a message has gone the full way, a lane learns its layout: the body's bytes from the
frame_id's length to the end of the names (joint_states) or of the pose count (PoseArray).
A next message whose bytes there are the same is read in one kernel:

* :class:`PoseLane` reads the poses, checks them with the World's one pass
  (small_scene.check_scene on World.pass_as_before's arguments: its validation and its reuse
  of an unchanged input's answer) and writes the cloud's bytes (messages.write_cloud), all in
  one kernel: the CDR in, the CDR out. Three kernel calls and their Python (the PoseArrayView,
  the step's checks of its input, the writer's) were the arm's cold cost over an echo node;
  a scene past the one pass reads its poses in the lane and steps the World on them;
* :class:`JointLane` reads the positions and merges them into the joint values, the robot's
  pass (robot_pass.check_robot_state, as World.check_joints runs it) checks them, and the
  cloud is written: one kernel too.

A lane never refuses: a message it cannot answer exactly as the full way would (another
layout, big-endian CDR, lengths or values the full way refuses, a joint still without a
value, a state the pass refuses, a continuous World, a scene past one pass) goes the full
way, which answers it or says why. ``test/test_lanes.py`` holds each lane to the full way
message by message.
"""
import math
from types import SimpleNamespace

import numpy as np

from collision_node.pipeline._jit import compiled_for, inlined_kernel, kernel
from collision_node.pipeline.contacts import CONTACT_DTYPE, STATE_CONTACT_DTYPE
from collision_node.pipeline.robot_pass import check_robot_state
from collision_node.pipeline.small_scene import check_scene
from collision_node.pipeline.world import World
from collision_node.ros.cdr import (CDR_LE, ENCAPSULATION_SIZE, MAX_JOINT_STATE_TRAILING_BYTES,
                                    MAX_TRAILING_BYTES, parse_pose_array, POSE_FIELDS,
                                    PoseArrayView, serialize_pose_array)
from collision_node.ros.messages import CloudWriter, compile_writer, write_cloud

# Body offset of the frame_id's length: the layout a lane compares starts there.
FRAME_ID_AT = 8
LITTLE_ENDIAN = tuple(np.frombuffer(CDR_LE, np.uint8).tolist())
NO_LAYOUT = np.zeros(0, np.uint8)
NO_MESSAGE = np.frombuffer(bytes(16), np.uint8)  # read-only, as a message's bytes are
NO_CONTACTS = np.zeros(0, CONTACT_DTYPE)
NO_CONTACTS.flags.writeable = False  # as a World's answers are


class _Layout:
    """The layout bytes of the last message that went the full way, for one owner."""

    def __init__(self):
        self.bytes = None  # the body bytes from the frame_id's length to the layout's end
        self.owner = None  # what the messages were checked against (config, joint values)

    def learn(self, buffer, end, owner):
        """Take body bytes [FRAME_ID_AT, end) of ``buffer`` (little-endian CDR) as the layout."""
        if bytes(buffer[:2]) != CDR_LE:
            self.bytes = self.owner = None
            return
        self.bytes = np.frombuffer(buffer, np.uint8, end - FRAME_ID_AT,
                                   ENCAPSULATION_SIZE + FRAME_ID_AT).copy()
        self.owner = owner


class PoseLane:
    """Reads, checks and answers the PoseArrays of a known layout (module docstring)."""

    def __init__(self):
        self._layout = _Layout()
        self._message = None  # the last message read the full way
        self._scene = None  # the World's pass_as_before arguments the lane last checked with
        self._extents = None  # their half extents, as check_scene takes them
        self._writing = None  # the cloud writer's kernel argument, for that scene
        self._kernel = None  # _answer_poses compiled for that scene's arguments (_jit)
        self._outcome = None  # the last answer's check (result() makes its Result)

    def learn(self, buffer, message, config):
        """Take the layout of ``buffer``, read the full way (``message``) and let by ``config``.

        ``config``: the node's configuration, whose rules the message passed (its frame, its
        pose count); a lane answers only under the same one.
        """
        self._layout.learn(buffer, message.count_end, config)
        self._message = message
        self._scene = None

    def read(self, buffer, config):
        """Return ``buffer``'s cdr.PoseArrayView, or None: the full way."""
        layout = self._layout
        if layout.owner is not config:  # its rules may differ (max_bodies, sizes)
            return None
        learned = self._message
        read, poses, sec, nanosec = _read_poses(np.frombuffer(buffer, np.uint8), layout.bytes,
                                                len(learned.poses))
        return PoseArrayView(sec, nanosec, learned.frame_id, poses, learned.count_end) \
            if read else None

    def answer(self, buffer, config, world, writer):
        """Check ``buffer`` as ``world.step`` would and write its cloud, in one kernel.

        Returns (the cloud's CDR bytes as ``writer`` writes them in the configuration's frame,
        poses, sec, nanosec), or None: the full way (another layout or configuration, a step
        the World would not check in one pass as before, an invalid pose). The step's Result
        is :meth:`result`'s, which the caller asks for once the cloud is out, before it lets
        go of the World.
        """
        layout = self._layout
        if layout.owner is not config:
            return None
        learned = self._message
        count = len(learned.poses)
        scene = world.pass_as_before(count, config.dynamic_half_extents)
        if scene is None:
            return None
        if scene is not self._scene:  # a new gathering: a new bound on the contacts
            extents = config.dynamic_half_extents
            self._extents = extents.reshape(1, 3) if extents.ndim == 1 else extents
            self._writing = writer.writing(config.frame_id,
                                           count * (count - 1) // 2 + count * scene.n_static)
            self._scene, self._kernel = scene, None
        # Of the same types at each call: the message's bytes, the gathering's arrays, the
        # last contacts (NO_CONTACTS, or a step's: both read-only CONTACT_DTYPE rows).
        arguments = (np.frombuffer(buffer, np.uint8), layout.bytes, count, self._extents,
                     *scene.arguments,
                     NO_CONTACTS if scene.result is None else scene.result.contacts,
                     self._writing)
        if self._kernel is None:
            self._kernel = compiled_for(_answer_poses, arguments)
        answered, contacts, counters, same, poses, size, sec, nanosec = self._kernel(*arguments)
        if not answered:
            return None
        self._outcome = scene, contacts, counters, same
        return self._writing[0][:size].tobytes(), poses, sec, nanosec

    def result(self, start, end):
        """Return the Result of the last answer, and let the World keep it (World.step's).

        ``start``, ``end``: perf_counter when the input came and when the check was done.
        """
        scene, contacts, counters, same = self._outcome
        self._outcome = None
        return scene.answer(contacts, counters, same, start, end)


class JointLane:
    """Answers the joint_states of a known layout (module docstring)."""

    def __init__(self):
        self._layout = _Layout()
        self._name_count = 0
        self._rows = self._writer = None  # the pass and writer the lane last answered with
        self._writing = None  # that writer's kernel argument, for that pass
        self._kernel = None  # _answer_joints compiled for their arguments (_jit)

    def learn(self, buffer, message, joints):
        """Take the layout of ``buffer``, merged the full way into ``joints`` (JointValues).

        ``message``: its cdr.JointStateView. One whose names the values did not take (no
        positions) leaves the lane without a layout.
        """
        if joints.merged_names != message.names:
            self._layout = _Layout()
            return
        # The values' own names object: answer() asks whether they merged another since.
        self._layout.learn(buffer, message.names_end, joints.merged_names)
        self._name_count = len(message.names)

    def answer(self, buffer, joints, rows, writer, frame_id):
        """Merge, check and write the cloud of ``buffer``, in one kernel.

        Returns (contacts, pairs passed, SAT tests, sec, nanosec, the cloud's CDR bytes as
        ``writer`` writes them in ``frame_id``), or None: the full way. ``joints``: the
        JointValues the layout was learned with; ``rows``: the World's robot_pass() (None:
        the full way).
        """
        layout = self._layout
        if rows is None or joints is None or layout.owner is None \
                or joints.merged_names is not layout.owner:
            return None
        if rows is not self._rows or writer is not self._writer:  # a bound for that pass
            self._writing = writer.writing(frame_id, rows.all_pairs)
            self._rows, self._writer, self._kernel = rows, writer, None
        arguments = (np.frombuffer(buffer, np.uint8), layout.bytes, self._name_count,
                     *joints.merge_arrays(), *rows.state_workspace, self._writing)
        if self._kernel is None:
            self._kernel = compiled_for(_answer_joints, arguments)
        answered, contacts, passed, sat_tests, size, sec, nanosec = self._kernel(*arguments)
        if not answered:
            return None
        return contacts, passed, sat_tests, sec, nanosec, self._writing[0][:size].tobytes()


def compile_ros_kernels(margins=(False, True), robot=True):
    """Compile the ROS layer's own kernels (the lanes' and the clouds' writer), or load them.

    ``margins``: the one pass's variants (without margins, with) the PoseArray lane is
    compiled for; ``robot``: the joint_states lane too. By default all of them:
    collision_node.tools.compile_kernels compiles them into numba's cache beforehand, and the
    node's background warm-up readies them; one list, so that neither can miss a kernel. The
    node's configure compiles only the variant its scene starts with, and the joint_states
    lane if it starts with a robot, before it subscribes.
    """
    compile_writer()
    _read_poses(NO_MESSAGE, NO_LAYOUT, 1)
    for with_margins in margins:  # small_scene's two variants
        _answer_one_pose(0.01 if with_margins else 0.0)
    if not robot:
        return
    # Not of the layout: not merged, so the robot's pass (which no workspace here could feed)
    # is compiled, never run.
    no_joints = np.zeros(0, np.int64)
    _answer_joints(NO_MESSAGE, NO_LAYOUT, 1, no_joints, no_joints, np.zeros(1),
                   np.zeros(1, np.bool_), np.zeros(1), np.zeros(1, np.int64),
                   CloudWriter(STATE_CONTACT_DTYPE, CONTACT_DTYPE.names).writing('', 0))


def _answer_one_pose(margin):
    """Answer a PoseArray of one body in a lane, in a World of ``margin``: compiles its kernel."""
    world = World(margin=margin)
    config = SimpleNamespace(dynamic_half_extents=np.full((1, 3), 0.1), frame_id='')  # in short
    buffer = serialize_pose_array(0, 0, '', np.array([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]]))
    message = parse_pose_array(buffer)
    world.step(message.poses, config.dynamic_half_extents)
    lane = PoseLane()
    lane.learn(buffer, message, config)
    assert lane.answer(buffer, config, world, CloudWriter()) is not None
    lane.result(0.0, 0.0)


@kernel
def _read_poses(message, layout, count):
    """Return (read, poses (count, 7), sec, nanosec) of a message of ``layout``.

    Reads as cdr.parse_pose_array reads a little-endian message; ``read`` False: the full way.
    """
    at = _after_layout(message, layout)
    if at < 0:
        return False, np.empty((0, POSE_FIELDS)), 0, 0
    body = message[ENCAPSULATION_SIZE:]
    if count:
        at = (at + 7) // 8 * 8
    end = at + 8 * POSE_FIELDS * count
    if end > body.shape[0] or body.shape[0] - end > MAX_TRAILING_BYTES:
        return False, np.empty((0, POSE_FIELDS)), 0, 0
    sec, nanosec = _stamp(body)
    return True, _float64s(body, at, POSE_FIELDS * count).reshape((count, POSE_FIELDS)), sec, \
        nanosec


@kernel
def _answer_poses(message, layout, count, half_extents, last, statics, rows, options, previous,
                  writing):
    """Read a message of ``layout``, check it and write its cloud: PoseLane.answer's kernel.

    As _read_poses, then small_scene.check_scene (its arguments after the poses'), then
    messages.write_cloud (``previous``: the contacts of the last input, for the same input
    again). Returns (answered, contacts, counters, same, poses, cloud size, sec, nanosec);
    answered False: the full way (not of the layout, or a pose the World refuses).
    """
    read, poses, sec, nanosec = _read_poses(message, layout, count)
    if not read:
        return False, np.empty(0, CONTACT_DTYPE), (0, 0, 0, 0), False, poses, 0, sec, nanosec
    contacts, counters, bad, _, invalid, same = check_scene(poses, half_extents, last,
                                                            statics, rows, options)
    if same:
        return True, contacts, counters, True, poses, \
            write_cloud(writing, sec, nanosec, previous.view(np.uint8)), sec, nanosec
    if bad >= 0 or invalid:
        return False, contacts, counters, False, poses, 0, sec, nanosec
    return True, contacts, counters, False, poses, \
        write_cloud(writing, sec, nanosec, contacts.view(np.uint8)), sec, nanosec


@kernel
def _answer_joints(message, layout, name_count, entries, joints, values, known, floats, ints,
                   writing):
    """Merge a message of ``layout``, check the state and write its cloud: JointLane.answer's.

    As _merge_joints, then robot_pass.check_robot_state on the values (``floats``, ``ints``:
    its workspace), then messages.write_cloud. Returns (answered, contacts, pairs passed, SAT
    tests, cloud size, sec, nanosec); answered False: the full way (not merged, or a state
    the pass refuses).
    """
    merged, sec, nanosec = _merge_joints(message, layout, name_count, entries, joints, values,
                                         known)
    if not merged:
        return False, np.empty(0, STATE_CONTACT_DTYPE), 0, 0, 0, sec, nanosec
    contacts, (passed, sat_tests), state, _, _, invalid = check_robot_state(values, floats,
                                                                            ints)
    if state >= 0 or invalid:
        return False, contacts, passed, sat_tests, 0, sec, nanosec
    return True, contacts, passed, sat_tests, \
        write_cloud(writing, sec, nanosec, contacts.view(np.uint8)), sec, nanosec


@kernel
def _merge_joints(message, layout, name_count, entries, joints, values, known):
    """Merge a message of ``layout`` into the joint values; return (merged, sec, nanosec).

    Reads as cdr.parse_joint_state reads a little-endian message and merges as
    JointValues.merge; merged False: the full way (the values then changed only if every
    check passed and a joint is still without a value, as the full way changes them).
    """
    at = _after_layout(message, layout)
    if at < 0:
        return False, 0, 0
    body = message[ENCAPSULATION_SIZE:]
    size = body.shape[0]
    count, start, end = _float64_sequence(body, at)
    if count != name_count or count == 0 or end > size:
        return False, 0, 0
    for _ in range(2):  # velocity, effort: only their lengths
        end = _float64_sequence(body, end)[2]
        if end > size:
            return False, 0, 0
    if size - end > MAX_JOINT_STATE_TRAILING_BYTES:
        return False, 0, 0
    positions = _float64s(body, start, count)
    for value in positions:
        if not math.isfinite(value):
            return False, 0, 0
    for i in range(entries.shape[0]):
        values[joints[i]] = positions[entries[i]]
        known[joints[i]] = True
    for joint_known in known:
        if not joint_known:
            return False, 0, 0
    sec, nanosec = _stamp(body)
    return True, sec, nanosec


@inlined_kernel
def _after_layout(message, layout):
    """Return the body offset after ``layout`` in a little-endian message of it, else -1."""
    body_size = message.shape[0] - ENCAPSULATION_SIZE
    if body_size < FRAME_ID_AT + layout.shape[0] or message[0] != LITTLE_ENDIAN[0] \
            or message[1] != LITTLE_ENDIAN[1]:
        return -1
    start = ENCAPSULATION_SIZE + FRAME_ID_AT
    for i in range(layout.shape[0]):
        if message[start + i] != layout[i]:
            return -1
    return FRAME_ID_AT + layout.shape[0]


@inlined_kernel
def _stamp(body):
    """Return the header's (sec, nanosec): an int32 and a uint32."""
    sec = _uint32(body, 0)
    return (sec - (1 << 32) if sec >= 1 << 31 else sec), _uint32(body, 4)


@inlined_kernel
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


@inlined_kernel
def _float64s(body, start, count):
    """Return ``count`` float64 at body offset ``start``: an aligned, native copy."""
    return body[start:start + 8 * count].copy().view(np.float64)


@inlined_kernel
def _uint32(body, at):
    return (np.int64(body[at]) | np.int64(body[at + 1]) << 8 | np.int64(body[at + 2]) << 16
            | np.int64(body[at + 3]) << 24)
