"""Run collision_node for a long time and report its memory and latency over time.

    collision_soak --duration 600 --rate 100 --bodies 1000
    collision_soak --ticks 10000 --rate 500 --bodies 100 --json soak.json

Starts the node as a child process (this Python, the same ROS_DOMAIN_ID) on a params file made
for the scene (its static boxes as colliders, the sizes of its moving boxes), publishes the
moving boxes at ``--rate`` from a thread of this process and every ``--interval`` seconds prints
one line: the node's ticks and tick rate, inputs sent, the node process's resident memory (RSS),
the latency from publishing a PoseArray to receiving its collisions (p50, p99, max), and the
node's dropped and rejected inputs. Stops after ``--duration`` seconds or ``--ticks`` ticks,
waits until the node's diagnostics account for every input sent, stops the node, and prints a
summary (``--json``: also as a file).

Memory counts from the node's first answer on. It is flat when the RSS trend over the second
half of that time (least squares; the first half takes the warm-up: DDS buffers, the World's
arrays growing to their size, Python's allocator settling) adds up to less than
``--max-growth-mb`` over that half; the exit code is 1 if not, or if the node died.
"""
import argparse
import json
import os
import struct
import subprocess
import sys
import tempfile
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray
import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import remove_ros_args
from sensor_msgs.msg import PointCloud2

from collision_node.benchmarks.params_files import scene_parameters, write_params_file
from collision_node.pipeline.scenes import make_scene, scene_body_count, SCENES
from collision_node.ros.cdr import ENCAPSULATION_SIZE, serialize_pose_array
from collision_node.ros.lifetime import ending_on_shutdown
from collision_node.ros.node import INPUT_QOS  # the node's own input QoS
from collision_node.tools.processes import stop_process

STATUS_NAME = 'collision_node: collision_check'
OUTPUT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                        reliability=ReliabilityPolicy.RELIABLE)
DIAGNOSTIC_PERIOD_S = 0.5
RSS_PERIOD_S = 0.25
# Frames of the moving scene computed before the run and sent in turn: the publisher's own
# cost stays a copy, so it can outrun the node (overload runs) without stealing its core.
FRAMES = 256
FRAME_STEP_S = 0.01  # scene time between consecutive frames
READY_TIMEOUT_S = 120.0  # a cold numba cache compiles for tens of seconds
SETTLE_TIMEOUT_S = 15.0  # after the last input, for the diagnostics to count it
STOP_TIMEOUT_S = 10.0
STAMP = struct.Struct('<iI')  # header stamp at the start of a little-endian CDR body


def rss_mb(pid):
    """Return the resident memory of process ``pid`` in MB (VmRSS), None once it is gone."""
    try:
        with open('/proc/%d/status' % pid) as stream:
            for line in stream:
                if line.startswith('VmRSS:'):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None


def memory_trend(times_s, rss):
    """Summarise RSS samples (s, MB): values at quarters, and the trend over the second half.

    ``growth_mb`` is the least-squares slope over the second half of the run times that
    half's length: what the node gained once warmed up, insensitive to single samples.
    """
    times_s, rss = np.asarray(times_s, float), np.asarray(rss, float)
    if len(times_s) < 4:
        return {'samples': len(times_s)}
    middle = times_s[0] + 0.5 * (times_s[-1] - times_s[0])
    second = times_s >= middle
    slope = np.polyfit(times_s[second], rss[second], 1)[0] if second.sum() >= 2 else 0.0
    span = times_s[second][-1] - times_s[second][0]

    def at(fraction):
        return float(np.interp(times_s[0] + fraction * (times_s[-1] - times_s[0]), times_s, rss))
    return {'samples': len(times_s), 'rss_start_mb': float(rss[0]), 'rss_quarter_mb': at(0.25),
            'rss_half_mb': at(0.5), 'rss_end_mb': float(rss[-1]), 'rss_max_mb': float(rss.max()),
            'slope_mb_per_min': 60.0 * float(slope), 'growth_mb': float(slope * span)}


def percentiles_ms(latencies_s):
    """Return p50, p99 and max of latencies (s) in ms; zeros for none."""
    if not len(latencies_s):
        return {'p50_ms': 0.0, 'p99_ms': 0.0, 'max_ms': 0.0}
    p50, p99 = np.percentile(latencies_s, (50.0, 99.0), method='higher')
    return {'p50_ms': 1e3 * float(p50), 'p99_ms': 1e3 * float(p99),
            'max_ms': 1e3 * float(np.max(latencies_s))}


class Soak:
    """The publisher, the listeners and the bookkeeping of one soak run (node: a child pid)."""

    def __init__(self, node, frames, rate_hz, pid):
        self.frames = frames
        self.rate_hz = rate_hz
        self.pid = pid
        self.context = node.context
        self.publisher = node.create_publisher(PoseArray, 'dynamic_poses', INPUT_QOS)
        node.create_subscription(PointCloud2, 'collisions', self.on_collisions, OUTPUT_QOS,
                                 raw=True)
        node.create_subscription(DiagnosticArray, '/diagnostics', self.on_diagnostics,
                                 OUTPUT_QOS)
        self.lock = threading.Lock()
        self.sent = 0
        self.last_sent_stamp = None
        self.stop_publishing = threading.Event()
        self.answered = 0
        self.last_answer_stamp = None
        self.answers_in_order = True
        self.latencies = []        # s, since the last interval line
        self.all_latencies = []    # (seconds since start, s)
        self.ticks = 0
        self.dropped = self.rejected = 0
        self.last_rejection = ''
        self.tick_ms = []          # (median, p99) of each diagnostics period
        self.levels = []
        self.rss = []              # (seconds since start, MB)
        self.start_s = time.monotonic()
        self.first_answer_s = None
        self.first_answer = threading.Event()

    def publish_loop(self):
        """Publish a frame every 1/rate s; a late frame goes out at once, never two at once.

        The first frame goes out alone, and the rest only once it is answered: the node
        counts the inputs it missed from the sequence numbers after the first one it got.
        A shutdown signal (rclpy's context shut down) ends the loop quietly.
        """
        with ending_on_shutdown(self.context):
            self._publish_loop()

    def _publish_loop(self):
        while self.publisher.get_subscription_count() == 0:
            if self.stop_publishing.wait(0.05):
                return
        self.publish_frame()
        if not self.first_answer.wait(READY_TIMEOUT_S):
            return
        period = 1.0 / self.rate_hz
        next_s = time.monotonic()
        while not self.stop_publishing.is_set():
            self.publish_frame()
            next_s = max(next_s + period, time.monotonic())
            delay = next_s - time.monotonic()
            if delay > 0.0:
                time.sleep(delay)

    def publish_frame(self):
        buffer, stamp_view = self.frames[self.sent % len(self.frames)]
        sec, nanosec = divmod(time.time_ns(), 10**9)
        stamp_view[:] = STAMP.pack(sec, nanosec)  # only the stamp changes
        self.publisher.publish(bytes(buffer))
        with self.lock:
            self.sent += 1
            self.last_sent_stamp = (sec, nanosec)

    def on_collisions(self, buffer):
        received_ns = time.time_ns()
        sec, nanosec = STAMP.unpack_from(buffer, ENCAPSULATION_SIZE)
        latency = (received_ns - (sec * 10**9 + nanosec)) * 1e-9
        if self.first_answer_s is None:
            self.first_answer_s = time.monotonic() - self.start_s
            self.first_answer.set()
        if self.last_answer_stamp is not None and (sec, nanosec) <= self.last_answer_stamp:
            self.answers_in_order = False
        self.last_answer_stamp = (sec, nanosec)
        self.answered += 1
        self.latencies.append(latency)
        self.all_latencies.append((time.monotonic() - self.start_s, latency))

    def on_diagnostics(self, message):
        for status in message.status:
            if status.name != STATUS_NAME:
                continue
            found = {item.key: item.value for item in status.values}
            self.ticks += int(found['ticks'])
            self.dropped = int(found['dropped_inputs'])
            self.rejected = int(found['rejected_inputs'])
            self.last_rejection = found['last_rejection']
            if int(found['ticks']):
                self.tick_ms.append((float(found['total_ms_median']),
                                     float(found['total_ms_p99'])))
            self.levels.append(int.from_bytes(status.level, 'little'))

    def sample_rss(self):
        value = rss_mb(self.pid)
        if value is not None:
            self.rss.append((time.monotonic() - self.start_s, value))

    def interval_line(self, previous):
        """One progress line since ``previous`` (a dict this returns for the next call)."""
        now = time.monotonic() - self.start_s
        with self.lock:
            sent = self.sent
        elapsed = max(now - previous['time'], 1e-9)
        latencies, self.latencies = self.latencies, []
        stats = percentiles_ms(latencies)
        line = ('%7.1f s | %8d ticks %7.1f Hz | sent %8d | RSS %7.1f MB | latency ms p50 %6.2f '
                'p99 %7.2f max %7.2f | dropped %d rejected %d' % (
                    now, self.ticks, (self.ticks - previous['ticks']) / elapsed, sent,
                    self.rss[-1][1] if self.rss else float('nan'), stats['p50_ms'],
                    stats['p99_ms'], stats['max_ms'], self.dropped, self.rejected))
        return line, {'time': now, 'ticks': self.ticks}

    def summary(self, options, ready_s, node_exit):
        latencies = np.array([latency for _, latency in self.all_latencies])
        # Memory counts from the first answer on: before it the node was still starting.
        ready = [(t, mb) for t, mb in self.rss if ready_s is not None and t >= ready_s]
        times, values = zip(*ready) if ready else ((), ())
        tick_ms = np.array(self.tick_ms) if self.tick_ms else np.zeros((0, 2))
        quarter = len(latencies) // 4
        return {
            'scene': options.scene, 'bodies': options.bodies, 'rate_hz': options.rate,
            'duration_s': time.monotonic() - self.start_s, 'ready_s': ready_s,
            'sent': self.sent, 'ticks': self.ticks, 'answered': self.answered,
            'dropped': self.dropped, 'rejected': self.rejected,
            'last_rejection': self.last_rejection,
            'accounted': self.ticks + self.dropped + self.rejected == self.sent,
            'answers_in_order': self.answers_in_order,
            'last_answer_is_last_sent': self.last_answer_stamp == self.last_sent_stamp,
            'latency': percentiles_ms(latencies),
            'latency_first_quarter': percentiles_ms(latencies[:quarter]),
            'latency_last_quarter': percentiles_ms(latencies[len(latencies) - quarter:]),
            'tick_ms_median': float(np.median(tick_ms[:, 0])) if len(tick_ms) else 0.0,
            'tick_ms_p99_max': float(tick_ms[:, 1].max()) if len(tick_ms) else 0.0,
            'error_statuses': self.levels.count(2),
            'memory': memory_trend(times, values),
            'rss_samples': [[round(t, 2), round(v, 2)] for t, v in self.rss],
            'node_exit_code': node_exit,
        }


def parse_arguments(argv):
    parser = argparse.ArgumentParser(prog='collision_soak', description=__doc__.split('\n\n')[0])
    parser.add_argument('--duration', type=float, default=60.0, metavar='S',
                        help='seconds of publishing (default: 60)')
    parser.add_argument('--ticks', type=int, metavar='N',
                        help='stop once the node ticked N times instead (the duration is then '
                             'only a time limit)')
    parser.add_argument('--rate', type=float, default=100.0, metavar='HZ',
                        help='PoseArrays per second (default: 100)')
    parser.add_argument('--scene', choices=sorted(SCENES), default='uniform',
                        help='moving scene (default: uniform, half of its bodies static)')
    parser.add_argument('--bodies', type=int, metavar='N',
                        help='body count of the scene (default: its own, e.g. 7 for the arm; '
                        'else 1000)')
    parser.add_argument('--seed', type=int, default=0, help='scene seed (default: 0)')
    parser.add_argument('--broad-phase', default='auto',
                        help="the node's broad_phase (default: auto)")
    parser.add_argument('--interval', type=float, default=10.0, metavar='S',
                        help='seconds between progress lines (default: 10)')
    parser.add_argument('--max-growth-mb', type=float, default=2.0, metavar='MB',
                        help='RSS growth over the second half that still counts as flat '
                             '(default: 2)')
    parser.add_argument('--json', metavar='FILE', help='also write the summary here')
    options = parser.parse_args(argv)
    for name in ('duration', 'rate', 'interval'):
        if not getattr(options, name) > 0.0:
            parser.error('--%s must be positive, got %s' % (name, getattr(options, name)))
    if options.ticks is not None and options.ticks < 1:
        parser.error('--ticks must be at least 1, got %d' % options.ticks)
    try:
        options.bodies = scene_body_count(options.scene, options.bodies)
    except ValueError as error:
        parser.error('--bodies: %s' % error)
    if options.bodies < 1:
        parser.error('--bodies must be at least 1, got %d' % options.bodies)
    return options


def prepared_frames(scene):
    """Serialize FRAMES frames of the scene once; each with a writable view of its stamp."""
    frames = []
    for k in range(FRAMES):
        buffer = bytearray(serialize_pose_array(0, 0, 'world',
                                                scene.dynamic_poses(k * FRAME_STEP_S)))
        stamp = memoryview(buffer)[ENCAPSULATION_SIZE:ENCAPSULATION_SIZE + STAMP.size]
        frames.append((buffer, stamp))
    return frames


def start_node(params_path):
    return subprocess.Popen(
        [sys.executable, '-m', 'collision_node.ros.node', '--ros-args', '--params-file',
         params_path],
        start_new_session=True)  # Ctrl-C reaches the soak only; it stops the node itself


def stop_node(process):
    """Stop the node: SIGINT, then SIGTERM and SIGKILL if it hangs; return its exit code."""
    return stop_process(process, STOP_TIMEOUT_S)


def run(options, args):
    scene = make_scene(options.scene, options.bodies, options.seed)
    if not scene.dynamic_count:
        raise SystemExit('the %s scene of %d bodies has no moving body' % (
            options.scene, options.bodies))
    frames = prepared_frames(scene)
    workdir = tempfile.mkdtemp(prefix='collision_soak_')
    params_path = os.path.join(workdir, 'params.yaml')
    write_params_file(params_path, scene_parameters(
        scene.static_poses, scene.static_half_extents, scene.dynamic_half_extents,
        broad_phase=options.broad_phase, input_timeout_s=2.0,
        **{'diagnostic_updater.period': DIAGNOSTIC_PERIOD_S}))
    print('collision_soak: %s scene, %d bodies (%d moving), %g Hz, %s' % (
        options.scene, options.bodies, scene.dynamic_count, options.rate,
        '%d ticks' % options.ticks if options.ticks else '%g s' % options.duration), flush=True)

    rclpy.init(args=args)
    listener = rclpy.create_node('collision_soak')
    executor = SingleThreadedExecutor()
    executor.add_node(listener)
    process = start_node(params_path)
    soak = Soak(listener, frames, options.rate, process.pid)
    listener.create_timer(RSS_PERIOD_S, soak.sample_rss)
    publisher = threading.Thread(target=soak.publish_loop, daemon=True)
    publisher.start()
    ready_s = None
    try:
        with ending_on_shutdown(listener.context):  # SIGTERM: the summary of what ran
            deadline = time.monotonic() + READY_TIMEOUT_S
            while soak.first_answer_s is None and process.poll() is None \
                    and time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.05)
            ready_s = soak.first_answer_s
            print('node ready (first answer) %.2f s after its start' % (ready_s or float('nan')),
                  flush=True)
            run_start = time.monotonic()
            end = run_start + options.duration
            next_line = run_start + options.interval
            previous = {'time': time.monotonic() - soak.start_s, 'ticks': soak.ticks}
            while process.poll() is None and time.monotonic() < end and ready_s is not None \
                    and not (options.ticks and soak.ticks >= options.ticks):
                executor.spin_once(timeout_sec=0.05)
                if time.monotonic() >= next_line:
                    line, previous = soak.interval_line(previous)
                    print(line, flush=True)
                    next_line += options.interval
            soak.stop_publishing.set()
            publisher.join()
            settle = time.monotonic() + SETTLE_TIMEOUT_S
            while process.poll() is None and time.monotonic() < settle \
                    and soak.ticks + soak.dropped + soak.rejected < soak.sent:
                executor.spin_once(timeout_sec=0.05)
            for _ in range(int(2 * DIAGNOSTIC_PERIOD_S / 0.05)):  # one more period: late answers
                executor.spin_once(timeout_sec=0.05)
            line, previous = soak.interval_line(previous)
            print(line, flush=True)
    except KeyboardInterrupt:
        print('interrupted', flush=True)
    finally:
        soak.stop_publishing.set()
        soak.first_answer.set()  # a publisher still waiting for it goes too
        died = process.poll()  # None: alive until the end, then stopped here
        if died is None:
            stop_node(process)
        executor.shutdown()
        listener.destroy_node()
        rclpy.try_shutdown()
    summary = soak.summary(options, ready_s, died)
    return summary


def report(summary, options):
    """Print the summary; return the exit code (1: node died or memory not flat)."""
    memory = summary['memory']
    latency = summary['latency']
    print('summary: %d s, %d sent, %d ticks, %d answered, %d dropped, %d rejected%s' % (
        summary['duration_s'], summary['sent'], summary['ticks'], summary['answered'],
        summary['dropped'], summary['rejected'],
        '' if summary['accounted'] else ' (ticks + dropped + rejected != sent)'))
    print('latency ms: p50 %.2f p99 %.2f max %.2f; first quarter p99 %.2f, last quarter p99 '
          '%.2f; node tick ms median %.2f, worst period p99 %.2f' % (
              latency['p50_ms'], latency['p99_ms'], latency['max_ms'],
              summary['latency_first_quarter']['p99_ms'],
              summary['latency_last_quarter']['p99_ms'], summary['tick_ms_median'],
              summary['tick_ms_p99_max']))
    if 'growth_mb' in memory:
        print('RSS MB: start %.1f, 1/4 %.1f, 1/2 %.1f, end %.1f, max %.1f; second half trend '
              '%+.3f MB/min, %+.2f MB over it (flat below %g MB)' % (
                  memory['rss_start_mb'], memory['rss_quarter_mb'], memory['rss_half_mb'],
                  memory['rss_end_mb'], memory['rss_max_mb'], memory['slope_mb_per_min'],
                  memory['growth_mb'], options.max_growth_mb))
    if options.json:
        with open(options.json, 'w') as stream:
            json.dump(summary, stream, indent=1)
    if summary['node_exit_code'] is not None:
        print('the node died during the run with exit code %d' % summary['node_exit_code'])
        return 1
    if summary['ready_s'] is None:
        print('the node never answered')
        return 1
    if memory.get('growth_mb', 0.0) >= options.max_growth_mb:
        print('memory is not flat')
        return 1
    return 0


def main(args=None):
    """Run a soak as the command line asks; exit 1 if the node died or its memory grew."""
    options = parse_arguments(remove_ros_args(args if args is not None else sys.argv)[1:])
    return report(run(options, args), options)


if __name__ == '__main__':
    sys.exit(main())
