"""Reliability: bad input, overload and faults never lose the node.

Every input reaches the node through real publish/subscribe; the node's answers and its
/diagnostics are the only things the tests read. Correct answers come from hand-computed
contacts (the room of ros_helpers) or from a brute-force World.
"""
import os
import random

from collision_node.broadphase import NAMES
from collision_node.cdr import serialize_pose_array
import numpy as np
import pytest
from rclpy.parameter import Parameter
from ros_helpers import (check_room_contacts, count_inputs, EXPECTED, Harness, make_context,
                         room_overrides, room_poses, values)

DOMAIN_ID = random.Random(os.getpid() + 2).randint(1, 200)
# Fuzzed buffers go out in bursts this long; the node's input queue is made as deep (its
# qos_overrides parameter), so every buffer reaches the parser instead of being overwritten.
FUZZ_BURST = 200
FUZZ_SENTINEL_SEC = 2_000_000_000  # stamps of the valid message closing each burst
# Largest finite float64 is 1.8e308: poses this far out overflow differences and squares.
EXTREME = 1.7e308


@pytest.fixture(scope='module')
def context():
    context = make_context(DOMAIN_ID)
    yield context
    context.try_shutdown()


@pytest.fixture
def harness(context):
    made = []

    def make(input_depth=None, **overrides):
        made.append(Harness(context, input_depth, **room_overrides(**overrides)))
        return made[-1]
    yield make
    for harness in made:
        harness.close()


def valid_buffers(rng):
    """Serialize PoseArrays of 0 to 6 poses with frame ids that need every padding length."""
    buffers = []
    for frame_id in ('', 'w', 'wo', 'wor', 'world', 'a_long_frame_name'):
        for count in (0, 1, 6):
            poses = room_poses(rng.uniform(-3.0, 3.0, (count, 3)))
            buffers.append(serialize_pose_array(int(rng.integers(2**31)),
                                                int(rng.integers(10**9)), frame_id, poses))
    return buffers


def fuzzed(rng, valid):
    """Return a random, truncated or mutated buffer (bytes) built from the valid ones."""
    base = bytearray(valid[rng.integers(len(valid))])
    kind = rng.integers(6)
    if kind == 0:  # random bytes, half of them behind a valid CDR header
        head = b'\x00\x01\x00\x00' if rng.random() < 0.5 else b''
        return head + rng.bytes(int(rng.integers(0, 160)))
    if kind == 1:  # truncated
        return bytes(base[:rng.integers(len(base))])
    if kind == 2:  # bits flipped
        for _ in range(rng.integers(1, 5)):
            base[rng.integers(len(base))] ^= 1 << int(rng.integers(8))
        return bytes(base)
    if kind == 3:  # bytes overwritten
        for _ in range(rng.integers(1, 5)):
            base[rng.integers(len(base))] = rng.integers(256)
        return bytes(base)
    if kind == 4:  # a chunk cut out or put in
        at = rng.integers(len(base) + 1)
        if rng.random() < 0.5:
            del base[at:at + rng.integers(1, 16)]
        else:
            base[at:at] = rng.bytes(int(rng.integers(1, 16)))
        return bytes(base)
    return bytes(base) + rng.bytes(int(rng.integers(1, 64)))  # trailing bytes


@pytest.mark.parametrize('count', [
    10_000, pytest.param(100_000, marks=pytest.mark.slow)])
def test_fuzzed_buffers_are_rejected_and_counted(harness, count):
    room = harness(input_depth=FUZZ_BURST)
    rng = np.random.default_rng(count)
    valid = valid_buffers(rng)
    good = room_poses()
    published, bursts = 0, 0
    while published < count:
        for _ in range(min(FUZZ_BURST - 1, count - published)):
            room.poses.publish(fuzzed(rng, valid))
            published += 1
        # The burst ends with a valid message: it is answered, and correctly.
        sentinel = FUZZ_SENTINEL_SEC + bursts
        room.poses.publish(serialize_pose_array(sentinel, 999_999_999, 'world', good))
        room.wait_for(lambda: any(c.header.stamp.sec == sentinel
                                  and c.header.stamp.nanosec == 999_999_999
                                  for c in room.clouds), 'the answer to burst %d' % bursts)
        check_room_contacts(next(c for c in room.clouds if c.header.stamp.sec == sentinel),
                            EXPECTED, good)
        room.clouds.clear()
        bursts += 1
    statuses = list(room.statuses)
    ticks, dropped, rejected = count_inputs(room, published + bursts)
    print('%d fuzzed buffers: %d rejected, %d answered, %d dropped'
          % (published, rejected, ticks - bursts, dropped))
    assert dropped == 0  # the deep queue lets every buffer reach the parser
    assert rejected > published // 2  # mostly garbage, yet not all: some mutations stay valid
    warnings = [s for s in statuses if 'inputs rejected, last: ' in s.message]
    assert warnings and all(s.level == b'\x01' for s in warnings)
    assert all(values(s)['last_rejection'] for s in warnings)


def test_extreme_finite_coordinates_never_stop_the_node(harness):
    """Poses near the float64 limit: answered correctly or rejected, in every broad phase."""
    room = harness()
    extreme = room_poses()
    extreme[3, :3] = EXTREME  # the free body and the one in the crate fly off to the limits
    extreme[4, :3] = -EXTREME
    good = room_poses()
    rejected = 0
    for sec, name in enumerate(NAMES):
        assert room.node.set_parameters([Parameter('broad_phase', value=name)])[0].successful
        room.statuses.clear()
        room.poses.publish(serialize_pose_array(2 * sec, 0, 'world', extreme))
        room.publish(good, sec=2 * sec + 1)
        room.wait_for(lambda: room.clouds and room.clouds[-1].header.stamp.sec == 2 * sec + 1,
                      'the answer after the extreme input')
        if len(room.clouds) == 2:  # answered: nothing far out touches anything
            check_room_contacts(room.clouds[0], EXPECTED[:3], extreme)
        else:
            status = room.status(lambda s: int(values(s)['rejected_inputs']) > rejected)
            rejected = int(values(status)['rejected_inputs'])
            assert 'the World cannot check' in values(status)['last_rejection']
        check_room_contacts(room.clouds[-1], EXPECTED, good)
        room.clouds.clear()
