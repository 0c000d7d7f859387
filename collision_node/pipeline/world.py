"""The collision pipeline without ROS: boxes in, sorted contacts out.

    world = World(broad_phase='auto', sphere_prefilter=True)
    world.set_static(static_poses, static_half_extents)        # (S, 7), (S, 3); ids 0..S-1
    result = world.step(dynamic_poses, dynamic_half_extents)   # (D, 7), (D, 3) or (3,)
    world.move_static(ids, static_poses)                       # colliders by their ids

The World is a coordinator: it holds the settings and the static scene, and hands each check
to a path that lives elsewhere, as MoveIt's FCL, Bullet and AllValid implement one
``CollisionEnv``. Every path answers with contacts and one statistics record (stats.py); an
answer is the same to the bit whichever path gives it.

- static_scene.py: the colliders by stable id, changed only through the verbs ``set_static``,
  ``add_static``, ``move_static``, ``remove_static``, ``enable_static``, ``update_static``
  (each checks its whole input first and changes nothing when it raises ValueError).
- scene_rows.py: what the World derives from the scene and its settings at a version (the
  static rows, their ids, bits and margins, the options). The World writes it, paths read it.
- steps.py: which path checks a step, and the last accepted input: general_path.py (a broad
  phase over static and dynamic rows, the still-body cache, the loose statics and the
  continuous sweeps; any size of scene) or one_pass.py (a small scene in one compiled call,
  discrete, with ``ONE_PASS_PHASES``).
- one_pass.py's batches: ``check_states``. robot_path.py: joint values in, trajectories.

How a change reaches every path: a verb or a setter changes the scene rows, which draw a new
version (a setting becomes new ``Options`` there). Each path keys what it keeps on those
versions and its own inputs, and meets the change on its next call: no path drops another's
cache. A continuous step's motion starts at the last accepted input, whichever path took it.
"""
from typing import NamedTuple

import numpy as np

from collision_node.pipeline.broadphase import make_broad_phase, Settings
from collision_node.pipeline.contacts import CONTACT_DTYPE, DYNAMIC, STATIC  # noqa: F401
from collision_node.pipeline.continuous import CONTINUOUS_TOLERANCE
from collision_node.pipeline.filters import ALL_CATEGORIES, DEFAULT_CATEGORY, PairFilter
from collision_node.pipeline.obb import check_margin, check_tolerance
from collision_node.pipeline.one_pass import Batches
from collision_node.pipeline.robot_bodies import DEFAULT_RESOLUTION, RobotBodies
from collision_node.pipeline.robot_path import RobotPath
from collision_node.pipeline.scene_rows import Options, SceneRows
from collision_node.pipeline.static_scene import StaticScene
from collision_node.pipeline.stats import Result  # noqa: F401 (re-exported)
from collision_node.pipeline.steps import ONE_PASS_PAIRS, ONE_PASS_PHASES, Steps  # noqa: F401
from collision_node.pipeline.workers import Workers


class Description(NamedTuple):
    """What builds a World again elsewhere (another process): plain, picklable values.

    A World from_description answers as the described one, bit for bit (its first step has no
    last input to sweep from or reuse).
    """

    settings: dict     # the constructor's keyword arguments
    colliders: tuple   # static_scene.Colliders, every collider in slot order, enabled or not
    filters: tuple     # set_filters' (categories, masks, ignored_pairs) as given
    robot: object      # the Robot of set_robot, or None
    base_pose: object  # its base pose (7,), or None


class World:
    """Static and dynamic oriented boxes, and the paths that check them (module docstring)."""

    def __init__(self, broad_phase='auto', sphere_prefilter=True, octree_max_depth=0,
                 octree_leaf_cooldown_ticks=15, threads=1, margin=0.0, continuous=False,
                 continuous_tolerance=CONTINUOUS_TOLERANCE):
        """Raise ValueError on an unknown broad phase or an invalid setting."""
        self._workers = Workers(threads)
        settings = Settings(octree_max_depth, octree_leaf_cooldown_ticks)
        self._scene = StaticScene()
        self._rows = SceneRows(Options(
            broad_phase, settings, check_margin(margin), bool(sphere_prefilter),
            bool(continuous), check_tolerance(continuous_tolerance)), self._workers)
        self._rows.derive(self._scene.colliders)
        self._filters_given = (DEFAULT_CATEGORY, ALL_CATEGORIES, np.zeros((0, 4), np.int64))
        self._steps = Steps(self._rows)  # raises ValueError on an unknown phase
        self._batches = Batches(self._rows)
        self._robot = RobotPath(self._rows, self._batches)

    @property
    def broad_phase(self):
        return self._rows.options.broad_phase

    @property
    def sphere_prefilter(self):
        return self._rows.options.sphere_prefilter

    @sphere_prefilter.setter
    def sphere_prefilter(self, value):
        self._set_options(sphere_prefilter=bool(value))

    @property
    def margin(self):
        """Pairs whose boxes are at most this far apart (m, exact distance) are reported."""
        return self._rows.options.margin

    @margin.setter
    def margin(self, value):
        self._set_options(margin=check_margin(value))

    @property
    def has_margins(self):
        """Whether any pair has a margin: :attr:`margin`, or a collider's own."""
        return self._rows.has_margins

    @property
    def continuous(self):
        """Whether pairs are checked over the motion since the last input (continuous.py)."""
        return self._rows.options.continuous

    @continuous.setter
    def continuous(self, value):
        self._set_options(continuous=bool(value))

    @property
    def continuous_tolerance(self):
        """Metres: a continuous pair's boxes are within margin + this at its ``toi``."""
        return self._rows.options.tolerance

    @continuous_tolerance.setter
    def continuous_tolerance(self, value):
        self._set_options(tolerance=check_tolerance(value))

    def configure(self, broad_phase=None, octree_max_depth=None,
                  octree_leaf_cooldown_ticks=None):
        """Change the broad phase or its settings; raises ValueError on invalid values."""
        options = self._rows.options
        given = {'octree_max_depth': octree_max_depth,
                 'octree_leaf_cooldown_ticks': octree_leaf_cooldown_ticks}
        settings = options.phase_settings._replace(**{
            key: value for key, value in given.items() if value is not None})
        name = options.broad_phase if broad_phase is None else broad_phase
        make_broad_phase(name, settings)  # checks the name and settings
        self._set_options(broad_phase=name, phase_settings=settings)

    def set_filters(self, categories=DEFAULT_CATEGORY, masks=ALL_CATEGORIES, ignored_pairs=()):
        """Set the dynamic bodies' collision bits and the pairs never to check.

        ``categories`` and ``masks``: one integer for every dynamic body, or one per body in
        input order; ``ignored_pairs``: rows ``(id_a, type_a, id_b, type_b)`` as in the cloud.
        A pair is checked only if ``category_a & mask_b`` and ``category_b & mask_a`` are both
        non-zero and it is not ignored (filters.py). Raises ValueError on invalid values.
        """
        given = (categories, masks, np.asarray(ignored_pairs, np.int64).reshape(-1, 4))
        self._set_filter(given, self._robot.bodies)
        self._filters_given = given

    def _set_filter(self, given, robot):
        """Filter with the ``given`` settings plus the ``robot``'s self-collision pairs."""
        categories, masks, ignored_pairs = given
        if robot is not None:
            ignored_pairs = np.concatenate([ignored_pairs, robot.ignored_pairs])
        self._rows.set_filter(PairFilter(categories, masks, ignored_pairs))

    def _set_options(self, **changes):
        """Take the ``changes`` to the options (checked): the paths meet them next call."""
        options = self._rows.options._replace(**changes)
        if options != self._rows.options:
            self._rows.set_options(options, self._scene.colliders)

    def set_robot(self, robot, base_pose=None):
        """Make the boxes of ``robot`` (a Robot) the dynamic bodies, its root at ``base_pose``.

        Body i is box i (``robot.box_links[i]`` its link). The robot's self-collision filter
        joins the filters of :meth:`set_filters`; ``base_pose`` (x y z qx qy qz qw, default
        the identity) may change at any time with another call. Raises ValueError on a bad
        base pose, and then nothing changes.
        """
        bodies = RobotBodies(robot, base_pose)
        self._set_filter(self._filters_given, bodies)
        self._robot.set_bodies(bodies)

    def check_joints(self, q):
        """Check the robot at joint values q (dof,) or (K, dof), as :meth:`check_states`.

        State k's contacts are those :meth:`step` gives for ``robot.box_poses(q[k])`` at the
        base pose. Raises ValueError for a q of the wrong shape or with NaN or Inf (naming
        the state and joint), or without a robot (:meth:`set_robot`).
        """
        return self._robot.check_joints(q, ONE_PASS_PAIRS)

    def robot_pass(self):
        """Return the RobotRows check_joints runs now (None: no robot, or past one pass).

        The node's joint_states lane checks with it; ask again for each input.
        """
        return self._robot.robot_pass(ONE_PASS_PAIRS)

    def robot_poses(self, q):
        """Return the robot's box poses at joint values q (dof,) or (K, dof): (K, B, 7).

        In the World's frame (the base pose applied): ``step(robot_poses(q)[0],
        robot.half_extents)`` checks one state as a tick, with what a step keeps between
        ticks (an unchanged state's answer reused, still boxes not tested again). Raises
        ValueError as :meth:`check_joints`.
        """
        return self._robot.robot_poses(q)

    def check_trajectory(self, waypoints, resolution=DEFAULT_RESOLUTION):
        """Check a joint-space path: its W waypoints exactly, the segments between them safely.

        ``waypoints`` (W, dof). The contacts of waypoint k have ``state`` k and ``toi`` 0; a
        pair that is not proven free on segment k -> k + 1 (robot_bodies.py: nothing
        between waypoints is missed; a report is a configuration within ``resolution``
        metres of the pair's contact, or margin) has ``state`` k and ``toi`` the fraction of
        the segment where that configuration lies, with the contact there if the pair
        collides there (else depth 0, a zero normal and ``distance`` NaN). Sorted by
        (state, id_a, type_b, id_b, toi).
        """
        return self._robot.check_trajectory(self, waypoints, ONE_PASS_PAIRS,
                                            check_margin(resolution, 'resolution'))

    def set_static(self, poses, half_extents, ids=None, margins=0.0,
                   categories=DEFAULT_CATEGORY, masks=ALL_CATEGORIES):
        """Replace every static collider; ``ids`` (default 0..S-1) are reported as their id_b.

        ``poses`` (S, 7), ``half_extents`` (S, 3) or (3,); ``margins`` (m, one for all or one
        per collider) are added to the World's margin for pairs with that collider;
        ``categories`` and ``masks`` (one for all or one per collider) are its collision bits.
        """
        self._scene.replace(poses, half_extents, ids, margins, categories, masks)
        self._rows.derive(self._scene.colliders)

    def add_static(self, ids, poses, half_extents, margins=0.0, categories=DEFAULT_CATEGORY,
                   masks=ALL_CATEGORIES, enabled=True):
        """Add colliders with new ``ids`` (the others as in set_static; ``enabled`` too)."""
        self._after_scene_change(self._scene.add, ids, poses, half_extents, margins,
                                 categories, masks, enabled)

    def move_static(self, ids, poses=None, half_extents=None):
        """Give colliders ``ids`` new poses (K, 7) and/or half extents (K, 3); None: unchanged.

        They take effect from the next step; a disabled collider keeps them for when it is
        enabled. Only the rows of colliders whose pose or size differs are rewritten and
        re-tested (general_path.py). Returns how many colliders changed.
        """
        slots = self._scene.move(ids, poses, half_extents)
        self._rows.move(self._scene.colliders, slots)
        return len(slots)

    def remove_static(self, ids):
        """Remove colliders ``ids``; their ids are free again."""
        self._after_scene_change(self._scene.remove, ids)

    def enable_static(self, ids, enabled):
        """Enable or disable colliders ``ids``: a disabled collider is kept but never checked."""
        self._after_scene_change(self._scene.enable, ids, enabled)

    def update_static(self, ids, margins=None, categories=None, masks=None):
        """Change the margins, categories or masks of colliders ``ids`` (None: unchanged)."""
        self._after_scene_change(self._scene.update, ids, margins, categories, masks)

    @property
    def static_count(self):
        """Return the number of static rows: the enabled colliders."""
        return self._rows.count

    @property
    def static_colliders(self):
        """Return every collider, enabled or not, as read-only arrays (static_scene.Colliders)."""
        return self._scene.colliders

    def _after_scene_change(self, verb, *arguments):
        version = self._scene.version
        verb(*arguments)
        if self._scene.version != version:
            self._rows.derive(self._scene.colliders)

    def step(self, poses, half_extents):
        """Collide the dynamic boxes (poses (D, 7), half extents (D, 3) or (3,)).

        Raises ValueError naming the first invalid dynamic body; then nothing is reported.
        An input identical to the previous one returns the previous result again; pairs of
        bodies that kept their pose and size since the previous step keep their contacts
        without a SAT. The result's contacts are read-only: later steps reuse them.
        """
        return self._steps.step(poses, half_extents)

    def pass_as_before(self, count, half_extents):
        """Return what a step of ``count`` bodies of ``half_extents`` passes check_scene, or None.

        For a caller that runs small_scene.check_scene in a kernel of its own, straight from
        its input (the node's PoseLane): the one pass's gathering (its ``arguments``, after
        the input's), while a step of that many bodies would be checked in one pass as the
        last one was. The caller then hands the check's outcome to its ``answer`` method,
        which returns the step's Result.
        """
        return self._steps.pass_as_before(count, half_extents)

    def broad_phase_pairs(self, poses, half_extents):
        """Return a discrete general step's BroadPhasePairs at these poses; changes no step."""
        return self._steps.broad_phase_pairs(poses, half_extents)

    def check_states(self, states, half_extents):
        """Check K independent states of the D dynamic bodies against the static scene.

        ``states`` (K, D, 7) poses, ``half_extents`` (D, 3) or (3,). Each state is checked as
        a step of that state alone would check it, with the filters and margins (at its poses:
        a state has no motion to sweep), and its contacts carry its index in the field
        ``state``; they are sorted by (state, id_a, type_b, id_b). No step's state is read or
        changed. Raises ValueError naming the state and body of the first invalid pose; then
        nothing is reported. Small scenes are checked in one compiled pass spread over the
        World's threads, larger ones state after state by a general path of their own.
        """
        return self._batches.check(states, half_extents, ONE_PASS_PAIRS)

    def validate(self):
        """Check the whole World (for testing): raise AssertionError naming what is wrong.

        The scene itself, the static rows derived from it (the enabled colliders, each row's
        box written from its collider's pose and size), and the general path's copy of them,
        its loose rows and its broad phase's own structure (its static part; its dynamic part
        as of its last pairs, unless rows were written since without it).
        """
        self._scene.validate()
        self._rows.validate(self._scene.colliders)
        self._steps.general.validate()

    def describe(self):
        """Return a :class:`Description` of this World: settings, colliders, filters, robot."""
        settings = dict(self._rows.options.settings(), threads=self._workers.threads)
        robot = self._robot.bodies
        return Description(settings, tuple(np.array(part) for part in self._scene.colliders),
                           self._filters_given, robot and robot.robot,
                           robot and np.array(robot.base_pose))

    @classmethod
    def from_description(cls, description, **settings):
        """Build a World from :meth:`describe`'s answer; ``settings`` override its settings."""
        world = cls(**{**description.settings, **settings})
        ids, poses, half_extents, margins, categories, masks, enabled = description.colliders
        world.add_static(ids, poses, half_extents, margins, categories, masks, enabled)
        world.set_filters(*description.filters)
        if description.robot is not None:
            world.set_robot(description.robot, description.base_pose)
        return world

    def close(self):
        """Stop the World's helper threads (none with ``threads=1``)."""
        self._workers.close()
