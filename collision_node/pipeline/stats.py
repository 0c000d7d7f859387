"""One record of a check's statistics, filled by every path, and the Result that carries it.

Every path (the general path, the one pass, the batches of states and joints) fills one
:class:`Stats`, as Box2D's steps fill one ``b2Profile``: no path builds a dict of its own.
A :class:`Result` keeps the record as it was filled and builds the public ``stats`` dict from
it when it is first read, with the distance statistics of its contacts: a caller that never
reads the stats never pays for them.

The one pass fills the record as a plain tuple in :class:`Stats`' field order: a NamedTuple's
creation (``Stats(...)``) costs the arm's step 0.2-0.5 µs, a tuple display nearly nothing, and
both read the same by index.
"""
import math
from typing import NamedTuple

from collision_node.pipeline.contacts import closest_contact

# Stats.continuous: off, or swept over the motion since the previous input (else it says why
# the step was checked at its poses only).
OFF = 'off'
SWEPT = 'on'


class Stats(NamedTuple):
    """What one check did and how long it took; ``Result.stats`` is its dict."""

    broad_phase: str          # the phase that paired the boxes ('brute_force': the one pass)
    dynamic_bodies: int
    static_bodies: int
    counts: tuple             # (compared, candidate pairs, filtered pairs, SAT tests)
    reused: bool              # the last answer again: the input had not changed
    still_bodies: int         # bodies that kept their pose, whose contacts were kept
    continuous: str           # OFF, SWEPT or why a continuous step was discrete
    swept_pairs: int          # pairs touching only between the two inputs
    advance_steps: int        # conservative advancement's steps over all pairs
    unresolved_pairs: int     # pairs whose toi it did not resolve within the tolerance
    broad_phase_stats: dict   # the phase's own counters
    prepare_ms: float         # writing the boxes
    broad_ms: float           # the broad phase
    narrow_ms: float          # the filters and the SAT (the whole one pass)
    total_ms: float
    states: object            # check_states' number of states, None for a step


# Field indices the Result reads without building the dict.
COUNTS, REUSED, CONTINUOUS, PREPARE_MS, BROAD_MS, NARROW_MS = (
    Stats._fields.index(name) for name in ('counts', 'reused', 'continuous', 'prepare_ms',
                                           'broad_ms', 'narrow_ms'))
NO_PHASE_STATS = {}  # copied into each dict, never changed


def one_pass_stats(bodies, n_static, counts, ms, states):
    """Return the record of a one pass (a plain tuple in Stats' order: module docstring)."""
    return ('brute_force', bodies, n_static, counts, False, 0, OFF, 0, 0, 0, NO_PHASE_STATS,
            0.0, 0.0, ms, ms, states)


def reused(record):
    """Return ``record`` marked reused: the same answer, for an input that did not change."""
    return record[:REUSED] + (True,) + record[REUSED + 1:]


class Result:
    """Contacts sorted by (id_a, type_b, id_b), and the check's statistics (a dict).

    ``record`` is a :class:`Stats` (or a tuple in its order); ``stats`` is built from it
    when first read. A caller of its own may give the stats dict itself. Unpacks as
    (contacts, stats).
    """

    __slots__ = ('contacts', 'record', '_stats')

    def __init__(self, contacts, record):
        self.contacts = contacts
        if type(record) is dict:
            self.record, self._stats = None, record
        else:
            self.record, self._stats = record, None

    @property
    def stats(self):
        if self._stats is None:
            self._stats = _as_dict(self.record, self.contacts)
        return self._stats

    @property
    def continuous(self):
        """Return ``stats["continuous"]`` without building the stats."""
        return self.stats['continuous'] if self.record is None else self.record[CONTINUOUS]

    @property
    def phase_ms(self):
        """Return (prepare + broad, narrow) ms without building the stats; None if reused."""
        record = self.record
        if record is None:
            stats = self.stats
            return None if stats['reused'] else (stats['prepare_ms'] + stats['broad_ms'],
                                                 stats['narrow_ms'])
        return None if record[REUSED] else (record[PREPARE_MS] + record[BROAD_MS],
                                            record[NARROW_MS])

    def __iter__(self):
        return iter((self.contacts, self.stats))


def _as_dict(record, contacts):
    """Return the public stats dict of ``record`` and its ``contacts``."""
    # Unpacked, not Stats._make(record): a NamedTuple's creation costs ~1 µs.
    (broad_phase, dynamic_bodies, static_bodies, (compared, candidates, filtered, sat_tests),
     was_reused, still_bodies, continuous, swept_pairs, advance_steps, unresolved_pairs,
     phase_stats, prepare_ms, broad_ms, narrow_ms, total_ms, states) = record
    stats = {'broad_phase': broad_phase, 'dynamic_bodies': dynamic_bodies,
             'static_bodies': static_bodies, 'compared': int(compared),
             'candidate_pairs': int(candidates), 'filtered_pairs': int(filtered),
             'sat_tests': int(sat_tests)}
    stats.update(distance_stats(contacts))
    stats.update(reused=was_reused, still_bodies=still_bodies, continuous=continuous,
                 swept_pairs=swept_pairs, advance_steps=advance_steps,
                 unresolved_pairs=unresolved_pairs, broad_phase_stats=dict(phase_stats),
                 prepare_ms=prepare_ms, broad_ms=broad_ms, narrow_ms=narrow_ms,
                 total_ms=total_ms)
    if states is not None:
        stats['states'] = states
    return stats


def distance_stats(contacts):
    """Return colliding_pairs, near_pairs, min_distance and min_distance_pair of contacts."""
    near, smallest, closest = closest_contact(contacts['distance'])
    if closest < 0:
        return {'colliding_pairs': 0, 'near_pairs': 0, 'min_distance': math.nan,
                'min_distance_pair': None}
    # One row as Python values (~0.4 µs; four fields of a numpy row cost 1.4 µs): the pair is
    # id_a, type_a, id_b, type_b, the four fields before distance and toi, the last two of
    # both contact dtypes.
    row = contacts.item(closest)
    return {'colliding_pairs': len(contacts) - near, 'near_pairs': near,
            'min_distance': smallest, 'min_distance_pair': row[-6:-2]}
