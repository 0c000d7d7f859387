"""Skip what a scene does not need (doc/python-api.md), and skip nothing a scene does need.

Each skip is checked by what runs (spies on the broad phase and the box writer), and each is
checked not to hide a change: an answer reused or work left out must equal the full answer.
How much time each skip saves is measured by ``collision_latency`` (section "skips").
"""
import numpy as np
import pytest

from collision_node.pipeline import scene_rows, scenes
from collision_node.pipeline.world import World


class Spy:
    """Wraps a callable and records the arguments of every call."""

    def __init__(self, function):
        self.function = function
        self.calls = []

    def __call__(self, *args):
        self.calls.append(args)
        return self.function(*args)


@pytest.fixture
def scene():
    return scenes.uniform(600, seed=8)


def spied_world(scene, monkeypatch, **options):
    world = World(**options)
    world.set_static(scene.static_poses, scene.static_half_extents)
    phase = world._steps.general.phase
    spies = {'find_pairs': Spy(phase.find_pairs), 'set_static': Spy(phase.set_static),
             'set_boxes': Spy(scene_rows.set_boxes)}
    monkeypatch.setattr(phase, 'find_pairs', spies['find_pairs'])
    monkeypatch.setattr(phase, 'set_static', spies['set_static'])
    monkeypatch.setattr(scene_rows, 'set_boxes', spies['set_boxes'])
    return world, spies


@pytest.mark.parametrize('broad_phase', ['auto', 'grid', 'octree', 'sweep_and_prune'])
def test_no_dynamic_body_runs_no_broad_phase(scene, monkeypatch, broad_phase):
    world, spies = spied_world(scene, monkeypatch, broad_phase=broad_phase)
    result = world.step(np.zeros((0, 7)), [0.1, 0.1, 0.1])
    assert not spies['find_pairs'].calls
    assert len(result.contacts) == 0 and result.stats['candidate_pairs'] == 0
    world.step(scene.dynamic_poses(0.0), scene.dynamic_half_extents)
    assert len(spies['find_pairs'].calls) == 1


def test_static_boxes_are_written_once(scene, monkeypatch):
    world, spies = spied_world(scene, monkeypatch)
    for t in (0.0, 0.1, 0.2):
        world.step(scene.dynamic_poses(t), scene.dynamic_half_extents)
    # Every tick writes the dynamic rows only, after the statics; the phase builds its static
    # structure once (the general path's first step) and keeps it.
    assert [call[1] for call in spies['set_boxes'].calls] == [len(scene.static_poses)] * 3
    assert len(spies['set_static'].calls) == 1


def test_identical_input_reuses_the_answer(scene, monkeypatch):
    world, spies = spied_world(scene, monkeypatch)
    poses = scene.dynamic_poses(0.3)
    first = world.step(poses, scene.dynamic_half_extents)
    again = world.step(poses.copy(), scene.dynamic_half_extents.copy())
    assert again.stats['reused'] and not first.stats['reused']
    assert len(spies['find_pairs'].calls) == 1 and len(spies['set_boxes'].calls) == 1
    np.testing.assert_array_equal(again.contacts, first.contacts)


def changed_inputs(scene):
    """Return the first input and inputs that each differ from it in the least way."""
    poses = scene.dynamic_poses(0.3)
    moved = poses.copy()
    moved[5, 0] = np.nextafter(moved[5, 0], np.inf)  # one ulp: not the same input
    resized = scene.dynamic_half_extents.copy()
    resized[7, 1] *= 2.0
    return poses, [('one ulp moved', moved, scene.dynamic_half_extents),
                   ('one box resized', poses, resized),
                   ('one body fewer', poses[:-1], scene.dynamic_half_extents[:-1])]


def test_any_change_is_computed_afresh(scene):
    poses, cases = changed_inputs(scene)
    for what, changed_poses, changed_extents in cases:
        world = World()
        world.set_static(scene.static_poses, scene.static_half_extents)
        world.step(poses, scene.dynamic_half_extents)
        result = world.step(changed_poses, changed_extents)
        assert not result.stats['reused'], what
        fresh = World()
        fresh.set_static(scene.static_poses, scene.static_half_extents)
        np.testing.assert_array_equal(result.contacts,
                                      fresh.step(changed_poses, changed_extents).contacts)


def test_settings_and_statics_changes_are_not_hidden_by_reuse(scene):
    poses = scene.dynamic_poses(0.3)
    world = World()
    world.set_static(scene.static_poses, scene.static_half_extents)
    full = world.step(poses, scene.dynamic_half_extents).contacts
    for change in (lambda: setattr(world, 'sphere_prefilter', False),
                   lambda: world.configure(broad_phase='octree'),
                   lambda: world.set_static(scene.static_poses[:10],
                                            scene.static_half_extents[:10])):
        change()
        result = world.step(poses, scene.dynamic_half_extents)
        assert not result.stats['reused']
    # Fewer statics (colliders disabled): exactly the contacts with the others left out.
    kept = (full['type_b'] == 0) | (full['id_b'] < 10)
    np.testing.assert_array_equal(result.contacts, full[kept])


@pytest.mark.parametrize('make', [scenes.uniform, scenes.clustered, scenes.flying_out])
def test_sphere_prefilter_changes_no_answer(make):
    scene = make(800, seed=9)
    answers = []
    for sphere in (True, False):
        world = World(sphere_prefilter=sphere)
        world.set_static(scene.static_poses, scene.static_half_extents)
        answers.append(world.step(scene.dynamic_poses(0.2), scene.dynamic_half_extents))
    assert answers[0].stats['sat_tests'] <= answers[1].stats['sat_tests']
    np.testing.assert_array_equal(answers[0].contacts, answers[1].contacts)
