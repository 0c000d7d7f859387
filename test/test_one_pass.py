"""The one-pass path of small scenes, and check_states: the general path's answers, to the bit.

The referee for a small scene's step is the same World with the one pass switched off
(``ONE_PASS_PAIRS`` below any scene), so the general path (broad phase, filters, SAT,
contacts, each a stage of its own) answers the same input. For ``check_states`` the referee is
a fresh World's step of each state alone, for every broad phase (which also decides whether
the batch runs in one pass or state after state).
"""
import os
import subprocess
import sys

from broadphase_reference import random_quaternions
import numpy as np
import pytest

from collision_node import World
from collision_node.pipeline import one_pass, scenes, world as world_module
from collision_node.pipeline.broadphase import NAMES
from collision_node.pipeline.contacts import (CONTACT_DTYPE, DYNAMIC, joined, STATE_CONTACT_DTYPE,
                                              STATIC)

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
IDENTITY = [0.0, 0.0, 0.0, 1.0]


def arm_world(broad_phase='brute_force', threads=1):
    """Return a World set up as config/arm.yaml."""
    scene = scenes.arm()
    world = World(broad_phase=broad_phase, margin=0.05, threads=threads)
    world.set_static(scene.static_poses, scene.static_half_extents, margins=[0.0, 0.0, 0.05])
    world.set_filters(ignored_pairs=[(i, DYNAMIC, i + 1, DYNAMIC) for i in range(6)]
                      + [(0, DYNAMIC, 0, STATIC)])
    return world


def arm_states(count, period=scenes.ARM_PERIOD_S):
    scene = scenes.arm()
    return np.array([scene.dynamic_poses(t) for t in np.linspace(0.0, period, count)])


def random_scene(rng, n_static, n_dynamic, side):
    def poses(n):
        return np.concatenate([rng.uniform(0.0, side, (n, 3)), random_quaternions(rng, n)], 1)
    return (poses(n_static), rng.uniform(0.05, 0.5, (n_static, 3)), poses(n_dynamic),
            rng.uniform(0.05, 0.4, (n_dynamic, 3)))


def configured(rng, world, n_static, n_dynamic, static_poses, static_extents):
    """Set random margins, filters and ignored pairs on ``world``; return its settings."""
    margins = rng.choice([0.0, 0.0, 0.03], n_static)
    masks = rng.choice([-1, -1, 1, 2], n_static)
    world.margin = float(rng.choice([0.0, 0.02]))
    world.set_static(static_poses, static_extents, ids=np.arange(n_static) * 3 + 5,
                     margins=margins, masks=masks)
    if rng.random() < 0.6 and n_dynamic:
        ignored = [(int(a), DYNAMIC, int(b), DYNAMIC) for a, b in
                   rng.integers(0, n_dynamic, (3, 2)) if a != b]
        ignored += [(int(rng.integers(n_dynamic)), DYNAMIC, 5, STATIC)]
        world.set_filters(categories=rng.choice([1, 2, 3], n_dynamic), masks=-1,
                          ignored_pairs=ignored)


@pytest.fixture
def general_path(monkeypatch):
    """Return a function that steps a World through the general path only."""
    def step(world, poses, half_extents):
        with monkeypatch.context() as patch:
            patch.setattr(world_module, 'ONE_PASS_PAIRS', -1)
            return world.step(poses, half_extents)
    return step


def test_the_arm_in_one_pass_answers_as_the_general_path(general_path):
    one_pass, general = arm_world(), arm_world()
    extents = scenes.arm().dynamic_half_extents
    reported = 0
    for poses in arm_states(200):
        fast = one_pass.step(poses, extents)
        slow = general_path(general, poses, extents)
        assert fast.contacts.tobytes() == slow.contacts.tobytes()
        assert fast.stats['near_pairs'] == slow.stats['near_pairs']
        assert fast.stats['sat_tests'] == slow.stats['sat_tests']
        assert fast.stats['filtered_pairs'] == slow.stats['filtered_pairs']
        assert slow.stats['broad_phase'] == fast.stats['broad_phase'] == 'brute_force'
        reported += len(fast.contacts)
    assert reported > 100  # colliding and near pairs: not vacuous


@pytest.mark.parametrize('seed', range(6))
def test_random_small_scenes_in_one_pass_answer_as_the_general_path(seed, general_path):
    rng = np.random.default_rng(seed)
    for case in range(15):
        n_static, n_dynamic = int(rng.integers(0, 12)), int(rng.integers(0, 25))
        static_poses, static_extents, poses, extents = random_scene(rng, n_static, n_dynamic,
                                                                    side=2.5)
        one_pass, general = World(broad_phase='auto'), World(broad_phase='auto')
        for world in (one_pass, general):
            configured(np.random.default_rng([seed, case]), world, n_static, n_dynamic,
                       static_poses, static_extents)
        one_size = rng.random() < 0.3
        sizes = extents[0] if one_size and n_dynamic else extents
        for tick in range(3):
            fast = one_pass.step(poses, sizes)
            slow = general_path(general, poses, sizes)
            assert fast.contacts.tobytes() == slow.contacts.tobytes(), (seed, case, tick)
            poses[:, :3] += rng.normal(0.0, 0.1, (n_dynamic, 3))


def test_one_pass_refuses_bad_input_as_the_general_path(general_path):
    world = arm_world()
    extents = scenes.arm().dynamic_half_extents
    bad = arm_states(1)[0]
    bad[4, 5] = np.nan
    for step in (world.step, lambda p, e: general_path(world, p, e)):
        with pytest.raises(ValueError, match='body 4: pose has a NaN'):
            step(bad, extents)
        with pytest.raises(ValueError, match=r'half extents must have shape \(3,\) or \(7, 3\)'):
            step(arm_states(1)[0], extents[:2])
    good = world.step(arm_states(1)[0], extents)  # nothing of the refused input was kept
    assert good.contacts.tobytes() == arm_world().step(arm_states(1)[0], extents).contacts \
        .tobytes()


def test_one_pass_reuses_an_identical_input_and_nothing_else():
    world = arm_world()
    extents = scenes.arm().dynamic_half_extents
    poses = arm_states(3)[1]
    first = world.step(poses, extents)
    again = world.step(poses.copy(), extents.copy())
    assert again.stats['reused'] and again.contacts is first.contacts
    world.move_static([1], [[0.75, -0.1, 0.35] + IDENTITY])  # the table rises
    moved = world.step(poses, extents)
    assert not moved.stats['reused']
    assert not world.step(arm_states(3)[2], extents).stats['reused']


def test_stats_are_built_only_when_read():
    world = arm_world()
    result = world.step(arm_states(2)[1], scenes.arm().dynamic_half_extents)
    assert result._stats is None
    stats = result.stats
    assert stats is result.stats  # built once
    assert stats['dynamic_bodies'] == 7 and stats['static_bodies'] == 3
    contacts, unpacked = result
    assert contacts is result.contacts and unpacked is stats


def test_phase_times_and_continuous_mode_agree_with_the_stats_they_skip():
    """What the node reads on every input, without building a small scene's stats."""
    extents = scenes.arm().dynamic_half_extents
    general = World(broad_phase='sweep_and_prune', margin=0.05)
    swept = World(continuous=True)
    for world in (arm_world(), general, swept):
        for poses in (arm_states(3)[1], arm_states(3)[1], arm_states(3)[2]):  # one reused
            fresh = world.step(poses, extents)
            answered = fresh.phase_ms, fresh.continuous  # read before the stats are built
            stats = fresh.stats
            assert answered[1] == stats['continuous']
            if stats['reused']:
                assert answered[0] is None
            else:
                assert answered[0] == (stats['prepare_ms'] + stats['broad_ms'],
                                       stats['narrow_ms'])
    assert swept.step(arm_states(3)[0], extents).continuous == 'on'


def test_a_scene_that_grows_leaves_the_one_pass_and_comes_back(general_path):
    rng = np.random.default_rng(9)
    static_poses, static_extents, poses, extents = random_scene(rng, 20, 400, side=8.0)
    world, reference = World(), World(broad_phase='grid')
    for w in (world, reference):
        w.set_static(static_poses, static_extents)
    for count in (10, 400, 12, 12, 300, 5):  # one pass, general, one pass, ...
        expected = reference.step(poses[:count], extents[:count]).contacts
        assert world.step(poses[:count], extents[:count]).contacts.tobytes() == \
            expected.tobytes(), count
        world.validate()
        poses[:, :3] += rng.normal(0.0, 0.05, (len(poses), 3))


# ---------------------------------------------------------------- check_states

def same_rows(a, b):
    """Whether two contact arrays hold the same rows, field by field, to the bit.

    Not their bytes: a state's contacts are aligned, and their padding is left unwritten.
    """
    return a.dtype == b.dtype and len(a) == len(b) and all(
        a[name].tobytes() == b[name].tobytes() for name in a.dtype.names)


def one_by_one(world_settings, states, extents):
    """Return the referee: each state stepped alone by a fresh World, with its state index."""
    rows = []
    for k, poses in enumerate(states):
        world = world_settings()
        contacts = world.step(poses, extents).contacts
        out = np.empty(len(contacts), STATE_CONTACT_DTYPE)
        for name in CONTACT_DTYPE.names:
            out[name] = contacts[name]
        out['state'] = k
        rows.append(out)
    return np.concatenate(rows)


@pytest.mark.parametrize('threads', [1, 2])
def test_check_states_answers_each_state_as_a_step_of_it_alone(threads, monkeypatch):
    monkeypatch.setattr(one_pass, 'MIN_STATES_PER_CHUNK', 16)  # several chunks
    states = arm_states(300)
    extents = scenes.arm().dynamic_half_extents
    world = arm_world(threads=threads)
    result = world.check_states(states, extents)
    assert result.contacts.dtype == STATE_CONTACT_DTYPE
    assert same_rows(result.contacts, one_by_one(arm_world, states, extents))
    keys = [(c['state'], c['id_a'], c['type_b'], c['id_b']) for c in result.contacts]
    assert keys == sorted(keys) and len(keys) > 100
    assert result.stats['states'] == 300
    world.close()


def test_joined_contacts_are_numpys_concatenation_byte_for_byte():
    rng = np.random.default_rng(5)
    parts = [np.zeros(n, STATE_CONTACT_DTYPE) for n in (3, 0, 5, 1)]
    for part in parts:
        for name in STATE_CONTACT_DTYPE.names:
            part[name] = rng.integers(0, 1000, len(part))
    together = joined(parts)
    assert together.dtype == STATE_CONTACT_DTYPE
    assert together.tolist() == np.concatenate(parts).tolist()


@pytest.mark.parametrize('name', NAMES)
def test_check_states_equals_one_state_steps_for_every_phase(name):
    """Small scenes (one pass for brute force and auto) and large ones (state after state)."""
    rng = np.random.default_rng(NAMES.index(name))
    for n_static, n_dynamic in ((6, 9), (150, 160)):
        static_poses, static_extents, poses, extents = random_scene(rng, n_static, n_dynamic,
                                                                    side=4.0)
        states = np.array([poses + np.r_[rng.normal(0.0, 0.2, 3), [0.0] * 4]
                           for _ in range(5)])

        def settings(seed=n_dynamic):
            world = World(broad_phase=name)
            configured(np.random.default_rng(seed), world, n_static, n_dynamic, static_poses,
                       static_extents)
            return world
        got = settings().check_states(states, extents).contacts
        assert same_rows(got, one_by_one(settings, states, extents))


def test_check_states_leaves_the_ticks_alone():
    world = arm_world()
    extents = scenes.arm().dynamic_half_extents
    states = arm_states(50)
    first = world.step(states[10], extents)
    world.check_states(states, extents)
    again = world.step(states[10], extents)
    assert again.stats['reused'] and again.contacts is first.contacts  # nothing changed
    fresh = arm_world().step(states[11], extents)
    assert world.step(states[11], extents).contacts.tobytes() == fresh.contacts.tobytes()
    # A large scene's ticks keep their coherence too (still bodies keep their contacts).
    rng = np.random.default_rng(3)
    static_poses, static_extents, poses, sizes = random_scene(rng, 200, 300, side=7.0)
    big = World(broad_phase='grid')
    big.set_static(static_poses, static_extents)
    big.step(poses, sizes)
    big.check_states(np.array([poses, poses + [0.1, 0, 0, 0, 0, 0, 0]]), sizes)
    half = poses.copy()
    half[::2, 0] += 0.01
    assert big.step(half, sizes).stats['still_bodies'] == 150


def test_check_states_refuses_bad_input_naming_the_state_and_body():
    world = arm_world()
    extents = scenes.arm().dynamic_half_extents
    states = arm_states(20)
    states[13, 2, 3:] = 0.0
    with pytest.raises(ValueError, match='state 13: dynamic body 2: quaternion'):
        world.check_states(states, extents)
    with pytest.raises(ValueError, match=r'states must have shape \(K, D, 7\)'):
        world.check_states(states[0], extents)
    with pytest.raises(ValueError, match=r'half extents must have shape \(3,\) or \(7, 3\)'):
        world.check_states(arm_states(2), extents[:6])
    assert len(world.check_states(np.zeros((0, 7, 7)), extents).contacts) == 0


NO_COMPILE = """
import numpy as np
from collision_node import warm_up, World
from collision_node.pipeline import scenes
from collision_node.pipeline._jit import KERNELS
from collision_node.pipeline.contacts import DYNAMIC, STATIC

def compiled():  # every kernel of the package (pipeline._jit.KERNELS): its compiled types
    return {(kernel.py_func.__module__, kernel.py_func.__name__): len(kernel.overloads)
            for kernel in KERNELS}

warm_up()
before = compiled()
scene = scenes.arm()
extents = scene.dynamic_half_extents
states = np.array([scene.dynamic_poses(t) for t in np.linspace(0.0, 8.0, 40)])
for margin, own, filters, threads in ((0.0, 0.0, False, 1), (0.05, 0.0, True, 2),
                                      (0.0, 0.05, True, 1), (0.05, 0.05, False, 2)):
    world = World(broad_phase='brute_force', margin=margin, threads=threads)
    world.set_static(scene.static_poses, scene.static_half_extents, margins=own)
    if filters:
        world.set_filters(categories=[1, 2] * 3 + [1], ignored_pairs=[(0, DYNAMIC, 1, DYNAMIC),
                                                                    (0, DYNAMIC, 0, STATIC)])
    read_only = states.copy()  # as a message's bytes are
    read_only.flags.writeable = False
    for sizes in (extents, extents[0]):
        for poses in states[:3]:
            world.step(poses, sizes)
        world.step(states[2], sizes)  # an identical input
        world.step(read_only[3], sizes)
        world.check_states(states, sizes)
        world.check_states(read_only, sizes)
    world.close()
after = compiled()
print(sorted(key for key in after if after[key] != before.get(key)))
"""


def test_no_one_pass_step_nor_batch_compiles_after_the_warm_up():
    done = subprocess.run([sys.executable, '-c', NO_COMPILE], capture_output=True, text=True,
                          timeout=900, cwd=REPO)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip() == '[]'
