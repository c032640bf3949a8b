"""The kernels' thread pools: parts done, work beside, errors raised, and a forked child that works."""

from __future__ import annotations

import multiprocessing
import time

import numpy as np
import pytest

from model.octree.parallel import run_parts, split


def test_every_part_is_done_once():
    seen = np.zeros(1000, int)

    def work(a: int, b: int) -> None:
        seen[a:b] += 1

    for n, parts in ((1000, 4), (1000, 1), (3, 8)):
        seen[:] = 0
        run_parts(work, n, parts)
        assert (seen[:n] == 1).all()
    assert split(10, 3) == [0, 3, 6, 10]


def test_an_error_in_a_part_is_raised():
    def work(a: int, b: int) -> None:
        if a > 0:
            raise ValueError("part failed")

    with pytest.raises(ValueError, match="part failed"):
        run_parts(work, 100, 2)


def _child(queue) -> None:
    from model.octree.parallel import beside

    out = np.zeros(100, int)

    def work(a: int, b: int) -> None:
        out[a:b] = 1

    run_parts(work, 100, 2)
    queue.put(int(out.sum()) + beside(lambda: 7).result(timeout=20))


def test_a_forked_child_uses_a_pool_of_its_own():
    """A data loader's worker forked after the parent used the pool: the parent's pool has no
    threads in the child, which would wait for ever on it."""
    from model.octree.parallel import beside

    run_parts(lambda a, b: time.sleep(0.05), 10, 2)      # the parent's pools have their threads,
    beside(lambda: time.sleep(0.05)).result()
    time.sleep(0.2)                                       # idle by now
    ctx = multiprocessing.get_context("fork")
    queue = ctx.Queue()
    child = ctx.Process(target=_child, args=(queue,))
    child.start()
    child.join(30)
    if child.exitcode is None:
        child.kill()
    assert child.exitcode == 0, "the forked child did not finish (a pool without threads)"
    assert queue.get(timeout=5) == 107


def test_work_beside_returns_its_result_and_its_error_where_it_is_waited_on():
    from model.octree.parallel import beside

    assert beside(lambda: 6 * 7).result(timeout=30) == 42
    failed = beside(lambda: int("not a number"))
    with pytest.raises(ValueError, match="not a number"):
        failed.result(timeout=30)


def test_work_beside_may_share_itself_between_the_pool_s_threads():
    """Work beside runs in a pool of its own: two callers' work, running at once, each sharing
    itself through run_parts, finishes (were it run in the kernels' pool, both of its threads would
    wait on parts that no thread is left to run)."""
    import threading

    from model.octree.parallel import WORKERS, beside

    if WORKERS < 2:
        pytest.skip("one core: work beside runs where it is asked")
    both = threading.Barrier(2, timeout=10)

    def work() -> int:
        both.wait()
        out = np.zeros(100, int)
        run_parts(lambda a, b: out.__setitem__(slice(a, b), 1), 100, 2)
        return int(out.sum())

    first, second = beside(work), beside(work)
    assert first.result(timeout=30) == second.result(timeout=30) == 100


def test_work_beside_of_two_callers_runs_at_once():
    """Two threads' work beside does not queue behind one another: each waits for the other."""
    import threading

    from model.octree.parallel import WORKERS, beside

    if WORKERS < 2:
        pytest.skip("one core: work beside runs where it is asked")
    both = threading.Barrier(2, timeout=10)
    first, second = beside(both.wait), beside(both.wait)
    assert {first.result(timeout=30), second.result(timeout=30)} == {0, 1}
