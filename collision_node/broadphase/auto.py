"""``auto``: picks the broad phase per tick from the body count and spread, with hysteresis.

Rule, from the measurements in the README ("Broad phases"): brute force while the scene is
small (fewer than ``SMALL_SCENE`` bodies: its loop has no set-up cost and beats every
structure there) or packed (the dynamic boxes' bounding box is less than ``PACKED_SPREAD``
mean box sides across: every box meets every other, so no structure can prune anything);
otherwise the hashed uniform grid, the fastest phase measured on every larger scene.

Hysteresis: the thresholds are crossed only with a margin (``MARGIN`` above on the way up,
below on the way down), and a new choice must hold for ``SWITCH_AFTER_TICKS`` ticks in a row
before it is taken, so a scene hovering at a threshold does not flap between phases (each
switch throws away the structure of the phase left, e.g. the grid's static table).
"""
from collision_node._jit import kernel
from collision_node.broadphase.brute_force import BruteForce
from collision_node.broadphase.grid import Grid

SMALL_SCENE = 256      # bodies (static + dynamic): brute force below, measured crossover
PACKED_SPREAD = 3.0    # bounding box / mean box side of the dynamic boxes: brute force below
MARGIN = 1.25          # thresholds are passed by this factor before a switch is considered
SWITCH_AFTER_TICKS = 8  # ticks a new choice must hold before it is taken


class Auto:
    """Chooses the broad phase; ``name`` tells which one ran last, ``stats`` its figures."""

    def __init__(self, settings):
        self._settings = settings
        self._phases = {}
        self._static = None  # (boxes, n_static) of the last set_static, for new phases
        self._current = BruteForce.name
        self._wanted = self._current
        self._wanted_for = 0
        self.name = self._current
        self.switches = 0
        self.stats = {}

    def set_static(self, boxes, n_static):
        self._static = (boxes, n_static)
        for phase in self._phases.values():
            phase.set_static(boxes, n_static)

    def find_pairs(self, boxes, n_static, n_dynamic):
        wanted = self._choose(boxes.aabbs, n_static, n_dynamic)
        if wanted == self._wanted:
            self._wanted_for += 1
        else:
            self._wanted, self._wanted_for = wanted, 1
        if wanted != self._current and self._wanted_for >= SWITCH_AFTER_TICKS:
            self._current = wanted
            self.switches += 1
        phase = self._phase(self._current)
        pairs = phase.find_pairs(boxes, n_static, n_dynamic)
        self.name = phase.name
        self.stats = dict(getattr(phase, 'stats', {}), auto_switches=self.switches)
        return pairs

    def _choose(self, aabbs, n_static, n_dynamic):
        """Name the phase the scene asks for, thresholds moved away from the current one."""
        up = self._current == BruteForce.name  # leaving brute force needs the higher bar
        margin = MARGIN if up else 1.0 / MARGIN
        if n_static + n_dynamic < SMALL_SCENE * margin:
            return BruteForce.name
        if spread_in_box_sides(aabbs, n_static, n_static + n_dynamic) < PACKED_SPREAD * margin:
            return BruteForce.name
        return Grid.name

    def _phase(self, name):
        if name not in self._phases:
            phase = (BruteForce if name == BruteForce.name else Grid)(self._settings)
            if self._static is not None:
                phase.set_static(*self._static)
            self._phases[name] = phase
        return self._phases[name]


@kernel
def spread_in_box_sides(aabbs, first, stop):
    """Largest extent of the boxes' common bounding box, in units of their mean side."""
    low0 = low1 = low2 = 0.0
    high0 = high1 = high2 = 0.0
    side = 0.0
    for row in range(first, stop):
        if row == first:
            low0, low1, low2 = aabbs[row, 0, 0], aabbs[row, 0, 1], aabbs[row, 0, 2]
            high0, high1, high2 = aabbs[row, 1, 0], aabbs[row, 1, 1], aabbs[row, 1, 2]
        low0 = min(low0, aabbs[row, 0, 0])
        low1 = min(low1, aabbs[row, 0, 1])
        low2 = min(low2, aabbs[row, 0, 2])
        high0 = max(high0, aabbs[row, 1, 0])
        high1 = max(high1, aabbs[row, 1, 1])
        high2 = max(high2, aabbs[row, 1, 2])
        for k in range(3):
            side += aabbs[row, 1, k] - aabbs[row, 0, k]
    extent = max(high0 - low0, high1 - low1, high2 - low2)
    side /= 3 * max(stop - first, 1)
    if side <= 0.0:
        return 0.0 if extent <= 0.0 else float(stop - first)  # points: spread if apart
    return extent / side
