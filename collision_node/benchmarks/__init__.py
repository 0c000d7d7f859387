"""The benchmark programs and their parts.

:mod:`~collision_node.benchmarks.collision_bench`,
:mod:`~collision_node.benchmarks.collision_latency` and
:mod:`~collision_node.benchmarks.collision_soak` are the console scripts of the same names.

:mod:`~collision_node.benchmarks.runs` steps a World through a scene and times its ticks;
:mod:`~collision_node.benchmarks.accuracy` measures run time against error for each broad
phase and accuracy mode; :mod:`~collision_node.benchmarks.fcl_reference` drives python-fcl
from the same arrays; :mod:`~collision_node.benchmarks.report` writes results.json,
results.md and time_vs_error.png.
"""
