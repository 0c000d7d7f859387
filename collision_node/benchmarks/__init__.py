"""The pieces of ``collision_bench`` (:mod:`collision_node.bench`), one concern per module.

:mod:`~collision_node.benchmarks.runs` steps a World through a scene and times its ticks;
:mod:`~collision_node.benchmarks.accuracy` measures run time against error for each broad
phase and accuracy mode; :mod:`~collision_node.benchmarks.fcl_reference` drives python-fcl
from the same arrays; :mod:`~collision_node.benchmarks.report` writes results.json,
results.md and time_vs_error.png.
"""
