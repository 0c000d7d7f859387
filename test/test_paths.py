"""Random sequences of scene verbs, settings and checks: every path answers as a fresh World.

Each path keeps caches keyed on the scene rows' versions and its own inputs (world.py), so
no change has to remember to drop one. Here one World goes through random verbs, settings,
steps of one-pass and general-path size and batches of states, with ``validate()`` after
each; every answer is compared, to the bit, with a World built afresh from its description
(no history: nothing cached).
"""
from broadphase_reference import random_quaternions
import numpy as np
import pytest

from collision_node import World
from collision_node.pipeline.contacts import DYNAMIC, STATIC

SIDE = 4.0  # m: the scenes' cube, dense enough for contacts at every size
SMALL, LARGE = 6, 190  # bodies: a one-pass step, and one past ONE_PASS_PAIRS (17,955 pairs)


def poses(rng, count):
    return np.concatenate([rng.uniform(0.0, SIDE, (count, 3)), random_quaternions(rng, count)],
                          1)


def same(contacts, expected):
    """Whether two contact arrays are equal to the bit, field by field (not their padding)."""
    return contacts.dtype == expected.dtype and all(
        contacts[name].tobytes() == expected[name].tobytes() for name in contacts.dtype.names)


class Run:
    """One World, its scene as given, and what its steps were given."""

    def __init__(self, seed):
        self.rng = np.random.default_rng(seed)
        self.world = World(broad_phase='brute_force')
        self.ids = list(range(0, 120, 2))
        self.world.set_static(poses(self.rng, len(self.ids)),
                              self.rng.uniform(0.05, 0.3, (len(self.ids), 3)), ids=self.ids)
        self.previous = None  # the last accepted input (a continuous step's motion start)
        self.inputs = {}      # per body count: the last poses given, moved a little each time

    def verb(self):
        """Apply a random scene verb or setting."""
        rng, world = self.rng, self.world
        some = [int(i) for i in rng.choice(self.ids, min(5, len(self.ids)), replace=False)]
        choice = rng.integers(10)
        if choice == 0:
            new = [max(self.ids) + 1 + k for k in range(3)]
            world.add_static(new, poses(rng, 3), rng.uniform(0.05, 0.3, (3, 3)),
                             margins=float(rng.choice([0.0, 0.02])))
            self.ids += new
        elif choice in (1, 2, 3):  # the most common change: colliders move a little or far
            moved = world.static_colliders.poses[np.searchsorted(world.static_colliders.ids,
                                                                 some)]
            moved[:, :3] += rng.normal(0.0, rng.choice([0.01, 1.0]), (len(some), 3))
            world.move_static(some, moved)
        elif choice == 4 and len(self.ids) > 20:
            world.remove_static(some)
            self.ids = [i for i in self.ids if i not in some]
        elif choice == 5:
            world.enable_static(some, bool(rng.integers(2)))
        elif choice == 6:
            world.update_static(some, margins=float(rng.choice([0.0, 0.03])),
                                masks=int(rng.choice([-1, 1])))
        elif choice == 7:
            world.set_filters(categories=int(rng.choice([1, 3])), ignored_pairs=[
                (0, DYNAMIC, 1, DYNAMIC), (2, DYNAMIC, some[0], STATIC)])
        elif choice == 8:
            setting = rng.integers(4)
            if setting == 0:
                world.margin = float(rng.choice([0.0, 0.04]))
            elif setting == 1:
                world.sphere_prefilter = not world.sphere_prefilter
            elif setting == 2:
                world.continuous = not world.continuous
            else:
                world.configure(broad_phase=str(rng.choice(['brute_force', 'auto', 'grid',
                                                           'sweep_and_prune', 'octree'])))
        else:
            world.set_static(poses(rng, 50), rng.uniform(0.05, 0.3, (50, 3)),
                             ids=np.arange(50) * 2)
            self.ids = list(range(0, 100, 2))

    def step_input(self, count):
        """Return the next input of ``count`` bodies: some moved, the others kept, or the same."""
        rng = self.rng
        given = self.inputs.get(count)
        if given is None or rng.random() < 0.1:
            given = poses(rng, count)
        elif rng.random() < 0.8:  # else the same input again
            given = given.copy()
            moving = rng.random(count) < 0.5
            given[moving, :3] += rng.normal(0.0, 0.05, (int(moving.sum()), 3))
        self.inputs[count] = given
        return given

    def fresh(self):
        return World.from_description(self.world.describe())


def check_step(run, count):
    given = run.step_input(count)
    extents = np.full((count, 3), 0.2)
    result = run.world.step(given, extents)
    fresh = run.fresh()
    if run.world.continuous and run.previous is not None:
        fresh.step(run.previous, np.full((len(run.previous), 3), 0.2))
    expected = fresh.step(given, extents)
    assert same(result.contacts, expected.contacts)
    run.previous = given.copy()


def check_batch(run, count):
    states = np.stack([poses(run.rng, count) for _ in range(3)])
    result = run.world.check_states(states, [0.2, 0.2, 0.2])
    expected = run.fresh().check_states(states, [0.2, 0.2, 0.2])
    assert same(result.contacts, expected.contacts)


@pytest.mark.parametrize('seed', range(1, 7))
def test_random_verbs_settings_and_checks_answer_as_a_fresh_world(seed):
    run = Run(seed)
    paths = {'small': 0, 'large': 0, 'batch': 0}
    for _ in range(100):
        what = run.rng.integers(6)
        if what < 2:
            run.verb()
        elif what < 4:
            check_step(run, SMALL)
            paths['small'] += 1
        elif what == 4:
            check_step(run, LARGE)
            paths['large'] += 1
        else:
            check_batch(run, int(run.rng.choice([SMALL, LARGE])))
            paths['batch'] += 1
        run.world.validate()
    assert min(paths.values()) > 5, paths  # each path ran, between changes of every kind


def test_a_robot_between_verbs_and_steps_answers_as_a_fresh_world():
    from collision_node.pipeline.robot import Robot
    from collision_node.pipeline.warm_up import WARM_UP_ROBOT
    robot = Robot.from_urdf(WARM_UP_ROBOT)
    run = Run(7)
    run.world.set_robot(robot, [1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0])
    for _ in range(40):
        what = run.rng.integers(4)
        if what == 0:
            run.verb()
        q = run.rng.uniform(-2.0, 2.0, (3, robot.dof))
        if what == 1:
            result = run.world.check_joints(q)
            assert same(result.contacts, run.fresh().check_joints(q).contacts)
        elif what == 2:
            poses = run.world.robot_poses(q[0])[0]
            result = run.world.step(poses, robot.half_extents)
            fresh = run.fresh()
            if run.world.continuous and run.previous is not None:
                fresh.step(run.previous, robot.half_extents)
            assert same(result.contacts, fresh.step(poses, robot.half_extents).contacts)
            run.previous = poses
        elif what == 3:
            result = run.world.check_trajectory(q)
            assert same(result.contacts, run.fresh().check_trajectory(q).contacts)
        run.world.validate()
