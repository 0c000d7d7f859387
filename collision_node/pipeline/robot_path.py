"""The robot path: a robot's joint values in, its contacts out, states and trajectories.

The World's robot methods live here (World keeps thin delegations): ``set_robot`` makes the
robot's boxes the dynamic bodies (robot_bodies.RobotBodies) and its self-collision pairs join
the World's ignored pairs; ``check_joints`` runs forward kinematics and the one pass in one
compiled call per chunk of states (robot_bodies.check_joint_states) through the batches of
one_pass.py, or the robot's box poses through ``check_states`` when the scene is too large
for one pass; ``check_trajectory`` checks the segments between waypoints
(robot_bodies.first_uncleared_pieces). The pairs a trajectory's segments test are kept per
version of the scene rows and robot (scene_rows.py), as every path keys what it keeps.
"""
import time

import numpy as np

from collision_node.pipeline.contacts import DYNAMIC, STATIC
from collision_node.pipeline.robot_bodies import (check_joint_states, DEFAULT_RESOLUTION,
                                                  first_uncleared_pieces, segment_contacts)
from collision_node.pipeline.small_scene import ID as STATICS_ID, ROW as STATICS_ROW
from collision_node.pipeline.stats import one_pass_stats, Result


class RobotPath:
    """A robot at a base pose, checked against the scene rows (module docstring)."""

    def __init__(self, scene, batches):
        """Read ``scene`` (scene_rows.SceneRows); check states with ``batches`` (one_pass.py)."""
        self._scene = scene
        self._batches = batches
        self.bodies = None  # robot_bodies.RobotBodies once set_robot gave one
        self._segment_pairs = (-1, None, None)  # version, bodies, _robot_pairs of them

    def set_bodies(self, bodies):
        """Take ``bodies`` (robot_bodies.RobotBodies) as the robot; the World set its filter."""
        self.bodies = bodies

    def check_joints(self, q, one_pass_pairs):
        """Check the robot at joint values ``q`` as World.check_joints does."""
        start = time.perf_counter()
        bodies = self._robot_bodies()
        states = bodies.robot._states(q)
        count, n_static = bodies.count, self._scene.count
        if count * (count - 1) // 2 + count * n_static > one_pass_pairs:
            return self._batches.check(bodies.poses(states), bodies.robot.half_extents,
                                       one_pass_pairs)
        model, base_pose = bodies.model_fields, bodies.base_pose
        contacts, counters = self._batches.in_one_pass(
            len(states), count,
            lambda *scene: check_joint_states(model, base_pose, states, *scene))
        contacts.flags.writeable = False
        return Result(contacts, one_pass_stats(count, n_static, counters,
                                               1e3 * (time.perf_counter() - start),
                                               len(states)))

    def robot_poses(self, q):
        """Return the robot's box poses at joint values ``q``: (K, B, 7), the World's frame."""
        return self._robot_bodies().poses(q)

    def check_trajectory(self, world, waypoints, resolution=DEFAULT_RESOLUTION):
        """Check a joint-space path as World.check_trajectory does (``world`` checks joints)."""
        bodies = self._robot_bodies()
        waypoints = bodies.robot._states(waypoints)
        # The forward kinematics of the waypoints once, for their exact check and for the
        # segments' ends (check_joints is check_states on these poses, bit for bit).
        poses = bodies.poses(waypoints)
        exact = world.check_states(poses, bodies.robot.half_extents).contacts
        if len(waypoints) < 2:
            return Result(exact, {})
        version, pairs_of, arguments = self._segment_pairs
        if version != self._scene.version or pairs_of is not bodies:  # kept while unchanged
            arguments = self._robot_pairs(bodies)
            self._segment_pairs = (self._scene.version, bodies, arguments)
        pairs, keys, radii, margins, boxes = arguments
        found = first_uncleared_pieces(bodies.model_fields, bodies.base_pose, waypoints, poses,
                                       pairs, radii, margins, boxes, max(resolution, 1e-12))
        return Result(segment_contacts(world, bodies, waypoints, exact, found, keys), {})

    def _robot_bodies(self):
        if self.bodies is None:
            raise ValueError('no robot: call set_robot(robot) first')
        return self.bodies

    def _robot_pairs(self, bodies):
        """Return the robot's pairs the filters let through, for the segment check.

        (pairs (P, 2) rows of the boxes below, keys (P, 3) id_a, type_b, id_b, their motion
        radii (P, dof), margins (P,), boxes (centers, rotations, half extents): B rows for
        the robot, then the static rows).
        """
        scene = self._scene
        count, statics = bodies.count, scene.rows.by_id
        checked = scene.filter_table(count)
        a, j = np.nonzero(np.triu(checked, 1))  # the pass's order: a, then its b's
        static = j >= count
        rows, types, ids = j.copy(), np.full(len(j), DYNAMIC, np.int64), j.copy()
        rows[static] = count + statics[j[static] - count, STATICS_ROW]
        ids[static] = statics[j[static] - count, STATICS_ID]
        types[static] = STATIC
        margins = np.full(len(j), scene.options.margin)
        if scene.rows.own_margins:
            margins[static] += scene.boxes.margins[rows[static] - count]
        n_static = scene.count
        boxes = tuple(np.concatenate([np.zeros((count,) + part.shape[1:]), part[:n_static]])
                      for part in (scene.boxes.centers, scene.boxes.rotations,
                                   scene.boxes.half_extents))
        radii = bodies.robot.pair_motion_radii(a, np.where(static, -1, j))
        return (np.column_stack([a, rows]), np.column_stack([a, types, ids]), radii, margins,
                boxes)
