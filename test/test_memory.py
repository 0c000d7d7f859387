"""keep_heap_memory: glibc keeps large freed blocks, so reusing them touches no new page."""
import resource
import subprocess
import sys

# Allocates, fills and frees blocks of two sizes in turn (as a tick does with a message and a
# cloud) and prints the page faults of five rounds after the first.
PATTERN = """
import resource, sys
import numpy as np
from collision_node.ros.memory import keep_heap_memory
if sys.argv[1] == 'keep':
    assert keep_heap_memory()
sizes = (2 << 20, 9 << 20)
for size in sizes:
    np.ones(size, np.uint8)
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(5):
    for size in sizes:
        np.ones(size, np.uint8)
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def faults(mode):
    return int(subprocess.run([sys.executable, '-c', PATTERN, mode], check=True,
                              capture_output=True, text=True).stdout)


def test_large_blocks_are_reused_without_page_faults():
    pages = (11 << 20) // resource.getpagesize()  # one round's pages
    # glibc's own rule maps the larger block afresh and faults in its pages every round;
    # kept, the blocks come back from the heap already touched.
    assert faults('default') > pages // 8
    assert faults('keep') < pages // 100
