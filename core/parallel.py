"""How many threads a run uses, and the one way the core runs independent work items on them.

NumPy's large array operations and SciPy's sparse products release the GIL, so plain threads run them on
several cores at once without copying the arrays into other processes. The BLAS that NumPy and SciPy link
(OpenBLAS) would start threads of its own for each large product, on the same cores; the entry points run under
:func:`blas_on_one_thread`.
"""

from __future__ import annotations

import collections
import contextlib
import itertools
import os
from concurrent.futures import Future, ThreadPoolExecutor, wait

__all__ = ["available_cores", "blas_on_one_thread", "joined", "resolve_threads", "start", "streamed", "thread_map"]


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity where the system has one), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no affinity on this system (macOS, Windows)
        return max(1, os.cpu_count() or 1)


def resolve_threads(threads: int | None) -> int:
    """``threads``, or :func:`available_cores` for None; at least 1."""
    return available_cores() if threads is None else max(1, int(threads))


def thread_map(fn, items, threads: int | None = None, done=None) -> list:
    """``[fn(x) for x in items]``, on up to ``threads`` threads (None: every available core), in order.

    ``done(i)``, if given, is called in the calling thread once item i is done, in order (for progress and
    cancelling: an exception it raises drops the items not yet started and is raised). With one thread (or
    one item) everything runs in the calling thread, with no pool.
    """
    items = list(items)
    n = min(resolve_threads(threads), len(items))
    out = []
    if n <= 1:
        for i, x in enumerate(items):
            out.append(fn(x))
            if done is not None:
                done(i)
        return out
    pool = ThreadPoolExecutor(max_workers=n)
    try:
        futures = [pool.submit(fn, x) for x in items]
        for i, f in enumerate(futures):
            out.append(f.result())
            if done is not None:
                done(i)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    return out


def start(fn, *args, threads: int | None = None) -> Future:
    """``fn(*args)`` begun on a thread of its own, to overlap with the caller's work; its :class:`Future`.

    With one thread (``threads``, as :func:`resolve_threads`) it runs now, in the calling thread. Its exception,
    if any, is raised by ``result()``.
    """
    if resolve_threads(threads) <= 1:
        done = Future()
        try:
            done.set_result(fn(*args))
        except Exception as e:
            done.set_exception(e)
        return done
    pool = ThreadPoolExecutor(max_workers=1)
    try:
        return pool.submit(fn, *args)
    finally:
        pool.shutdown(wait=False)  # the thread ends once fn returns


@contextlib.contextmanager
def joined(future: Future):
    """``with joined(start(...)) as job:``: if the block raises, the job is waited for before the error goes on.

    So that a failed or cancelled run leaves no thread of its own working behind it.
    """
    try:
        yield future
    except BaseException:
        wait([future])
        raise


def streamed(fn, items, threads: int | None = None):
    """``fn(x)`` for each item of the iterable ``items``, yielded in order, worked on by up to ``threads`` threads.

    For a loop over more work than memory holds at once (the detail stage's bands of full-resolution photos):
    items are drawn from ``items`` in the calling thread, and only as threads come free, so while the caller
    uses one result, ``threads`` items are begun and one more at most is drawn. With one thread (``threads``, as
    :func:`resolve_threads`) it is ``map(fn, items)``. An error of ``fn`` is raised in the caller at its item's
    turn. When the caller stops early (an error, a cancel), the items begun are waited for and no other is begun.
    """
    n = resolve_threads(threads)
    if n <= 1:
        yield from map(fn, items)
        return
    it = iter(items)
    pool = ThreadPoolExecutor(max_workers=n)
    pending = collections.deque()
    try:
        while True:
            # n items at work while the caller uses the one before them.
            for x in itertools.islice(it, n + 1 - len(pending)):
                pending.append(pool.submit(fn, x))
            if not pending:
                return
            yield pending.popleft().result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


@contextlib.contextmanager
def blas_on_one_thread():
    """While the block runs, the BLAS libraries loaded (OpenBLAS, MKL, ...) use one thread each; as a decorator, too.

    The core gives the cores out itself. A BLAS that also starts a thread per core for each matrix product
    oversubscribes them, and its idle threads spin while the pools wait: a 13 x 12 MP run took 1.4 times as
    long (docs/measurements.md). The limits before the block are restored after it. Without threadpoolctl
    (shipped with the add-on, in requirements.txt) this does nothing.
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        yield
        return
    with threadpool_limits(limits=1, user_api="blas"):
        yield
