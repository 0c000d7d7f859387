"""executor_cost: every row is timed and printed, more services never make it free."""
from collision_node.benchmarks import executor_cost


def test_each_count_of_services_gets_its_line(capsys):
    executor_cost.main(['--services', '0', '3', '--wakes', '20'])
    lines = capsys.readouterr().out.splitlines()
    assert [line.split(' extra')[0].strip() for line in lines] == ['0', '3']
    for line in lines:
        assert float(line.split('median ')[1].split(' us')[0]) > 0.0
