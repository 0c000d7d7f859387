"""collision_label: label N configurations of a robot in a scene, on Ray workers (doc/cluster.md).

    collision_label --urdf panda.urdf --srdf panda.srdf --count 1000000 --output labels.npy
    collision_label --poses states.npy --half-extents 0.1 0.1 0.1 --static 0 0 0 0 0 0 1 1 1 .1 \
        --output labels.npy

Configurations are drawn uniformly within the joint limits (``--seed``; a continuous joint
within [-pi, pi]) or read from ``--q`` (K, dof) .npy; without a robot, states of box poses
(K, D, 7) come from ``--poses``. Each label says whether the state collides and which pair is
nearest: the reported row with the smallest ``distance`` (the largest depth), pairs within
``--margin`` included. Labels go to an .npy file of LABEL_FIELDS rows (with ``q`` for a
robot) chunk by chunk as they arrive, so memory does not grow with N; the file is written as
``OUTPUT.part`` and renamed when complete. Ray is imported only here, in :func:`main`.
"""
import argparse
import math
import os
import resource
import sys
import time

import numpy as np

from collision_node.pipeline.robot import Robot
from collision_node.pipeline.world import World
from collision_node.ros.params import load_static_scene

# One row per state; id_a, type_b, id_b -1 and depth, distance NaN when nothing is reported.
LABEL_FIELDS = [('collides', np.bool_), ('id_a', np.int32), ('type_b', np.int32),
                ('id_b', np.int32), ('depth', np.float64), ('distance', np.float64)]
PROGRESS_PERIOD = 0.5  # s between two progress lines


def label_dtype(dof=None):
    """Return the labels' dtype: LABEL_FIELDS, then ``q`` (dof,) for a robot."""
    return np.dtype(LABEL_FIELDS + ([('q', np.float64, (dof,))] if dof else []))


def labels_of(contacts, first, count, dtype):
    """Return the ``count`` labels of states ``first``... from their sorted contacts."""
    labels = np.zeros(count, dtype)
    labels['id_a'] = labels['type_b'] = labels['id_b'] = -1
    labels['depth'] = labels['distance'] = np.nan
    if len(contacts):
        state = contacts['state'].astype(np.int64) - first
        # Per state, the smallest distance; the first such row in the answer's order on a tie.
        order = np.lexsort((np.arange(len(contacts)), contacts['distance'], state))
        states, at = np.unique(state[order], return_index=True)
        nearest = contacts[order[at]]
        for name in ('id_a', 'type_b', 'id_b', 'depth', 'distance'):
            labels[name][states] = nearest[name]
        labels['collides'][states] = nearest['distance'] <= 0.0
    return labels


class Progress:
    """A plain-text progress line on stderr: states done, share, states per second."""

    def __init__(self, total, stream=sys.stderr):
        self._total, self._stream = total, stream
        self._start = self._shown = time.perf_counter()
        self.done = 0

    def update(self, count):
        self.done += count
        now = time.perf_counter()
        if now - self._shown >= PROGRESS_PERIOD or self.done == self._total:
            self._shown = now
            self._stream.write('\r%s' % self.line(now))
            self._stream.flush()

    def line(self, now=None):
        elapsed = (now or time.perf_counter()) - self._start
        return '%d/%d states (%3.0f%%) | %.0f states/s | %.1f s' % (
            self.done, self._total, 100.0 * self.done / max(self._total, 1),
            self.done / max(elapsed, 1e-9), elapsed)

    def finish(self):
        self._stream.write('\r%s\n' % self.line())
        self._stream.flush()


class LabelFile:
    """An .npy file of ``count`` rows of ``dtype``, written in order as rows arrive."""

    def __init__(self, path, dtype, count):
        self.path, self._part = path, path + '.part'
        self._file = open(self._part, 'wb')
        np.lib.format.write_array_header_1_0(self._file, {
            'descr': np.lib.format.dtype_to_descr(dtype), 'fortran_order': False,
            'shape': (count,)})
        self._left = count

    def write(self, rows):
        self._file.write(rows.tobytes())
        self._left -= len(rows)

    def close(self):
        """Close; rename to the final name only when every row was written."""
        self._file.close()
        if self._left == 0:
            os.replace(self._part, self.path)
        return self._left == 0


def parse(argv):
    parser = argparse.ArgumentParser(
        prog='collision_label', description='Label configurations of a robot in a scene '
        '(collides, nearest pair) on Ray workers; labels streamed to an .npy file.')
    robot = parser.add_argument_group('robot (or --poses without one)')
    robot.add_argument('--urdf', help='URDF file')
    robot.add_argument('--srdf', help='SRDF file (its disabled collisions)')
    robot.add_argument('--package-path', action='append', default=[],
                       help='folder holding pkg/ for package://pkg/ meshes (repeatable)')
    robot.add_argument('--base-pose', type=float, nargs=7, metavar='V',
                       help='the root link pose x y z qx qy qz qw (default identity)')
    robot.add_argument('--count', type=int, default=10_000,
                       help='configurations drawn uniformly within the joint limits')
    robot.add_argument('--seed', type=int, default=0, help='of the drawn configurations')
    robot.add_argument('--q', help='.npy (K, dof) of configurations instead of drawing them')
    robot.add_argument('--poses', help='without a robot: .npy (K, D, 7) states of box poses')
    robot.add_argument('--half-extents', type=float, nargs=3, metavar='H',
                       help="with --poses: every box's half extents (m)")
    scene = parser.add_argument_group('scene')
    scene.add_argument('--scene-file', help=".npz of static colliders, as the node's "
                       'static_scene_file (doc/parameters.md)')
    scene.add_argument('--static', type=float, nargs=10, action='append', default=[],
                       metavar='V', help='a static box: x y z qx qy qz qw hx hy hz '
                       "(repeatable; ids after the scene file's)")
    scene.add_argument('--margin', type=float, default=0.0,
                       help='m: pairs this close are reported with their distance')
    scene.add_argument('--broad-phase', default='auto')
    run = parser.add_argument_group('run')
    run.add_argument('--output', required=True, help='the labels .npy file')
    run.add_argument('--address', help="a running Ray cluster ('auto': ray start's on this "
                     'machine); default: a local Ray')
    run.add_argument('--workers', type=int, default=2)
    run.add_argument('--chunk', type=int, default=None, help='states a call to a worker')
    run.add_argument('--quiet', action='store_true', help='no progress line')
    args = parser.parse_args(argv)
    if args.urdf is None and args.poses is None:
        parser.error('give a robot (--urdf) or box poses (--poses with --half-extents)')
    if args.urdf is not None and args.poses is not None:
        parser.error('--poses is for scenes without a robot; give --urdf or --poses')
    if args.poses is not None and args.half_extents is None:
        parser.error('--poses needs --half-extents')
    return args


def make_world(args):
    """Return the World of the arguments: its margin, broad phase, colliders and robot."""
    world = World(broad_phase=args.broad_phase, margin=args.margin)
    parts = []
    if args.scene_file:
        parts.append(load_static_scene(args.scene_file))
    if args.static:
        boxes = np.array(args.static)
        count = sum(len(part.ids) for part in parts)
        parts.append((np.arange(count, count + len(boxes)), boxes[:, :7], boxes[:, 7:],
                      np.zeros(len(boxes)), np.ones(len(boxes), np.int64),
                      np.full(len(boxes), -1, np.int64), np.ones(len(boxes), np.bool_)))
    for ids, poses, half_extents, margins, categories, masks, enabled in parts:
        world.add_static(ids, poses, half_extents, margins, categories, masks, enabled)
    if args.urdf is not None:
        world.set_robot(Robot.from_urdf(args.urdf, args.srdf, args.package_path),
                        args.base_pose)
    return world


def robot_blocks(robot, args, size):
    """Return (count, blocks of q): drawn within the limits, or read from --q."""
    if args.q is not None:
        q = np.load(args.q, mmap_mode='r')
        return len(q), (np.array(q[first:first + size]) for first in range(0, len(q), size))
    if args.count < 0:
        raise ValueError('--count must be at least 0, got %d' % args.count)
    limits = np.array(robot.joint_limits)
    infinite = ~np.isfinite(limits)
    limits[infinite] = np.where(limits < 0, -math.pi, math.pi)[infinite]
    rng = np.random.default_rng(args.seed)
    # One draw of (count, dof) in blocks: the same numbers as one call would give.
    shapes = ((min(size, args.count - first), robot.dof) for first in range(0, args.count, size))
    return args.count, (rng.uniform(limits[:, 0], limits[:, 1], shape) for shape in shapes)


def main(argv=None):
    args = parse(argv)
    try:
        from collision_node.cluster import ClusterChecker, ClusterError, DEFAULT_CHUNK
    except ImportError as error:
        print('collision_label: %s' % error, file=sys.stderr)
        return 2
    chunk = args.chunk or DEFAULT_CHUNK
    try:
        world = make_world(args)
        robot = world.describe().robot
        if robot is not None:
            count, blocks = robot_blocks(robot, args, chunk)
            dtype = label_dtype(robot.dof)
        else:
            poses = np.load(args.poses, mmap_mode='r')
            count, dtype = len(poses), label_dtype()
            blocks = (np.array(poses[first:first + chunk]) for first in range(0, count, chunk))
        checker = ClusterChecker(world, workers=args.workers, chunk=chunk, address=args.address)
    except (ValueError, OSError) as error:
        print('collision_label: error: %s' % error, file=sys.stderr)
        return 2
    output = LabelFile(args.output, dtype, count)
    progress = Progress(count, open(os.devnull, 'w') if args.quiet else sys.stderr)
    try:
        if robot is not None:
            kept = []  # the q of each block, until its labels are written

            def remembered():
                for block in blocks:
                    kept.append(block)
                    yield block
            answers = checker.stream_joints(remembered())
        else:
            answers = checker.stream_states(blocks, args.half_extents)
        offset = 0  # the first state of kept[0]
        colliding = 0
        for first, length, contacts in answers:
            labels = labels_of(contacts, first, length, dtype)
            if robot is not None:
                while offset + len(kept[0]) <= first:
                    offset += len(kept.pop(0))
                labels['q'] = kept[0][first - offset:first - offset + length]
            output.write(labels)
            colliding += int(labels['collides'].sum())
            progress.update(length)
    except (ValueError, ClusterError) as error:
        print('\ncollision_label: error: %s' % error, file=sys.stderr)
        return 2
    finally:
        complete = output.close()
        checker.close()
    progress.finish()
    # ru_maxrss: KiB on Linux. This process only: Ray's own processes and the workers apart.
    print('%d labels (%d colliding) written to %s; peak memory of this process %.0f MB' % (
        count, colliding, args.output,
        resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024))
    return 0 if complete else 1


if __name__ == '__main__':
    sys.exit(main())
