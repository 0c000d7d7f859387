"""Publish dynamic poses at a fixed rate: a named moving scene, or frames from a .npy file.

    pose_publisher --scene room --rate 30
    pose_publisher --npy poses.npy --count 100

A scene's clock starts at the first message: message k shows the scene at its header stamp
minus the first message's stamp, so a subscriber can recompute every pose it receives with
``make_scene(name, bodies, seed).dynamic_poses(t)`` (:mod:`collision_node.pipeline.scenes`).
Only the scene's dynamic boxes are published; its static boxes belong in the node's parameters
(the statics of ``room`` are those of config/default.yaml). A .npy file holds one frame (N, 7)
or a sequence (T, N, 7) of x y z qx qy qz qw rows, published in turn and cycled.
"""
import argparse
import sys

from geometry_msgs.msg import PoseArray
import numpy as np
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from rclpy.utilities import remove_ros_args

from collision_node.pipeline.scenes import (make_scene, scene_body_count, SCENE_BODY_COUNTS,
                                            SCENES)
from collision_node.ros.cdr import serialize_pose_array
from collision_node.tools.processes import spin_until_finished

TOPIC = 'dynamic_poses'
# Scenes other than the room are sized by their total body count (uniform ones keep half of
# them static); a thousand is the seed papers' scale.
DEFAULT_BODIES = 1000
# After the last of --count messages: time for a reliable subscriber to acknowledge it
# before the process, and with it the DDS writer, goes away.
ACK_TIMEOUT_S = 2.0


class PosePublisher(Node):
    """Publishes one PoseArray per timer period from a frame source until ``count`` are out."""

    def __init__(self, frames, rate_hz, frame_id, count=None, wait_for_subscriber=False):
        """``frames(time_s, k)`` gives the (N, 7) poses of message ``k`` at scene time."""
        super().__init__('pose_publisher')
        self.frames = frames
        self.frame_id = frame_id
        self.count = count
        self.wait_for_subscriber = wait_for_subscriber
        self.sent = 0
        self.first_stamp_ns = None
        self.finished = Future()
        # Reliable: a large PoseArray does not get through best-effort with Fast DDS's default
        # transports. Newest only, as the node's input (doc/design.md), when running on. A run of
        # ``count`` keeps them all, transient-local: DDS matches the two ends of a topic one
        # at a time, so a subscriber this writer already sees may not yet see this writer and
        # miss the first messages; a transient-local subscriber then still gets every one.
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=count or 1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL if count
                         else DurabilityPolicy.VOLATILE)
        self.publisher = self.create_publisher(PoseArray, TOPIC, qos)
        self.timer = self.create_timer(1.0 / rate_hz, self.publish_next)

    def publish_next(self):
        if self.wait_for_subscriber and self.publisher.get_subscription_count() == 0:
            return
        now = self.get_clock().now()
        if self.first_stamp_ns is None:
            self.first_stamp_ns = now.nanoseconds
        poses = self.frames((now.nanoseconds - self.first_stamp_ns) * 1e-9, self.sent)
        sec, nanosec = now.seconds_nanoseconds()
        # Serialized bytes: rclpy's own conversion of a PoseArray costs ~6 µs per pose.
        self.publisher.publish(serialize_pose_array(sec, nanosec, self.frame_id, poses))
        self.sent += 1
        if self.count is not None and self.sent >= self.count:
            self.timer.cancel()
            self.publisher.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))
            self.finished.set_result(self.sent)


def scene_frames(name, bodies, seed):
    """Return the frame source of a named scene: its dynamic poses at the scene time."""
    scene = make_scene(name, bodies, seed)
    return lambda time_s, _k: scene.dynamic_poses(time_s)


def npy_frames(path):
    """Return the frame source of a .npy file of shape (N, 7) or (T, N, 7): frame k mod T."""
    try:
        frames = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as error:
        raise ValueError('cannot read %s as a .npy array: %s' % (path, error)) from None
    if frames.ndim == 2:
        frames = frames[None]
    if frames.ndim != 3 or frames.shape[2] != 7 or len(frames) == 0:
        raise ValueError('%s holds an array of shape %s; expected (N, 7) or (T, N, 7) with '
                         'T >= 1, rows x y z qx qy qz qw' % (path, frames.shape))
    if frames.dtype.kind not in 'fiu':
        raise ValueError('%s holds %s values; expected real numbers' % (path, frames.dtype))
    frames = frames.astype(np.float64)
    return lambda _time_s, k: frames[k % len(frames)]


def parse_arguments(argv):
    parser = argparse.ArgumentParser(
        prog='pose_publisher', description=__doc__.split('\n\n')[0],
        epilog='ROS arguments may follow --ros-args (e.g. -r dynamic_poses:=/other).')
    source = parser.add_mutually_exclusive_group()
    source.add_argument('--scene', choices=sorted(SCENES), default='room',
                        help='moving scene to publish (default: room)')
    source.add_argument('--npy', metavar='FILE', help='publish the frames of this .npy file')
    parser.add_argument('--bodies', type=int, metavar='N',
                        help='body count of the scene (default: %s, else %d)'
                        % (', '.join('%d for %s' % (count, name) for name, count
                                     in SCENE_BODY_COUNTS.items()), DEFAULT_BODIES))
    parser.add_argument('--seed', type=int, default=0, help='scene seed (default: 0)')
    parser.add_argument('--rate', type=float, default=30.0, metavar='HZ',
                        help='messages per second (default: 30)')
    parser.add_argument('--frame-id', default='world',
                        help="header.frame_id, as the node's frame_id (default: world)")
    parser.add_argument('--count', type=int, metavar='K',
                        help='stop after K messages, all kept for transient-local '
                        'subscribers (default: run until Ctrl-C)')
    parser.add_argument('--wait-for-subscriber', action='store_true',
                        help='publish only while someone subscribes, so none is lost')
    options = parser.parse_args(argv)
    if not options.rate > 0.0:
        parser.error('--rate must be positive, got %s' % options.rate)
    if options.count is not None and options.count < 1:
        parser.error('--count must be at least 1, got %d' % options.count)
    if options.bodies is not None and options.bodies < 0:
        parser.error('--bodies must not be negative, got %d' % options.bodies)
    if options.npy is not None and options.bodies is not None:
        parser.error('--bodies applies to a scene; the .npy file fixes its own body count')
    return options, parser


def main(args=None):
    options, parser = parse_arguments(remove_ros_args(args)[1:])
    try:
        if options.npy is not None:
            frames = npy_frames(options.npy)
        else:
            bodies = scene_body_count(options.scene, options.bodies, DEFAULT_BODIES)
            frames = scene_frames(options.scene, bodies, options.seed)
    except ValueError as error:
        parser.error(str(error))

    spin_until_finished(args, lambda: PosePublisher(frames, options.rate, options.frame_id,
                                                    options.count, options.wait_for_subscriber))


if __name__ == '__main__':
    sys.exit(main())
