"""against_commit: the base is the commit's package, the child times this tree, ratios."""
import pathlib

from collision_node.benchmarks import against_commit


def test_export_writes_the_commits_package(tmp_path):
    against_commit.export('HEAD', str(tmp_path))
    world = tmp_path / 'collision_node' / 'pipeline' / 'world.py'
    assert world.is_file()
    assert 'class World' in world.read_text()


def test_child_times_each_case_and_its_stages_in_the_given_tree_and_threads():
    cases = ['uniform:20', 'low_motion:40', 'flying_out:30', 'teleport:20', 'count:20', 'arm:7']
    medians = against_commit.run_child(str(against_commit.REPO), [(c, 3) for c in cases], 2)
    assert set(medians) == set(cases)
    for row in medians.values():
        assert set(row) == {'tick', 'prepare_ms', 'broad_ms', 'narrow_ms'}
        assert 0.0 < row['tick'] < 1e4
        assert all(0.0 <= row[stage] < 1e4 for stage in ('prepare_ms', 'broad_ms', 'narrow_ms'))


def test_summary_is_this_over_base_per_round():
    rounds = [{'base': {'u:10': {'tick': 2.0}}, 'this': {'u:10': {'tick': 1.0}}},
              {'this': {'u:10': {'tick': 3.0}}, 'base': {'u:10': {'tick': 2.0}}}]
    assert against_commit.summary(rounds, ['u:10']) == {'u:10': [0.5, 1.5]}


def test_ticks_fill_the_budget_but_never_fewer_than_twenty():
    assert against_commit.ticks_for(1000, 600.0) == 1200
    assert against_commit.ticks_for(10 ** 6, 600.0) == 20


def test_repo_is_the_checkout_holding_the_package():
    assert (pathlib.Path(against_commit.REPO) / 'collision_node' / '__init__.py').is_file()
