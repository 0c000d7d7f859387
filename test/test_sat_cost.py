"""sat_cost: the pairs timed are the tick's candidates, split by verdict without loss."""
from collision_node.benchmarks.sat_cost import sat_cost, SETTLE_TICKS
from collision_node.pipeline.scenes import uniform
from collision_node.pipeline.world import World


def test_the_split_covers_every_candidate_and_the_colliding_ones_are_the_contacts():
    costs = sat_cost(400, repeats=2)
    assert costs['colliding'][0] + costs['other'][0] == costs['all'][0]
    assert all(ms > 0.0 for _, ms in costs.values())
    scene = uniform(400)
    world = World()
    world.set_static(scene.static_poses, scene.static_half_extents)
    for tick in range(SETTLE_TICKS):
        result = world.step(scene.dynamic_poses(tick / 60), scene.dynamic_half_extents)
    assert costs['colliding'][0] == len(result.contacts) > 0
    assert costs['all'][0] == result.stats['candidate_pairs']
