"""``auto``: picks the broad phase per tick from the body count and spread, with hysteresis.

Rule, from the measurements in doc/benchmarks.md ("Which broad phase"):

* brute force while it has fewer than ``BRUTE_FORCE_WORK`` pairs to compare (D·S + D(D-1)/2,
  about 60 bodies): its loop has no set-up cost and beats every structure there;
* sweep and prune below ``GRID_BODIES`` bodies, and for packed scenes: when the cube around
  the dynamic boxes holds less than ``PACKED_VOLUME`` mean-box-side cubes per box (all bodies
  near one point), every box overlaps many others, cells and trees cannot prune, and the
  sorted sweep, which writes its pairs in order, is the fastest (3-4x the grid's speed there);
* the hashed uniform grid otherwise: the fastest measured on every larger scene.

Hysteresis: each threshold is moved by ``MARGIN`` away from the phase in use (a scene must
pass it clearly to leave), and a new choice must hold for ``SWITCH_AFTER_TICKS`` ticks in a row
before it is taken, so a scene hovering at a threshold does not flap (each switch throws away
the structures of the phase left, e.g. the grid's static table). The first tick, and a scene
beyond a threshold by ``URGENT_MARGIN`` (100,000 bodies arriving while brute force runs: one
such tick takes seconds), switch at once. ``validate`` (for tests) validates the phase that
ran the last tick.
"""
import numpy as np

from collision_node.pipeline._jit import kernel
from collision_node.pipeline.broadphase import make_broad_phase
from collision_node.pipeline.broadphase.brute_force import BruteForce
from collision_node.pipeline.broadphase.grid import Grid
from collision_node.pipeline.broadphase.sweep_and_prune import SweepAndPrune
from collision_node.pipeline.broadphase.validation import check

BRUTE_FORCE_WORK = 1500   # pair comparisons: brute force below (measured crossover ~1,000-2,000)
GRID_BODIES = 700         # bodies: sweep and prune below, the grid above (crossover 500-1,000)
PACKED_VOLUME = 0.25      # (extent / mean side)^3 per dynamic box below which a scene is packed
MARGIN = 1.25             # thresholds move by this factor away from the phase in use
URGENT_MARGIN = 8.0       # beyond a threshold by this factor: switch without waiting
SWITCH_AFTER_TICKS = 8    # ticks a new choice must hold before it is taken

SIMPLER = {BruteForce.name: 0, SweepAndPrune.name: 1, Grid.name: 2}  # threshold order


class Auto:
    """Chooses the broad phase; ``name`` tells which one ran last, ``stats`` its figures."""

    def __init__(self, settings, workers=None):
        self._settings = settings
        self._workers = workers
        self._phases = {}
        self._static = None  # (boxes, n_static) of the last set_static, for new phases
        self._current = None
        self._wanted = None
        self._wanted_for = 0
        self.name = BruteForce.name
        self.switches = 0
        self.stats = {}

    def set_static(self, boxes, n_static):
        self._static = (boxes, n_static)
        for phase in self._phases.values():
            phase.set_static(boxes, n_static)

    def move_static(self, boxes, rows):
        kept = np.ones(len(rows), np.bool_)
        for phase in self._phases.values():  # a phase made later is built as the boxes are
            kept &= phase.move_static(boxes, rows)
        return kept

    def find_pairs(self, boxes, n_static, n_dynamic, moved=None):
        wanted = self._choose(boxes.aabbs, n_static, n_dynamic, MARGIN)
        if wanted == self._wanted:
            self._wanted_for += 1
        else:
            self._wanted, self._wanted_for = wanted, 1
        if self._current is None:
            self._current = wanted
        elif wanted != self._current and (
                self._wanted_for >= SWITCH_AFTER_TICKS
                or self._choose(boxes.aabbs, n_static, n_dynamic, URGENT_MARGIN) != self._current):
            self._current = wanted
            self.switches += 1
        phase = self._phase(self._current)
        pairs = phase.find_pairs(boxes, n_static, n_dynamic, moved)
        self.name = phase.name
        self.stats = dict(phase.stats, auto_switches=self.switches)
        return pairs

    def validate(self, boxes, n_static, n_dynamic, loose=None):
        """Validate the phase that ran the last tick (the others' lists are of older ticks).

        For testing; raises InvalidStructure (see the phases' own ``validate``).
        """
        if self._current is None:
            return  # no tick yet: no phase made
        phase = self._phases[self._current]
        check(self.name == phase.name, 'auto names %s, %s ran', self.name, phase.name)
        phase.validate(boxes, n_static, n_dynamic, loose)

    def _choose(self, aabbs, n_static, n_dynamic, margin):
        """Name the phase the scene asks for, thresholds moved away from the current one."""
        def below(value, threshold, simpler_than):
            """``value < threshold``, the threshold raised while a simpler phase runs."""
            if self._current is None:
                return value < threshold
            current_is_simpler = SIMPLER[self._current] < SIMPLER[simpler_than]
            return value < threshold * (margin if current_is_simpler else 1.0 / margin)

        work = n_dynamic * n_static + n_dynamic * (n_dynamic - 1) // 2
        if below(work, BRUTE_FORCE_WORK, SweepAndPrune.name):
            return BruteForce.name
        if below(n_static + n_dynamic, GRID_BODIES, Grid.name):
            return SweepAndPrune.name
        spread = spread_in_box_sides(aabbs, n_static, n_static + n_dynamic)
        if below(spread ** 3 / n_dynamic, PACKED_VOLUME, Grid.name):
            return SweepAndPrune.name
        return Grid.name

    def _phase(self, name):
        if name not in self._phases:
            phase = make_broad_phase(name, self._settings, self._workers)
            if self._static is not None:
                phase.set_static(*self._static)
            self._phases[name] = phase
        return self._phases[name]


@kernel
def spread_in_box_sides(aabbs, first, stop):
    """Largest extent of the boxes' common bounding box, in units of their mean side."""
    low = aabbs[first, 0].copy()
    high = aabbs[first, 1].copy()
    side = 0.0
    for row in range(first, stop):
        for k in range(3):
            low[k] = min(low[k], aabbs[row, 0, k])
            high[k] = max(high[k], aabbs[row, 1, k])
            side += aabbs[row, 1, k] - aabbs[row, 0, k]
    extent = max(high[0] - low[0], high[1] - low[1], high[2] - low[2])
    side /= 3 * (stop - first)
    if side <= 0.0:  # points only: spread out unless they all coincide
        return 0.0 if extent <= 0.0 else float(stop - first)
    return extent / side
