"""Collision filtering: categories and masks, ignored pairs, for every broad phase.

The reference is the unfiltered brute-force World's contacts, filtered here in plain Python
by the rule as doc/filtering-and-margins.md states it: a pair is reported only if
``category_a & mask_b`` and ``category_b & mask_a`` are both non-zero and the pair is not in
``ignored_pairs``.
"""
from broadphase_reference import uniform
import numpy as np
import pytest

from collision_node import DYNAMIC, STATIC, World
from collision_node.pipeline.broadphase import NAMES
from collision_node.pipeline.filters import ALL_CATEGORIES


def allowed(key, categories, masks, ignored):
    """Apply the rule to one contact key (id_a, type_b, id_b); ``categories[type][id]``."""
    id_a, type_b, id_b = key
    a, b = (DYNAMIC, id_a), (type_b, id_b)
    masks_accept = (categories[a[0]][a[1]] & masks[b[0]][b[1]]) != 0 \
        and (categories[b[0]][b[1]] & masks[a[0]][a[1]]) != 0
    return masks_accept and frozenset([a, b]) not in ignored


def keys(result):
    contacts = result.contacts
    return [tuple(int(v) for v in row) for row in
            zip(contacts['id_a'], contacts['type_b'], contacts['id_b'])]


def random_filters(rng, n_dynamic, n_static, reference_keys):
    """Categories and masks over 3 bits (about half the pairs pass) and some ignored pairs."""
    categories = {DYNAMIC: rng.integers(1, 8, n_dynamic), STATIC: rng.integers(1, 8, n_static)}
    masks = {DYNAMIC: rng.integers(0, 8, n_dynamic), STATIC: rng.integers(0, 8, n_static)}
    chosen = rng.choice(len(reference_keys), len(reference_keys) // 4, replace=False)
    ignored = [reference_keys[i] for i in chosen]
    rows = [(id_a, DYNAMIC, id_b, type_b) for id_a, type_b, id_b in ignored]
    # Both orders of an entry name the same pair, and entries beyond the input never apply.
    rows += [(id_b, type_b, id_a, DYNAMIC) for id_a, type_b, id_b in ignored[:3]]
    rows += [(n_dynamic + 5, DYNAMIC, 0, DYNAMIC), (n_dynamic + 7, DYNAMIC, 0, STATIC)]
    return categories, masks, rows, {frozenset([(DYNAMIC, a), (t, b)]) for a, t, b in ignored}


@pytest.mark.parametrize('name', NAMES)
def test_every_broad_phase_returns_the_filtered_brute_force_pairs(name):
    scene = uniform(600, seed=3)
    rng = np.random.default_rng(11)
    reference = World('brute_force')
    reference.set_static(scene.static_poses, scene.static_half_extents)
    world = World(name)
    n_static = len(scene.static_poses)
    for tick in range(4):
        poses, extents = scene.dynamic(tick)
        expected = reference.step(poses, extents)
        all_keys = keys(expected)
        categories, masks, rows, ignored = random_filters(rng, len(poses), n_static, all_keys)
        world.set_static(scene.static_poses, scene.static_half_extents,
                         categories=categories[STATIC], masks=masks[STATIC])
        world.set_filters(categories[DYNAMIC], masks[DYNAMIC], rows)
        result = world.step(poses, extents)
        kept = [key for key in all_keys if allowed(key, categories, masks, ignored)]
        assert 0 < len(kept) < len(all_keys) / 2
        assert keys(result) == kept
        # The kept contacts are those of the unfiltered World, to the bit.
        np.testing.assert_array_equal(
            result.contacts, expected.contacts[[key in set(kept) for key in all_keys]])
        stats = result.stats
        assert stats['filtered_pairs'] > 0
        if not stats['still_bodies']:
            assert stats['sat_tests'] <= stats['candidate_pairs'] - stats['filtered_pairs']


def test_filtered_pairs_never_reach_the_sat():
    scene = uniform(400, seed=5)
    poses, extents = scene.dynamic(0)
    world = World('brute_force', sphere_prefilter=False)
    world.set_static(scene.static_poses, scene.static_half_extents)
    plain = world.step(poses, extents).stats
    world.set_filters(categories=1, masks=0)  # dynamic bodies accept nothing
    masked = world.step(poses, extents).stats
    assert masked['candidate_pairs'] == plain['candidate_pairs'] == plain['sat_tests'] > 0
    assert masked['filtered_pairs'] == masked['candidate_pairs']
    assert masked['sat_tests'] == 0 and masked['colliding_pairs'] == 0


def overlapping_pair_world(**filters):
    world = World('brute_force')
    world.set_static([[5.0, 0, 0, 0, 0, 0, 1]], [[0.5, 0.5, 0.5]], **filters)
    return world


POSES = np.array([[0.0, 0, 0, 0, 0, 0, 1], [0.5, 0, 0, 0, 0, 0, 1], [5.5, 0, 0, 0, 0, 0, 1]])


def test_defaults_report_every_pair_bit_for_bit():
    plain = World('brute_force')
    plain.set_static([[5.0, 0, 0, 0, 0, 0, 1]], [[0.5, 0.5, 0.5]])
    expected = plain.step(POSES, [0.5, 0.5, 0.5])
    world = overlapping_pair_world(categories=1, masks=ALL_CATEGORIES)
    world.set_filters(categories=1, masks=ALL_CATEGORIES, ignored_pairs=[])
    result = world.step(POSES, [0.5, 0.5, 0.5])
    assert keys(result) == [(0, DYNAMIC, 1), (2, STATIC, 0)]
    np.testing.assert_array_equal(result.contacts, expected.contacts)
    assert result.stats['filtered_pairs'] == 0


def test_an_ignored_pair_is_never_reported_whatever_the_masks():
    world = overlapping_pair_world()
    world.set_filters(categories=1, masks=ALL_CATEGORIES, ignored_pairs=[(1, DYNAMIC, 0, DYNAMIC)])
    assert keys(world.step(POSES, [0.5, 0.5, 0.5])) == [(2, STATIC, 0)]
    world.set_filters(ignored_pairs=[(0, STATIC, 2, DYNAMIC)])  # a static body first
    assert keys(world.step(POSES, [0.5, 0.5, 0.5])) == [(0, DYNAMIC, 1)]


def test_masks_alone_filter_a_pair_that_is_not_ignored():
    world = overlapping_pair_world(categories=2, masks=2)  # the static accepts category 2 only
    world.set_filters(categories=[1, 1, 1], masks=ALL_CATEGORIES)
    assert keys(world.step(POSES, [0.5, 0.5, 0.5])) == [(0, DYNAMIC, 1)]
    world.set_filters(categories=[1, 1, 2], masks=[ALL_CATEGORIES, 4, ALL_CATEGORIES])
    # 0-1: category 1 & mask 4 == 0 (one direction suffices to filter); 2-s0: 2 & 2 both ways.
    assert keys(world.step(POSES, [0.5, 0.5, 0.5])) == [(2, STATIC, 0)]


def test_a_uint64_mask_keeps_its_bits():
    world = overlapping_pair_world()
    # Bit 63 is the sign bit of the int64 the bits are kept in.
    world.set_filters(categories=np.array([2**63, 2**63, 1], np.uint64),
                      masks=np.uint64(2**64 - 1))
    world.set_static([[5.0, 0, 0, 0, 0, 0, 1]], [[0.5, 0.5, 0.5]], categories=1,
                     masks=np.uint64(2**63))  # body 2's category 1 is not in this mask
    assert keys(world.step(POSES, [0.5, 0.5, 0.5])) == [(0, DYNAMIC, 1)]


def test_entries_beyond_the_input_apply_to_no_pair():
    world = overlapping_pair_world()
    world.set_filters(ignored_pairs=[(7, DYNAMIC, 1, DYNAMIC), (9, DYNAMIC, 0, STATIC)])
    assert keys(world.step(POSES, [0.5, 0.5, 0.5])) == [(0, DYNAMIC, 1), (2, STATIC, 0)]
    more = np.concatenate([POSES, [[5.0, 0.5, 0, 0, 0, 0, 1]] * 7])
    assert (7, DYNAMIC, 1) not in keys(world.step(more, [0.5, 0.5, 0.5]))


def test_a_filter_change_is_seen_by_bodies_that_did_not_move():
    world = overlapping_pair_world()
    assert len(world.step(POSES, [0.5, 0.5, 0.5]).contacts) == 2
    world.set_filters(categories=[1, 2, 1], masks=[1, 1, 1])
    assert keys(world.step(POSES, [0.5, 0.5, 0.5])) == [(2, STATIC, 0)]
    world.set_filters()
    assert len(world.step(POSES, [0.5, 0.5, 0.5]).contacts) == 2


@pytest.mark.parametrize('call, message', [
    (lambda w: w.set_filters(categories=[1.5]), 'integer'),
    (lambda w: w.set_filters(masks='all'), 'integer'),
    (lambda w: w.set_filters(masks=[[1, 2]]), 'integer'),
    (lambda w: w.set_filters(ignored_pairs=[(-1, DYNAMIC, 0, DYNAMIC)]), 'ids must be'),
    (lambda w: w.set_filters(ignored_pairs=[(0, 5, 1, DYNAMIC)]), 'type must be'),
    (lambda w: w.set_static(POSES, [1, 1, 1], categories=[1, 2]), 'one value or one per box'),
    (lambda w: w.set_static(POSES, [1, 1, 1], margins=-0.1), 'margin must be a distance in'),
    (lambda w: w.step(POSES, [0.5] * 3) if w.set_filters(categories=[1, 2]) is None else 0,
     'collision_category has 2 values, the input 3 bodies'),
])
def test_invalid_filter_values_are_refused(call, message):
    with pytest.raises(ValueError, match=message):
        call(World('brute_force'))
