"""Workers: ranges cover the loop once, in order, on several threads; errors come back."""
import random
import threading
import time

import pytest

from collision_node.pipeline.workers import CHUNKS_PER_THREAD, Workers


@pytest.mark.parametrize('threads', [1, 2, 3])
@pytest.mark.parametrize('count, min_chunk', [(0, 1), (1, 1), (10, 3), (1000, 1), (1000, 400),
                                              (5, 100)])
def test_ranges_cover_every_item_once_in_order(threads, count, min_chunk):
    workers = Workers(threads)
    calls = []
    results = workers.map_ranges(lambda k, start, stop: calls.append((k, start, stop)) or k,
                                 count, min_chunk)
    workers.close()
    calls.sort()
    assert [k for k, _, _ in calls] == list(range(len(calls))) == results
    bounds = [start for _, start, _ in calls] + [calls[-1][2]]
    assert bounds[0] == 0 and bounds[-1] == count
    assert all(stop == start for (_, _, stop), (_, start, _) in zip(calls, calls[1:]))
    assert len(calls) <= workers.max_chunks == CHUNKS_PER_THREAD * threads
    if threads == 1 or count < 2 * min_chunk:
        assert len(calls) == 1
    else:
        assert all(stop - start >= min_chunk for _, start, stop in calls)


def test_chunks_run_on_several_threads():
    workers = Workers(2)
    seen = set()

    def task(k, start, stop):
        seen.add(threading.get_ident())
        time.sleep(0.02)  # releases the GIL, as a nogil kernel does
        return stop - start

    assert sum(workers.map_ranges(task, 800, 100)) == 800
    workers.close()
    assert len(seen) == 2


def test_an_error_in_a_helper_is_raised_after_every_chunk_is_done():
    workers = Workers(2)
    done = []

    def task(k, start, stop):
        time.sleep(0.01)
        if k == 1:
            raise ZeroDivisionError('chunk 1')
        done.append(k)

    with pytest.raises(ZeroDivisionError, match='chunk 1'):
        workers.map_ranges(task, 800, 100)
    assert sorted(done) == [0, 2, 3, 4, 5, 6, 7]
    workers.close()


@pytest.mark.parametrize('threads', [0, -1, 1.5, True, '2', None])
def test_threads_must_be_a_positive_integer(threads):
    with pytest.raises(ValueError, match='threads must be a positive integer'):
        Workers(threads)


def test_back_to_back_loops_wait_for_every_chunk():
    # Loops of uneven chunks follow each other at once: a helper still finishing one loop must
    # never let the caller return from it, nor the next loop miss a chunk.
    rng = random.Random(7)
    workers = Workers(3)
    for loop in range(300):
        count = rng.randint(0, 40)

        def task(k, start, stop):
            if rng.random() < 0.1:
                time.sleep(0.0005)
            return list(range(start, stop))

        results = workers.map_ranges(task, count, rng.randint(1, 6))
        assert [i for chunk in results for i in chunk] == list(range(count)), loop
    workers.close()
