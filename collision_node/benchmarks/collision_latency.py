"""collision_latency: PoseArray published → collisions received through ROS, node apart.

    collision_latency --quick --json latency.json     # under 2 minutes
    collision_latency --json latency.json             # 100 ... 100,000 bodies at 10, 100, 1,000 Hz

Prints markdown tables; ``--json`` writes every number. Ten sections:

* latency: the node runs as its own process (``python -m collision_node.ros.node``, the console
  script's code, default parameters but the scene's sizes); this process publishes pre-serialised
  PoseArrays (only the stamp is patched in, before the send time is taken) and receives the
  ``collisions`` cloud as raw bytes. Latency = receipt − send on one monotonic clock. Stage
  times are the node's own /diagnostics (1-s periods; the table gives the median over periods
  of each period's median, the p99 and max over all). ``output`` there is the cloud (and
  markers) written as CDR bytes, ``publish`` handing them to rclpy; the node's overhead is
  parse + output + publish over the total. Inputs the node had no
  time for are dropped (depth-1 input queue), so at high rates not every input is answered.
* arm: the scene a robot runs, config/arm.yaml (7 links over 3 colliders) at 200 Hz: the node
  and an echo node (below) both up, answering in turns of a few seconds each, so that a slow
  moment of the machine hits both alike. The node's median latency minus the echo's is what
  the node adds at robot scale (target: at most ``ARM_TARGET_ADDED_MS``).
* joint_states: the same against the echo for a robot from its URDF (example-robot-data's
  Panda over three boxes): JointState messages in at 200 Hz, collisions out (target: at most
  ``JOINT_STATES_TARGET_ADDED_MS`` over the echo).
* floor: the same inputs answered by an echo node (:func:`run_echo`, its own process) that
  publishes the node's cloud for the scene at once: what ROS itself costs both ways (DDS,
  the two executors, taking and publishing the bytes). The node's latency minus this floor is
  what the node adds.
* tick: the node's input callback (``CollisionNode._check``) in this process, inputs back to
  back, for the arm and uniform scenes: µs per input and the node's stage medians, the work
  of a tick without DDS, the executor or cold caches.
* output: message object vs pre-serialised bytes for the cloud, written and published, here.
* skips: what a scene does not need, each against the case that needs it, through
  ``CollisionNode._check`` (the node's whole tick without the transport), in this process.
* sphere: the World's narrow phase with and without the bounding-sphere prefilter, here.
* gaps: the World's tick (the --statics scene, here) back to back and after idle time of each kind
  (sleeping, busy-waiting, the caches flushed), interleaved: why sparse input ticks slower.
* startup: node process start → first answer, with a fresh numba cache (cold) and again (warm),
  and warm with 100,000 dynamic sizes and 10,000 static colliders given as files.

Scene: ``scenes.uniform(N)`` (about one colliding pair per body); by default all N bodies come
in the PoseArray (the node's worst case: every pose parsed, stepped and drawn); ``--statics``
gives the scene's static half to the node as ``static_colliders`` instead (the scene of the
performance targets, doc/benchmarks.md).
"""
import argparse
import contextlib
import itertools
import json
import os
import platform
import shlex
import subprocess
import sys
import tempfile
import threading
import time
from typing import NamedTuple

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray
import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message
from rclpy.task import Future
from sensor_msgs.msg import JointState, PointCloud2

from collision_node.benchmarks.params_files import (scene_parameters, write_params_file,
                                                    write_scene_files)
from collision_node.benchmarks.robot import arm_states, arm_world
from collision_node.pipeline import scenes
from collision_node.pipeline.broadphase import NAMES
from collision_node.pipeline.scenes import uniform, UNIFORM_HALF_EXTENTS
from collision_node.pipeline.warm_up import BACKGROUND_READY
from collision_node.pipeline.world import Result, World
from collision_node.ros import diagnostics
from collision_node.ros.cdr import ENCAPSULATION_SIZE, serialize_pose_array
from collision_node.ros.lifetime import RosProgram
from collision_node.ros.memory import keep_heap_memory
from collision_node.ros.messages import CloudWriter, contacts_to_cloud
from collision_node.ros.node import (  # the node's own QoS
    CollisionNode, INPUT_QOS, JOINT_STATES_QOS, OUTPUT_QOS)
from collision_node.tools.demo import default_config
from collision_node.tools.processes import stop_process
from collision_node.tools.programs import child_command

STATUS_NAME = 'collision_node: collision_check'
# Fast DDS reads its XML profile (e.g. a larger shared-memory segment) from this variable; the
# node's process inherits it from this one.
FASTDDS_PROFILE_VARIABLE = 'FASTRTPS_DEFAULT_PROFILES_FILE'
DIAGNOSTIC_PERIOD_S = 1.0
FRAMES = 16            # distinct pre-serialised inputs cycled through (a repeat would be reused)
FRAME_DT_S = 1.0 / 60.0  # scene time between frames
SETTLE_ANSWERS = 12    # answered inputs before a size is measured (auto settles in 8 ticks)
STRAGGLER_S = 2.0      # after a run: time for answers still on their way
READY_TIMEOUT_S = 300.0
# The startup section's scene from files: the target's "100,000 dynamic sizes + 10,000 statics".
FILE_SCENE_DYNAMIC = 100000
FILE_SCENE_STATIC = 10000
SKIP_TICKS = 30        # timed ticks per case of the skips section
STAMP_OFFSET = ENCAPSULATION_SIZE  # the stamp (int32 sec, uint32 nanosec) follows the header
NODE_STOP_TIMEOUT_S = 10.0
SECTIONS = ('latency', 'arm', 'joint_states', 'floor', 'tick', 'output', 'skips', 'sphere',
            'gaps', 'startup')
ARM_RATE_HZ = 200.0
ARM_TARGET_ADDED_MS = 0.15  # the node's median latency over the echo's, at most (issue target)
# The inputs the node must answer for the arm's verdict: it keeps up. Its input queue is one
# deep (newest input wins), so a stall of one period (5 ms: the 2-vCPU VM's scheduler, about
# once a minute) drops an input; one in a thousand is far beyond that, far below falling behind.
ARM_ANSWERED_FRACTION = 0.999
ECHO_NAMESPACE = 'echo'     # the arm section's echo answers /echo/dynamic_poses
# The inputs the node answers on collisions: type and the node's own QoS for each.
INPUTS = {'dynamic_poses': (PoseArray, INPUT_QOS),
          'joint_states': (JointState, JOINT_STATES_QOS)}
JOINT_STATES_TARGET_ADDED_MS = 0.2  # joint_states -> collisions over the echo, at most
# The gaps section: what comes before each tick, (name, kind, seconds), timed in rounds that
# take every case in turn, so that a slow minute of a shared machine hits them all alike.
GAPS = (('nothing (back to back)', 'none', 0.0), ('sleep 1 ms', 'sleep', 0.001),
        ('sleep 10 ms', 'sleep', 0.01), ('busy-wait 10 ms', 'busy', 0.01),
        ('caches flushed', 'flush', 0.0))
GAP_ROUNDS = 6
GAP_TICKS_PER_ROUND = 8
FLUSH_BYTES = 64 << 20  # written between ticks: twice a 32 MB L3 cache


class Plan(NamedTuple):
    """What one run covers."""

    sizes: tuple       # bodies
    rates: tuple       # input messages per second
    run_s: float       # seconds of input per (size, rate)
    max_messages: int  # per run, so that slow large runs stay short
    skip_bodies: int   # size of the skips section's scenes
    sphere_sizes: tuple
    gap_bodies: int    # size of the gaps section's scene
    startup: bool
    arm_turns: int     # the arm section's turns each of the node and of the echo
    arm_turn_s: float  # seconds of input per turn
    tick_inputs: int   # the tick section's inputs per scene
    tick_bodies: tuple  # the tick section's uniform scenes (half of the bodies static)


PLANS = {
    'full': Plan(sizes=(100, 1000, 10000, 100000), rates=(10, 100, 1000), run_s=10.0,
                 max_messages=3000, skip_bodies=10000, sphere_sizes=(10000, 100000),
                 gap_bodies=10000, startup=True, arm_turns=10, arm_turn_s=3.0,
                 tick_inputs=20000, tick_bodies=(64, 1000)),
    'quick': Plan(sizes=(100, 1000, 10000, 100000), rates=(10, 100, 1000), run_s=3.0,
                  max_messages=600, skip_bodies=10000, sphere_sizes=(10000,), gap_bodies=10000,
                  startup=False, arm_turns=6, arm_turn_s=2.0, tick_inputs=5000,
                  tick_bodies=(64, 1000)),
    'tiny': Plan(sizes=(100,), rates=(20,), run_s=1.0, max_messages=20, skip_bodies=200,
                 sphere_sizes=(200,), gap_bodies=200, startup=False, arm_turns=2,
                 arm_turn_s=0.5, tick_inputs=50, tick_bodies=(64,)),
}


def scene_input(bodies, statics, seed=0):
    """Return (frames of poses, static poses, static half extents, dynamic half extents).

    The dynamic boxes share one size (the scene's mean): per-body sizes would be a 3 x N
    parameter, which rcl's YAML parser reads in time quadratic in N (106 s for 300,000 values
    here), and so would the node's start.
    """
    scene = uniform(bodies, seed)
    frames = [scene.dynamic_poses(k * FRAME_DT_S) for k in range(FRAMES)]
    static_poses, static_extents = scene.static_poses, scene.static_half_extents
    if not statics:  # the static half comes in the PoseArray as bodies that do not move
        frames = [np.concatenate([static_poses, poses]) for poses in frames]
        static_poses, static_extents = static_poses[:0], static_extents[:0]
    return frames, static_poses, static_extents, np.full(3, np.mean(UNIFORM_HALF_EXTENTS))


def node_parameters(static_poses, static_extents, dynamic_extents, broad_phase='auto',
                    threads=1):
    """Return the node's parameters for a scene, as name -> value."""
    return scene_parameters(static_poses, static_extents, dynamic_extents,
                            broad_phase=broad_phase, threads=threads, input_timeout_s=0.0,
                            **{'diagnostic_updater.period': DIAGNOSTIC_PERIOD_S})


class Client:
    """This process's side: publishes inputs, records answers and diagnostics by stamp.

    Its topics are relative: in ``namespace`` it talks to a node there (the arm section's echo).
    Inputs go to ``input_topic`` (:data:`INPUTS`): both begin with a header, so the stamp is
    patched at the same offset.
    """

    def __init__(self, context, namespace='', input_topic='dynamic_poses'):
        self.node = rclpy.create_node('collision_latency', namespace=namespace, context=context)
        self.poses = self.node.create_publisher(INPUTS[input_topic][0], input_topic, INPUT_QOS)
        self.node.create_subscription(PointCloud2, 'collisions', self._on_cloud, OUTPUT_QOS,
                                      raw=True)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics,
                                      OUTPUT_QOS)
        self.sent = {}       # (sec, nanosec) -> send time
        self.received = {}   # (sec, nanosec) -> receipt time
        self.statuses = []   # (receipt time, {key: value})
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        try:
            self.executor.spin()
        except Exception:  # noqa: B902 - the context went away at shutdown
            pass

    def _on_cloud(self, data):
        now = time.perf_counter()
        self.received[tuple(np.frombuffer(data, '<u4', 2, STAMP_OFFSET).tolist())] = now

    def _on_diagnostics(self, message):
        now = time.perf_counter()
        for status in message.status:
            if status.name == STATUS_NAME:
                self.statuses.append((now, {v.key: v.value for v in status.values}))

    def send(self, frame, sec, nanosec):
        """Publish ``frame`` (CDR bytes) with the stamp patched in; record the send time."""
        data = b''.join((frame[:STAMP_OFFSET], np.array([sec, nanosec], '<u4').tobytes(),
                         frame[STAMP_OFFSET + 8:]))
        self.sent[(sec, nanosec)] = time.perf_counter()
        self.poses.publish(data)

    def wait(self, condition, timeout_s):
        deadline = time.perf_counter() + timeout_s
        while not condition():
            if time.perf_counter() > deadline:
                return False
            time.sleep(0.002)
        return True

    def close(self):
        self.executor.shutdown()
        self._thread.join()
        self.node.destroy_node()


@contextlib.contextmanager
def ros_context(domain_id):
    """Yield an initialised rclpy context of its own; shut it down on leaving."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    try:
        yield context
    finally:
        context.try_shutdown()


def start_node(params_path, domain_id, cache_dir=None, command=None):
    """Start the node's own process (or ``command``, e.g. the echo); its log goes to a file."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id))
    if cache_dir is not None:
        env['NUMBA_CACHE_DIR'] = cache_dir
    log = tempfile.TemporaryFile('w+')
    if command is None:
        command = child_command('collision_node', '--ros-args', '--params-file', params_path)
    process = subprocess.Popen(command, env=env, stdout=log, stderr=subprocess.STDOUT)
    return process, log


def run_echo(cloud_path, namespace='', input_topic='dynamic_poses'):
    """Answer every PoseArray at once with the cloud in ``cloud_path``, its stamp copied.

    The floor section's stand-in for the node: the same messages both ways through the same
    QoS, and no collision work, so its latency is what ROS itself costs to a plain rclpy node
    (one executor for its subscription and its parameter services; the node answers its
    inputs on an executor of their own: lifetime.PriorityInputs).
    """
    keep_heap_memory()
    with open(cloud_path, 'rb') as source:
        cloud = bytearray(source.read())

    def make_echo():
        node = rclpy.create_node('collision_echo', namespace=namespace)
        publisher = node.create_publisher(PointCloud2, 'collisions', OUTPUT_QOS)

        def answer(data):
            cloud[STAMP_OFFSET:STAMP_OFFSET + 8] = data[STAMP_OFFSET:STAMP_OFFSET + 8]
            publisher.publish(bytes(cloud))

        message_type, qos = INPUTS[input_topic]
        node.create_subscription(message_type, input_topic, answer, qos, raw=True)
        return node

    with RosProgram() as program:  # as the node's main: the same exit
        program.start(make_echo)
        program.spin_until(Future())  # until SIGINT or SIGTERM


def stop_node(process, log):
    stop_process(process, NODE_STOP_TIMEOUT_S)
    log.close()


def node_log(log):
    """Return what the node wrote to ``log`` (start_node's) so far."""
    log.seek(0)  # the node appends at the end, where the read leaves the offset
    return log.read()


def node_failure(process, log):
    return 'the node exited with %s:\n%s' % (process.returncode, node_log(log)[-3000:])


def wait_ready(client, process, log, frame, run_id, started):
    """Send ``frame`` every 0.2 s until the node answers; return s from process start."""
    k = 0
    while True:
        if process.poll() is not None:
            raise RuntimeError(node_failure(process, log))
        if time.perf_counter() - started > READY_TIMEOUT_S:
            raise RuntimeError('the node did not answer within %g s' % READY_TIMEOUT_S)
        client.send(frame, run_id, k)
        k += 1
        if client.wait(lambda: any(key[0] == run_id for key in client.received), 0.2):
            return min(t for key, t in client.received.items() if key[0] == run_id) - started


def settle(client, frames, run_id):
    """Send inputs one at a time, each after the last was answered (auto picks its phase)."""
    for k in range(SETTLE_ANSWERS):
        client.send(frames[k % len(frames)], run_id, k)
        if not client.wait(lambda: (run_id, k) in client.received, READY_TIMEOUT_S):
            raise RuntimeError('no answer while settling')


def publish_at_rate(client, frames, rate_hz, count, run_id):
    """Publish ``count`` inputs at ``rate_hz``; return (latencies in ms, start, end)."""
    period = 1.0 / rate_hz
    start = time.perf_counter()
    next_send = start
    for k in range(count):
        delay = next_send - time.perf_counter()
        if delay > 0.0:
            time.sleep(delay)
        client.send(frames[k % len(frames)], run_id, k)
        # A publisher that falls behind does not burst to catch up.
        next_send = max(next_send + period, time.perf_counter())
    end = time.perf_counter()
    client.wait(lambda: all((run_id, k) in client.received for k in range(count)),
                STRAGGLER_S)
    latencies = np.array([client.received[(run_id, k)] - client.sent[(run_id, k)]
                          for k in range(count) if (run_id, k) in client.received]) * 1e3
    return latencies, start, end


def run_rate(client, frames, rate_hz, plan, run_id):
    """Publish at ``rate_hz`` for plan.run_s (or plan.max_messages); return the row."""
    count = min(plan.max_messages, max(int(rate_hz * plan.run_s), 1))
    latencies, start, end = publish_at_rate(client, frames, rate_hz, count, run_id)
    # Diagnostics periods end at most one period after the last tick.
    client.wait(lambda: any(t > end + DIAGNOSTIC_PERIOD_S for t, _ in client.statuses),
                3 * DIAGNOSTIC_PERIOD_S)
    statuses = [values for t, values in client.statuses
                if start < t <= end + DIAGNOSTIC_PERIOD_S + 0.5 and values['ticks'] != '0']
    row = {'rate_hz': rate_hz, 'sent': count, 'sent_rate_hz': count / max(end - start, 1e-9),
           'answered': len(latencies)}
    row.update(percentiles('latency', latencies))
    row.update(stage_summary(statuses))
    return row


def percentiles(name, values_ms):
    if not len(values_ms):
        return dict.fromkeys('%s_ms_%s' % (name, s) for s in ('median', 'p90', 'p99', 'max'))
    median, p90, p99 = np.percentile(values_ms, (50, 90, 99), method='higher')
    return {'%s_ms_median' % name: float(median), '%s_ms_p90' % name: float(p90),
            '%s_ms_p99' % name: float(p99), '%s_ms_max' % name: float(np.max(values_ms))}


def stage_summary(statuses):
    """Median of the periods' medians, largest p99 and max, per stage; World figures."""
    row = {}
    for stage in diagnostics.STAGES:
        for statistic, combine in (('median', np.median), ('p99', np.max), ('max', np.max)):
            key = '%s_ms_%s' % (stage, statistic)
            row[key] = float(combine([float(s[key]) for s in statuses])) if statuses else None
    last = statuses[-1] if statuses else {}
    for key in ('broad_phase', 'dynamic_bodies', 'static_bodies', 'candidate_pairs',
                'colliding_pairs', 'dropped_inputs'):
        row[key] = last.get(key)
    return row


def latency_section(plan, statics, broad_phase, thread_counts, domain_id, progress):
    """Time the node, one process per size and thread count."""
    def start(run, directory, bodies, threads, scene):
        _, static_poses, static_extents, dynamic_extents = scene
        params_path = os.path.join(directory, 'params_%d.yaml' % run)
        write_params_file(params_path, node_parameters(
            static_poses, static_extents, dynamic_extents, broad_phase, threads))
        return start_node(params_path, domain_id)

    runs = [(bodies, threads) for bodies in plan.sizes for threads in thread_counts]
    return _answered_runs(plan, runs, statics, domain_id, progress, start)


def arm_section(plan, domain_id, progress):
    """config/arm.yaml at ARM_RATE_HZ: the node and the echo in turns; the node's added ms."""
    arm = scenes.arm()
    states = [arm.dynamic_poses(k / ARM_RATE_HZ) for k in range(FRAMES)]
    frames = [serialize_pose_array(0, 0, 'world', poses) for poses in states]
    contacts = arm_world().step(states[0], arm.dynamic_half_extents).contacts
    return _against_echo('arm', plan, domain_id, progress, default_config('arm'), frames,
                         contacts, 'dynamic_poses', ARM_TARGET_ADDED_MS)


def joint_states_section(plan, domain_id, progress):
    """Time the Panda from its URDF at ARM_RATE_HZ, joint_states in, against the echo.

    The node reads robot_description (the Panda of example-robot-data, its meshes as boxes)
    and the robot_model section's table, wall and shelf; the inputs are JointState messages
    along a smooth collision-free path.
    """
    from collision_node.benchmarks import robot_model  # example-robot-data: bench only
    prefix, urdf_path, srdf_path = robot_model.panda_files()
    panda = robot_model.load_panda()
    world = robot_model.panda_world(panda)
    path, _ = robot_model.free_path(panda, world, np.random.default_rng(0), FRAMES)
    names = list(panda.joint_names)
    frames = [bytes(serialize_message(JointState(name=names, position=q.tolist())))
              for q in path]
    contacts = world.step(world.robot_poses(path[0])[0], panda.half_extents).contacts
    with open(urdf_path) as urdf, open(srdf_path) as srdf, \
            tempfile.TemporaryDirectory() as directory:
        params_path = os.path.join(directory, 'panda.yaml')
        write_params_file(params_path, scene_parameters(
            robot_model.STATIC_POSES, robot_model.STATIC_HALF_EXTENTS, [0.1, 0.1, 0.1],
            robot_description=urdf.read(), robot_description_semantic=srdf.read(),
            robot_description_package_paths=[os.path.join(prefix, 'share')]))
        return _against_echo('joint_states', plan, domain_id, progress, params_path, frames,
                             contacts, 'joint_states', JOINT_STATES_TARGET_ADDED_MS)


def _against_echo(name, plan, domain_id, progress, params_path, frames, contacts, input_topic,
                  target_added_ms):
    """Time the node (on ``params_path``) and an echo on ``frames``, in turns at ARM_RATE_HZ.

    The echo answers every input at once with the cloud of ``contacts``; both take turns of a
    few seconds, so that a slow moment of the machine hits both alike. Returns the section's
    row: each one's latencies, and the node's median over the echo's against the target.
    """
    count = max(int(ARM_RATE_HZ * plan.arm_turn_s), 1)
    latencies = {'node': [], 'echo': []}
    turn_medians = {'node': [], 'echo': []}
    with ros_context(domain_id) as context, tempfile.TemporaryDirectory() as directory:
        cloud_path = os.path.join(directory, 'cloud.bin')
        with open(cloud_path, 'wb') as out:
            out.write(bytes(CloudWriter().serialize(contacts, 0, 0, 'world')))
        clients = {'node': Client(context, input_topic=input_topic),
                   'echo': Client(context, ECHO_NAMESPACE, input_topic)}
        started = time.perf_counter()
        processes = {'node': start_node(params_path, domain_id),
                     'echo': start_node(None, domain_id, command=[
                         sys.executable, '-m', 'collision_node.benchmarks.collision_latency',
                         '--echo', cloud_path, '--echo-namespace', ECHO_NAMESPACE,
                         '--echo-input', input_topic])}
        try:
            for who, client in clients.items():
                ready_s = wait_ready(client, *processes[who], frames[0], 1, started)
                settle(client, frames, 2)
                progress('%s, %s: ready after %.2f s' % (name, who, ready_s))
            # Timed as the node runs after its first seconds: once its background warm-up
            # (every other kernel, loaded in its process) no longer competes with its ticks.
            log = processes['node'][1]
            if not clients['node'].wait(lambda: BACKGROUND_READY in node_log(log),
                                        READY_TIMEOUT_S):
                raise RuntimeError('the node did not finish its background warm-up within '
                                   '%g s' % READY_TIMEOUT_S)
            for turn in range(plan.arm_turns):
                for who, client in clients.items():
                    measured, _, _ = publish_at_rate(client, frames, ARM_RATE_HZ, count,
                                                     10 + turn)
                    latencies[who].append(measured)
                    turn_medians[who].append(float(np.median(measured)))
                    if processes[who][0].poll() is not None:
                        raise RuntimeError(node_failure(*processes[who]))
            progress('%s: median ms per turn: node %s; echo %s'
                     % (name, _fmt_list(turn_medians['node']), _fmt_list(turn_medians['echo'])))
        finally:
            for client in clients.values():
                client.close()
            for process, log in processes.values():
                stop_node(process, log)
    row = {'name': name, 'rate_hz': ARM_RATE_HZ, 'turns': plan.arm_turns,
           'sent': plan.arm_turns * count, 'target_added_ms': target_added_ms}
    for who in ('node', 'echo'):
        measured = np.concatenate(latencies[who])
        row[who + '_answered'] = len(measured)
        row.update(percentiles(who, measured))
        row[who + '_turn_medians_ms'] = turn_medians[who]
    row['added_ms'] = row['node_ms_median'] - row['echo_ms_median']
    return row


def arm_target_line(row):
    """Return the arm or joint_states section's target as one line, with its verdict.

    PASS: the median within the target, and ARM_ANSWERED_FRACTION of the inputs answered.
    """
    return ('%s through ROS at %g Hz, median latency <= echo + %g ms: node %.3f ms (p90 %.3f, '
            'p99 %.3f), echo %.3f ms (p90 %.3f, p99 %.3f) (%d/%d and %d/%d answered): +%.3f ms: '
            '%s' % (
                row['name'], row['rate_hz'], row['target_added_ms'], row['node_ms_median'],
                row['node_ms_p90'], row['node_ms_p99'], row['echo_ms_median'],
                row['echo_ms_p90'], row['echo_ms_p99'], row['node_answered'], row['sent'],
                row['echo_answered'], row['sent'], row['added_ms'],
                'PASS' if row['added_ms'] <= row['target_added_ms']
                and row['node_answered'] >= ARM_ANSWERED_FRACTION * row['sent'] else 'FAIL'))


def floor_section(plan, statics, domain_id, progress):
    """Time the echo (:func:`run_echo`) on the node's messages: what ROS costs, per size."""
    def start(run, directory, bodies, threads, scene):
        frames, static_poses, static_extents, dynamic_extents = scene
        world = World()
        world.set_static(static_poses, static_extents)
        contacts = world.step(frames[0], dynamic_extents).contacts
        cloud_path = os.path.join(directory, 'cloud_%d.bin' % run)
        with open(cloud_path, 'wb') as out:
            out.write(bytes(CloudWriter().serialize(contacts, 0, 0, 'world')))
        return start_node(None, domain_id, command=[
            sys.executable, '-m', 'collision_node.benchmarks.collision_latency', '--echo',
            cloud_path])

    return _answered_runs(plan, [(bodies, None) for bodies in plan.sizes], statics, domain_id,
                          progress, start)


def _answered_runs(plan, runs, statics, domain_id, progress, start):
    """Publish each run's scene at every rate to the process ``start`` starts; its rows.

    ``runs`` are (bodies, threads or None); ``start(run, directory, bodies, threads, scene)``
    starts the answering process and returns (process, log).
    """
    rows = []
    with ros_context(domain_id) as context, tempfile.TemporaryDirectory() as directory:
        client = Client(context)
        try:
            for run, (bodies, threads) in enumerate(runs):
                scene = scene_input(bodies, statics)
                frames = [serialize_pose_array(0, 0, 'world', poses) for poses in scene[0]]
                who = 'echo' if threads is None else '%d thread(s)' % threads
                started = time.perf_counter()
                process, log = start(run, directory, bodies, threads, scene)
                try:
                    base = 1000 * (run + 1)
                    ready_s = wait_ready(client, process, log, frames[0], base, started)
                    settle(client, frames, base + 1)
                    progress('%d bodies, %s: ready after %.2f s' % (bodies, who, ready_s))
                    for k, rate in enumerate(plan.rates):
                        time.sleep(DIAGNOSTIC_PERIOD_S + 0.1)  # no period spans two runs
                        row = run_rate(client, frames, rate, plan, base + 2 + k)
                        row.update(bodies=bodies, poses=bodies - len(scene[1]),
                                   statics=len(scene[1]), threads=threads,
                                   ready_s=ready_s, message_bytes=len(frames[0]))
                        rows.append(row)
                        progress('%d bodies, %s at %g Hz: median %s ms, %d of %d answered'
                                 % (bodies, who, rate, _fmt(row['latency_ms_median']),
                                    row['answered'], row['sent']))
                        if process.poll() is not None:
                            raise RuntimeError(node_failure(process, log))
                finally:
                    stop_node(process, log)
        finally:
            client.close()
    return rows


def _median_ms(function, repeats):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def output_section(plan, domain_id):
    """Cloud as a message object vs as bytes: written, and written + published."""
    rows = []
    with ros_context(domain_id) as context:
        node = rclpy.create_node('collision_latency_output', context=context)
        publisher = node.create_publisher(PointCloud2, 'output_probe', OUTPUT_QOS)
        node.create_subscription(PointCloud2, 'output_probe', lambda _: None, OUTPUT_QOS,
                                 raw=True)
        writer = CloudWriter()  # kept from call to call, as in the node
        try:
            for bodies in plan.sizes:
                frames, _, _, extents = scene_input(bodies, statics=False)
                contacts = World().step(frames[0], extents).contacts
                repeats = 50 if bodies < 100000 else 10
                cloud_bytes = writer.serialize(contacts, 1, 2, 'world')
                cloud = contacts_to_cloud(contacts, PointCloud2().header)
                rows.append({
                    'bodies': bodies, 'contacts': len(contacts),
                    'bytes_write_ms': _median_ms(
                        lambda: writer.serialize(contacts, 1, 2, 'world'), repeats),
                    'bytes_publish_ms': _median_ms(
                        lambda: publisher.publish(cloud_bytes), repeats),
                    'message_write_ms': _median_ms(
                        lambda: contacts_to_cloud(contacts, PointCloud2().header), repeats),
                    'message_publish_ms': _median_ms(
                        lambda: publisher.publish(cloud), repeats)})
        finally:
            node.destroy_node()
    return rows


class SkipCase(NamedTuple):
    """A node setup and the inputs it ticks on."""

    name: str
    parameters: dict
    frames: list     # CDR inputs, cycled


def skip_cases(bodies):
    """Pairs of (case that needs the work, case that skips it), as SkipCase tuples."""
    scene = uniform(2 * bodies, seed=3)
    statics, static_extents = scene.static_poses, scene.static_half_extents
    few = max(bodies // 10, 1)
    moving = [scene.dynamic_poses(k * FRAME_DT_S)[:few] for k in range(FRAMES)]
    all_moving = [scene.dynamic_poses(k * FRAME_DT_S) for k in range(FRAMES)]
    extents = scene.dynamic_half_extents

    def cdr(frames):
        return [serialize_pose_array(0, 0, 'world', poses) for poses in frames]

    with_statics = node_parameters(statics, static_extents, extents[:few])
    one_size = node_parameters(statics, static_extents, extents[0])  # for 1 or 0 poses
    disabled = dict(with_statics, **{name + '.enabled': False
                                     for name in with_statics['static_colliders']})
    as_dynamic = node_parameters(statics[:0], static_extents[:0],
                                 np.concatenate([static_extents, extents[:few]]))
    return [
        ('no dynamic bodies: %d statics' % len(statics),
         SkipCase('1 dynamic body', one_size, cdr([poses[:1] for poses in moving])),
         SkipCase('0 dynamic bodies', one_size, cdr([poses[:0] for poses in moving]))),
        ('identical input: %d dynamic bodies' % len(extents),
         SkipCase('moving', node_parameters(statics[:0], static_extents[:0], extents),
                  cdr(all_moving)),
         SkipCase('same poses again', node_parameters(statics[:0], static_extents[:0], extents),
                  cdr(all_moving[:1]))),
        ('bodies at rest: %d dynamic bodies, %d of them moving' % (len(extents), few),
         SkipCase('all moving', node_parameters(statics[:0], static_extents[:0], extents),
                  cdr(all_moving)),
         SkipCase('the rest keep their poses',
                  node_parameters(statics[:0], static_extents[:0], extents),
                  cdr([np.concatenate([poses[:few], all_moving[0][few:]])
                       for poses in all_moving]))),
        ('static colliders: %d statics, %d dynamic' % (len(statics), few),
         SkipCase('statics sent as dynamic poses', as_dynamic,
                  cdr([np.concatenate([statics, poses]) for poses in moving])),
         SkipCase('statics as colliders', with_statics, cdr(moving))),
        ('disabled colliders: %d statics, %d dynamic' % (len(statics), few),
         SkipCase('colliders enabled', with_statics, cdr(moving)),
         SkipCase('colliders disabled', disabled, cdr(moving))),
    ]


def tick_ms(context, case, ticks):
    """Median ms of the node's tick (CollisionNode._check) over ``ticks`` inputs."""
    node = CollisionNode(context=context, parameter_overrides=[
        Parameter(name, value=value) for name, value in case.parameters.items()
        if value != []])  # an empty list has no type in rclpy
    frames = itertools.cycle(case.frames)
    try:
        for _ in range(3):  # the World's first steps build what later ones reuse
            node._check(next(frames))
        return _median_ms(lambda: node._check(next(frames)), ticks)
    finally:
        node.destroy_node()


def tick_section(plan, domain_id):
    """Time the node's tick in this process, warm, inputs back to back: µs per input, stages.

    The node's input callback (CollisionNode._check) on pre-serialised PoseArrays: parse and
    checks, World.step, the cloud written, the bytes handed to rclpy (no subscriber), the
    diagnostics' record. No DDS, no executor, and caches warm from the last input: through
    ROS the same work takes longer (the gaps section shows what idle time costs).
    """
    arm = arm_states(400)
    cases = [('arm (config/arm.yaml)', ['--ros-args', '--params-file', default_config('arm')],
              [], arm)]
    for bodies in plan.tick_bodies:
        frames, statics, static_extents, extents = scene_input(bodies, True)
        cases.append(('uniform %d (%d static)' % (bodies, len(statics)), [],
                      [Parameter(name, value=value) for name, value in node_parameters(
                          statics, static_extents, extents).items()], frames))
    rows = []
    with ros_context(domain_id) as context:
        for what, arguments, overrides, frames in cases:
            node = CollisionNode(context=context, cli_args=arguments,
                                 parameter_overrides=overrides)
            try:
                inputs = [serialize_pose_array(k, 0, 'world', poses)
                          for k, poses in enumerate(frames)]
                for data in inputs:  # the World's first steps build what later ones reuse
                    node._check(data)
                node._monitor.report(time.monotonic(), 0.0)  # a period of timed inputs only
                start = time.perf_counter()
                for k in range(plan.tick_inputs):
                    node._check(inputs[k % len(inputs)])
                per_input_us = 1e6 * (time.perf_counter() - start) / plan.tick_inputs
                values = dict(node._monitor.report(time.monotonic(), 0.0)[2])
            finally:
                node.destroy_node()
            row = {'scene': what, 'bodies': len(frames[0]), 'inputs': plan.tick_inputs,
                   'us_per_input': per_input_us}
            for stage in diagnostics.STAGES:
                row[stage + '_us'] = 1e3 * float(values[stage + '_ms_median'])
            rows.append(row)
    return rows


def skips_section(plan, domain_id):
    rows = []
    with ros_context(domain_id) as context:
        for what, needed, skipped in skip_cases(plan.skip_bodies):
            rows.append({'what': what,
                         'needed': needed.name, 'needed_ms': tick_ms(context, needed, SKIP_TICKS),
                         'skipped': skipped.name,
                         'skipped_ms': tick_ms(context, skipped, SKIP_TICKS)})
    rows.append(diagnostics_cost())
    return rows


def diagnostics_cost():
    """µs per Monitor.tick, and ms per report with a full ring of samples."""
    monitor = diagnostics.Monitor(0.0)
    result = Result(None, dict.fromkeys(diagnostics.WORLD_KEYS, 0))
    stage_ms = tuple(np.linspace(0.1, 1.0, len(diagnostics.STAGES)))
    count = 20000
    start = time.perf_counter()
    for k in range(count):
        monitor.tick(k * 1e-3, stage_ms, result)
    per_tick_us = 1e6 * (time.perf_counter() - start) / count
    start = time.perf_counter()
    monitor.report(count * 1e-3, 0.0)
    return {'what': 'diagnostics: per tick, whatever the scene',
            'needed': 'Monitor.tick (µs)', 'needed_ms': per_tick_us,
            'skipped': 'report with %d samples (ms, once a period)'
                       % diagnostics.SAMPLES_PER_PERIOD,
            'skipped_ms': 1e3 * (time.perf_counter() - start)}


def sphere_section(plan):
    """Time the SAT stage with and without the bounding-sphere test, per scene."""
    from collision_node.pipeline.scenes import make_scene
    rows = []
    for name in ('uniform', 'clustered', 'flying_out'):
        for bodies in plan.sphere_sizes:
            scene = make_scene(name, bodies, seed=4)
            row = {'scene': name, 'bodies': bodies}
            for sphere in (True, False):
                world = World(sphere_prefilter=sphere)
                world.set_static(scene.static_poses, scene.static_half_extents)
                narrow = []
                for k in range(12):
                    stats = world.step(scene.dynamic_poses(0.3 + k * FRAME_DT_S),
                                       scene.dynamic_half_extents).stats
                    narrow.append(stats['narrow_ms'])
                key = 'on' if sphere else 'off'
                row['narrow_ms_' + key] = float(np.median(narrow[2:]))
                row['sat_tests_' + key] = stats['sat_tests']
                row['candidate_pairs'] = stats['candidate_pairs']
                row['colliding_pairs'] = stats['colliding_pairs']
            rows.append(row)
    return rows


def gaps_section(plan):
    """Time the World's stages after each kind of gap in GAPS (the --statics scene)."""
    frames, static_poses, static_extents, extents = scene_input(plan.gap_bodies, statics=True)
    # The grid, as auto takes at 10,000 bodies: its stages (a small scene's one pass has none).
    world = World(broad_phase='grid')
    world.set_static(static_poses, static_extents)
    inputs = itertools.cycle(frames)
    for _ in range(FRAMES):  # the grid's order and table sizes settle
        world.step(next(inputs), extents)
    flushed = np.zeros(FLUSH_BYTES // 8)
    stages = ('prepare_ms', 'broad_ms', 'narrow_ms', 'total_ms')
    times = {name: {stage: [] for stage in stages} for name, _, _ in GAPS}
    for _ in range(GAP_ROUNDS):
        for name, kind, seconds in GAPS:
            for _ in range(GAP_TICKS_PER_ROUND):
                if kind == 'sleep':
                    time.sleep(seconds)
                elif kind == 'busy':
                    until = time.perf_counter() + seconds
                    while time.perf_counter() < until:
                        pass
                elif kind == 'flush':
                    flushed += 1.0
                stats = world.step(next(inputs), extents).stats
                for stage in stages:
                    times[name][stage].append(stats[stage])
    return [dict({'before_tick': name, 'bodies': plan.gap_bodies},
                 **{stage: float(np.median(times[name][stage])) for stage in stages})
            for name, _, _ in GAPS]


def startup_section(domain_id):
    """Process start → first answer, with an empty numba cache and then with it filled."""
    rows = []
    frames, *_, extents = scene_input(1000, statics=False)
    frame = serialize_pose_array(0, 0, 'world', frames[0])
    with ros_context(domain_id) as context, tempfile.TemporaryDirectory() as directory:
        client = Client(context)
        try:
            params_path = os.path.join(directory, 'params.yaml')
            write_params_file(params_path, node_parameters(np.zeros((0, 7)), np.zeros((0, 3)),
                                                           extents))
            cache = os.path.join(directory, 'numba_cache')
            for run, cache_state in enumerate(('cold (empty NUMBA_CACHE_DIR)',
                                               'warm (same NUMBA_CACHE_DIR)')):
                started = time.perf_counter()
                process, log = start_node(params_path, domain_id, cache)
                try:
                    ready_s = wait_ready(client, process, log, frame, 9000 + run, started)
                finally:
                    stop_node(process, log)
                rows.append({'cache': cache_state, 'ready_s': ready_s})
            # A large scene from files (rcl's YAML parser would take minutes over its lists),
            # answered once: the first answer is a tick of every body against every collider.
            dynamic = uniform(2 * FILE_SCENE_DYNAMIC)
            statics = uniform(2 * FILE_SCENE_STATIC)
            write_params_file(params_path, dict(
                node_parameters(np.zeros((0, 7)), np.zeros((0, 3)), [0.5, 0.5, 0.5]),
                **write_scene_files(directory, statics.static_poses, statics.static_half_extents,
                                    dynamic.dynamic_half_extents)))
            frame = serialize_pose_array(0, 0, 'world', dynamic.dynamic_poses(0.0))
            started = time.perf_counter()
            process, log = start_node(params_path, domain_id, cache)
            try:
                ready_s = wait_ready(client, process, log, frame, 9002, started)
            finally:
                stop_node(process, log)
            rows.append({'cache': 'warm; %d dynamic sizes (.npy), %d static colliders (.npz)'
                                  % (FILE_SCENE_DYNAMIC, FILE_SCENE_STATIC), 'ready_s': ready_s})
        finally:
            client.close()
    return rows


def _fmt(value, digits=3):
    if value is None:
        return '—'
    if isinstance(value, float):
        return '%.*g' % (digits, value)
    return str(value)


def _fmt_list(values):
    return ' '.join(_fmt(value) for value in values)


def markdown(results):
    out = ['# collision_latency', '', '`%s`' % results['command'], '',
           '%s; %s; %s=%s; Python %s' % (
               results['machine'], results['rmw'], FASTDDS_PROFILE_VARIABLE,
               results['fastdds_profile'], results['python']), '']
    rows = results.get('latency', [])
    if rows:
        out += ['## PoseArray in → collisions out (ms)', '',
                "Stage columns: the node's /diagnostics, median over 1-s periods of the "
                "period's median. overhead = (parse + output + publish) / total.", '',
                '| bodies | poses | statics | threads | rate Hz | sent/s | answered | median '
                '| p99 | max | parse | broad | narrow | output | publish | total | overhead '
                '| phase |',
                '|' + '---|' * 18]
        for r in rows:
            overhead = None
            if r['total_ms_median']:
                overhead = '%.0f %%' % (100.0 * (r['parse_ms_median'] + r['output_ms_median']
                                                 + r['publish_ms_median'])
                                        / r['total_ms_median'])
            out.append('| ' + ' | '.join(_fmt(v) for v in (
                r['bodies'], r['poses'], r['statics'], r['threads'], r['rate_hz'],
                round(r['sent_rate_hz']),
                '%d/%d' % (r['answered'], r['sent']), r['latency_ms_median'],
                r['latency_ms_p99'], r['latency_ms_max'], r['parse_ms_median'],
                r['broad_ms_median'], r['narrow_ms_median'], r['output_ms_median'],
                r['publish_ms_median'],
                r['total_ms_median'], overhead, r['broad_phase'])) + ' |')
        ready = sorted({(r['bodies'], r['threads'], round(r['ready_s'], 2)) for r in rows})
        out += ['', 'Node ready (process start → first answer, warm cache): ' + ', '.join(
            '%d bodies (%d thread(s)) %.2f s' % item for item in ready), '']
    for key, title in (('arm', 'Arm: config/arm.yaml, the node against an echo node (ms)'),
                       ('joint_states', 'Joint states: the Panda from its URDF, joint_states '
                        'in, the node against an echo node (ms)')):
        arm = results.get(key)
        if not arm:
            continue
        out += ['## ' + title, '',
                'The node and the echo answer in turns of %g s each, %d turns; medians per '
                'turn: node %s, echo %s.' % (
                    results['plan']['arm_turn_s'], arm['turns'],
                    _fmt_list(arm['node_turn_medians_ms']),
                    _fmt_list(arm['echo_turn_medians_ms'])), '',
                '| who | answered | median | p90 | p99 | max |', '|---|---|---|---|---|---|']
        out += ['| %s | %d/%d | %s | %s | %s | %s |' % (
            (who, arm[who + '_answered'], arm['sent'])
            + tuple(_fmt(arm['%s_ms_%s' % (who, statistic)])
                    for statistic in ('median', 'p90', 'p99', 'max')))
            for who in ('node', 'echo')]
        out += ['', 'Target: ' + arm_target_line(arm), '']
    for title, key, columns in (
            ('Floor: the same messages answered at once by an echo node (ms)', 'floor',
             ('bodies', 'poses', 'statics', 'rate_hz', 'answered', 'latency_ms_median',
              'latency_ms_p99', 'latency_ms_max')),
            ("Tick: the node's input callback in one process, warm, back to back (µs; "
             'stages: medians)', 'tick',
             ('scene', 'bodies', 'inputs', 'us_per_input', 'parse_us', 'broad_us', 'narrow_us',
              'output_us', 'publish_us', 'total_us')),
            ('Output: the cloud as bytes vs as a message object (ms)', 'output',
             ('bodies', 'contacts', 'bytes_write_ms', 'bytes_publish_ms', 'message_write_ms',
              'message_publish_ms')),
            ("Skip what a scene does not need: the node's tick, median ms", 'skips',
             ('what', 'needed', 'needed_ms', 'skipped', 'skipped_ms')),
            ('Sphere prefilter: SAT stage, median ms', 'sphere',
             ('scene', 'bodies', 'candidate_pairs', 'colliding_pairs', 'sat_tests_on',
              'narrow_ms_on', 'narrow_ms_off')),
            ("Gaps: the World's tick after idle time, median ms", 'gaps',
             ('bodies', 'before_tick', 'prepare_ms', 'broad_ms', 'narrow_ms', 'total_ms')),
            ('Startup: process start → first answer (s)', 'startup', ('cache', 'ready_s'))):
        if results.get(key):
            out += ['## ' + title, '', '| ' + ' | '.join(columns) + ' |',
                    '|' + '---|' * len(columns)]
            out += ['| ' + ' | '.join(_fmt(r[c] if c != 'answered' else
                                           '%d/%d' % (r['answered'], r['sent']))
                                      for c in columns) + ' |'
                    for r in results[key]]
            out.append('')
    return '\n'.join(out)


def parse_arguments(argv):
    parser = argparse.ArgumentParser(prog='collision_latency',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('--quick', action='store_const', const='quick', dest='plan',
                        default='full', help='short runs, under 2 minutes')
    parser.add_argument('--tiny', action='store_const', const='tiny', dest='plan',
                        help='one small size, seconds (for the tests)')
    parser.add_argument('--statics', action='store_true',
                        help="the scene's static half as the node's static_colliders")
    parser.add_argument('--broad-phase', default='auto', choices=NAMES,
                        help="the node's broad_phase parameter (default: auto)")
    parser.add_argument('--threads', type=int, nargs='+', default=[1], metavar='T',
                        help="the node's threads parameter; each count is a run (default: 1)")
    parser.add_argument('--sizes', type=int, nargs='+', metavar='N', help='body counts')
    parser.add_argument('--rates', type=float, nargs='+', metavar='HZ', help='input rates')
    parser.add_argument('--sections', nargs='+', default=list(SECTIONS), choices=SECTIONS)
    parser.add_argument('--json', metavar='FILE', help='write every number here')
    parser.add_argument('--echo', metavar='CLOUD_FILE',
                        help="run as the floor section's echo node, answering with this cloud")
    parser.add_argument('--echo-input', default='dynamic_poses', choices=sorted(INPUTS),
                        help="the topic the echo answers (default: dynamic_poses)")
    parser.add_argument('--echo-namespace', default='', metavar='NS',
                        help="the echo node's namespace (the arm section's: %s)" % ECHO_NAMESPACE)
    parser.add_argument('--domain-id', type=int, default=100 + os.getpid() % 100,
                        help='ROS_DOMAIN_ID of the node and this process')
    options = parser.parse_args(argv)
    plan = PLANS[options.plan]
    if options.sizes:
        plan = plan._replace(sizes=tuple(options.sizes))
    if options.rates:
        if min(options.rates) <= 0:
            parser.error('--rates must be positive')
        plan = plan._replace(rates=tuple(options.rates))
    if min(options.threads) < 1:
        parser.error('--threads must be positive')
    return options, plan


def main(args=None):
    """Run the sections asked for; print the tables; write JSON if asked."""
    argv = sys.argv[1:] if args is None else args
    options, plan = parse_arguments(argv)
    if options.echo:
        run_echo(options.echo, options.echo_namespace, options.echo_input)
        return 0
    keep_heap_memory()  # as the node does: receiving large clouds costs no page faults
    start = time.perf_counter()

    def progress(message):
        print('[%6.1f s] %s' % (time.perf_counter() - start, message), file=sys.stderr,
              flush=True)

    results = {'command': 'collision_latency ' + ' '.join(shlex.quote(a) for a in argv),
               'machine': '%s, %d cores' % (platform.machine(), os.cpu_count()),
               'rmw': os.environ.get('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp (default)'),
               'fastdds_profile': os.environ.get(FASTDDS_PROFILE_VARIABLE, 'none'),
               'python': platform.python_version(), 'plan': plan._asdict()}
    sections = options.sections
    if 'latency' in sections:
        results['latency'] = latency_section(plan, options.statics, options.broad_phase,
                                             options.threads, options.domain_id, progress)
    if 'arm' in sections:
        results['arm'] = arm_section(plan, options.domain_id, progress)
        progress(arm_target_line(results['arm']))
    if 'joint_states' in sections:
        results['joint_states'] = joint_states_section(plan, options.domain_id, progress)
        progress(arm_target_line(results['joint_states']))
    if 'floor' in sections:
        results['floor'] = floor_section(plan, options.statics, options.domain_id, progress)
    if 'tick' in sections:
        results['tick'] = tick_section(plan, options.domain_id)
        progress('tick done')
    if 'output' in sections:
        results['output'] = output_section(plan, options.domain_id)
        progress('output done')
    if 'skips' in sections:
        results['skips'] = skips_section(plan, options.domain_id)
        progress('skips done')
    if 'sphere' in sections:
        results['sphere'] = sphere_section(plan)
        progress('sphere done')
    if 'gaps' in sections:
        results['gaps'] = gaps_section(plan)
        progress('gaps done')
    if 'startup' in sections and plan.startup:
        results['startup'] = startup_section(options.domain_id)
    results['seconds'] = time.perf_counter() - start
    print(markdown(results))
    if options.json:
        with open(options.json, 'w') as out:
            json.dump(results, out, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
