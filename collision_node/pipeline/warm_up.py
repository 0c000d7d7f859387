"""Compile every kernel a tick can run, before the first tick.

numba compiles a kernel (or loads it from its cache) on its first call with each type
signature. The node calls :func:`warm_up` before it subscribes, the benchmarks before they
time: it runs every broad phase and every mode of the World (still bodies, margins, filters,
continuous checks, moving colliders, threads) on a small random scene of its own.
"""
import itertools

import numpy as np

from collision_node.pipeline.broadphase import NAMES
from collision_node.pipeline.broadphase.auto import GRID_BODIES
from collision_node.pipeline.contacts import (assemble_contacts, DYNAMIC, MIN_PAIRS_PER_THREAD,
                                              orient_pairs, STATIC)
from collision_node.pipeline.robot import Robot
from collision_node.pipeline.sat import COLLIDING, empty_output
from collision_node.pipeline.workers import Workers
from collision_node.pipeline.world import ONE_PASS_PAIRS, ONE_PASS_PHASES, World

WARM_UP_BODIES = 64  # half static: enough for every broad phase to run its full code path
AUTO_SPREAD_BODIES = 2 * GRID_BODIES  # auto measures the boxes' spread from this many bodies
# Half static, half dynamic (n/2 · (n/2 - 1) / 2 + n²/4 pairs): past ONE_PASS_PAIRS.
ONE_PASS_BODIES = 2 * int(np.sqrt(4.0 * ONE_PASS_PAIRS / 3.0)) + 8
# A robot with one joint of each kind the forward kinematics branches on (fixed, revolute,
# prismatic) and a box on each link: its kernels compile for any robot (same types).
WARM_UP_ROBOT = """<robot name="warm_up">
  <link name="base"><collision><geometry><box size="0.2 0.2 0.1"/></geometry></collision></link>
  <link name="arm"><collision><geometry><cylinder radius="0.05" length="0.4"/></geometry>
    </collision></link>
  <link name="tool"><collision><geometry><sphere radius="0.05"/></geometry></collision></link>
  <link name="tip"/>
  <joint name="turn" type="revolute"><parent link="base"/><child link="arm"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3"/></joint>
  <joint name="slide" type="prismatic"><parent link="arm"/><child link="tool"/>
    <origin xyz="0 0 0.4"/><axis xyz="0 0 1"/><limit lower="0" upper="0.1"/></joint>
  <joint name="end" type="fixed"><parent link="tool"/><child link="tip"/></joint>
</robot>"""


class _Scene:
    """``n`` random boxes in a cube, half static; the others drift and turn with time."""

    def __init__(self, n, seed=1):
        rng = np.random.default_rng(seed)
        side = 0.62 * n ** (1.0 / 3.0)  # about one contact per body, as scenes.uniform
        quaternions = rng.normal(size=(n, 4))
        quaternions /= np.linalg.norm(quaternions, axis=1, keepdims=True)
        poses = np.concatenate([rng.uniform(0.0, side, (n, 3)), quaternions], axis=1)
        extents = rng.uniform(0.1, 0.3, (n, 3))
        half = n // 2
        self.static_poses, self.static_half_extents = poses[:half], extents[:half]
        self._start, self.dynamic_half_extents = poses[half:], extents[half:]
        self._velocity = rng.uniform(-0.5, 0.5, (n - half, 3))

    def dynamic_poses(self, time_s):
        """Return the dynamic poses ``time_s`` seconds after the start."""
        poses = self._start.copy()
        poses[:, :3] += self._velocity * time_s
        # A turn about z by time_s rad, composed with each start orientation.
        turn = np.array([0.0, 0.0, np.sin(0.5 * time_s), np.cos(0.5 * time_s)])
        x, y, z, w = poses[:, 3:].T
        tz, tw = turn[2], turn[3]
        poses[:, 3:] = np.stack([tw * x - tz * y, tw * y + tz * x, tw * z + tz * w,
                                 tw * w - tz * z], axis=1)
        return poses

    def half_moved(self, time_s):
        """Return the poses at ``time_s``, every other body still where it was at 0 s."""
        poses = self.dynamic_poses(time_s)
        poses[::2] = self.dynamic_poses(0.0)[::2]
        return poses


def warm_up():
    """Run every broad phase and mode on a small scene, so that no later tick compiles."""
    scene = _Scene(WARM_UP_BODIES)
    extents = scene.dynamic_half_extents
    for name in NAMES:
        for statics in (True, False):
            world = World(broad_phase=name)
            if statics:
                world.set_static(scene.static_poses, scene.static_half_extents)
            for sphere_prefilter in (True, False):
                world.sphere_prefilter = sphere_prefilter
                # Bodies move between steps so that update paths (bodies leaving their cell or
                # leaf) run too, and half of them only, so that still bodies keep their
                # contacts; one size per body, then one size for all, one body, none.
                world.step(scene.dynamic_poses(0.0), extents)
                world.step(scene.half_moved(0.5), extents)
                world.step(scene.dynamic_poses(1.0), extents[0])
                world.step(scene.half_moved(1.0), extents[0])
                world.step(scene.dynamic_poses(1.5)[:1], extents[0])
                world.step(np.zeros((0, 7)), extents[0])
    # Brute force and auto past the one-pass pairs (their general path), and auto measuring
    # the boxes' spread (from AUTO_SPREAD_BODIES bodies on).
    for bodies, names in ((ONE_PASS_BODIES, ONE_PASS_PHASES), (AUTO_SPREAD_BODIES, ('auto',))):
        large = _Scene(bodies)
        for name in names:
            world = World(broad_phase=name)
            world.set_static(large.static_poses, large.static_half_extents)
            world.step(large.dynamic_poses(0.0), large.dynamic_half_extents)
            world.step(large.half_moved(0.5), large.dynamic_half_extents)
    # Margins (padded bounds, exact distances), the World's alone, then with the colliders'
    # own, and filters (masks per body, ignored pairs): in one pass and past it.
    for margins in (scene, _Scene(ONE_PASS_BODIES)):
        sizes = margins.dynamic_half_extents
        world = World(broad_phase='brute_force', margin=0.1)
        world.set_static(margins.static_poses, margins.static_half_extents)
        world.step(margins.dynamic_poses(0.0), sizes)
        world = World(broad_phase='brute_force', margin=0.1)
        world.set_static(margins.static_poses, margins.static_half_extents, margins=0.05,
                         masks=3)
        world.set_filters(categories=np.arange(len(sizes)) % 2 + 1,
                          ignored_pairs=[(0, DYNAMIC, 1, DYNAMIC), (0, DYNAMIC, 0, STATIC)])
        world.step(margins.dynamic_poses(0.0), sizes)
        world.step(margins.half_moved(0.5), sizes)
    # The one pass and batches of states in every combination of margins (the World's, the
    # colliders' own) and filters: each is a compiled variant of its own.
    states = np.array([scene.dynamic_poses(t) for t in (0.0, 0.5)])
    for margin, own, filters in itertools.product((0.0, 0.1), (0.0, 0.05), (False, True)):
        world = World(broad_phase='brute_force', margin=margin)
        world.set_static(scene.static_poses, scene.static_half_extents, margins=own)
        if filters:
            world.set_filters(ignored_pairs=[(0, DYNAMIC, 1, DYNAMIC)])
        for sizes in (extents, extents[0]):
            world.step(states[0], sizes)
            world.check_states(states, sizes)
    # Continuous checking (swept bounds, advancement, pairs touching only in between), with
    # and without margins: a bullet through a wall besides the scene.
    bullet = np.array([[0.0, 0.0, -2.0, 0.0, 0.0, 0.0, 1.0]])
    poses = [np.concatenate([scene.dynamic_poses(t), bullet + [[0.0, 0.0, 4.0 * t] + [0.0] * 4]])
             for t in (0.0, 0.5, 1.0)]
    for margin in (0.0, 0.1):
        world = World(broad_phase='brute_force', margin=margin, continuous=True)
        world.set_static(np.concatenate([scene.static_poses, [[0.0] * 6 + [1.0]]]),
                         np.concatenate([scene.static_half_extents, [[1.0, 1.0, 0.01]]]),
                         margins=margin)
        for step_poses in poses:
            world.step(step_poses, [0.05, 0.05, 0.05])
    # Candidate pairs sorted by row, which only scenes of SORT_PAIRS_ROWS boxes are.
    pairs = np.array([[0, 1]])
    orient_pairs(pairs, 0, np.arange(2), np.zeros(3, np.int64), pairs.copy())
    # Contacts listed by ranges of bodies for threads (discrete and swept ticks alike), which
    # only ticks of MIN_PAIRS_PER_THREAD candidate pairs a thread are: two bodies against one
    # static box, many times over.
    pairs = np.tile([[1, 0], [2, 0]], (MIN_PAIRS_PER_THREAD, 1))
    status, depth, normal, point = empty_output(len(pairs))
    status[:] = COLLIDING
    depth[:] = normal[:] = point[:] = 0.0
    workers = Workers(2)
    assemble_contacts(pairs, status, depth, normal, point, 1, 2, np.zeros(1, np.int64),
                      np.arange(2), workers=workers)
    workers.close()
    # Colliders that moved under still bodies: a little (kept in every phase's structure),
    # then far (loose in the grid and the octree: paired by the World itself).
    ids = np.arange(len(scene.static_poses))
    for name in NAMES:
        world = World(broad_phase=name)
        world.set_static(scene.static_poses, scene.static_half_extents)
        world.step(scene.dynamic_poses(0.0), extents)
        moved = scene.static_poses.copy()
        for shift in (1e-3, 2.0):
            moved[:2, 0] += shift
            world.move_static(ids, moved)
            world.step(scene.half_moved(0.5), extents)
    # The robot model's forward kinematics: one state, a batch, the link frames; then the
    # robot in a World: joint states and trajectories with and without margins, a robot
    # with pairs to leave out (a filter table) and one with none (no table).
    robot = Robot.from_urdf(WARM_UP_ROBOT)
    robot.box_poses(np.zeros(robot.dof))
    robot.box_poses(np.zeros((2, robot.dof)))
    robot.link_poses(np.zeros(robot.dof))
    lone_box = Robot.from_urdf(WARM_UP_ROBOT.split('<link name="arm">')[0] + '</robot>')
    for margin, own, arm in itertools.product((0.0, 0.1), (0.0, 0.05), (robot, lone_box)):
        world = World(margin=margin)
        world.set_static(scene.static_poses, scene.static_half_extents, margins=own)
        world.set_robot(arm)
        world.check_joints(np.zeros(arm.dof))
        world.step(world.robot_poses(np.zeros(arm.dof)), arm.half_extents)  # joint_states
        world.check_trajectory(np.linspace(0.0, 0.1, 2 * arm.dof).reshape(2, arm.dof))
