"""core.parallel: work items on threads, one job begun beside the caller's work, and BLAS kept to one thread."""

import threading

import numpy as np
import pytest
import scipy.linalg  # noqa: F401  (loads SciPy's own BLAS, which must be limited too)
from test_detail import band_mesh, fine_albedo, lighting, render, ring_cameras
from threadpoolctl import threadpool_info, threadpool_limits

from core.evaluate.synthetic import sphere_scene
from core.geometry.bake import bake_view
from core.parallel import blas_on_one_thread, joined, start, streamed, thread_map
from core.pipeline import Options, compute
from core.scene import SceneInputs, ViewInput
from core.solve.params import SolverParams
from core.solve.stages import solve


def test_thread_map_keeps_the_order_and_reports_each_item_in_turn():
    done = []
    out = thread_map(lambda x: x * x, range(20), threads=3, done=done.append)
    assert out == [x * x for x in range(20)]
    assert done == list(range(20))


def test_thread_map_stops_when_done_raises():
    started = []
    go = threading.Event()

    def work(x):
        started.append(x)
        if x > 0:  # no later item can end before done(0) has run: the race cannot finish them all first
            assert go.wait(10)
        return x

    def done(i):
        if i == 0:
            go.set()
            raise RuntimeError("cancelled")

    with pytest.raises(RuntimeError, match="cancelled"):
        thread_map(work, range(1000), threads=2, done=done)
    assert len(started) < 1000  # the items not yet started were dropped


def test_start_runs_beside_the_caller_and_gives_its_result():
    release = threading.Event()
    main = threading.get_ident()

    def job(x):
        assert release.wait(10)  # only returns once the caller has gone on
        return x + 1, threading.get_ident()

    future = start(job, 41, threads=2)
    release.set()
    value, ident = future.result(timeout=10)
    assert value == 42 and ident != main


def test_start_with_one_thread_runs_now_in_the_calling_thread():
    ran = []
    future = start(lambda: ran.append(threading.get_ident()) or "ok", threads=1)
    assert ran == [threading.get_ident()] and future.result() == "ok"


@pytest.mark.parametrize("threads", [1, 2])
def test_start_raises_the_jobs_error_from_result(threads):
    def job():
        raise ValueError("no triangle covers any texel")

    future = start(job, threads=threads)
    with pytest.raises(ValueError, match="no triangle"):
        future.result(timeout=10)


def test_a_failing_block_waits_for_its_job_so_no_thread_outlives_it():
    release = threading.Event()

    def job():
        release.wait(10)
        return "layout"

    future = start(job, threads=2)
    with pytest.raises(KeyError):
        with joined(future):
            threading.Timer(0.2, release.set).start()  # the job ends only after the block has raised
            raise KeyError("cancelled")
    assert future.done() and future.result() == "layout"


def test_a_block_that_goes_through_does_not_wait():
    release = threading.Event()
    future = start(lambda: release.wait(10), threads=2)
    with joined(future) as job:
        assert job is future
    assert not future.done()  # its result is the caller's to wait for
    release.set()
    assert future.result(timeout=10)


def test_streamed_works_on_the_next_items_while_the_caller_uses_this_one():
    begun = [threading.Event() for _ in range(6)]
    workers, drawn = set(), []

    def work(i):
        workers.add(threading.get_ident())
        begun[i].set()
        return i * i

    def items():
        for i in range(6):
            drawn.append(i)
            yield i

    out = []
    for k, r in enumerate(streamed(work, items(), threads=2)):
        for j in range(k + 1, min(k + 3, 6)):  # two at work while result k is in use: never if made on demand
            assert begun[j].wait(10)
        assert len(drawn) <= k + 3  # and one more at most drawn
        out.append(r)
    assert out == [i * i for i in range(6)]
    assert workers and threading.get_ident() not in workers


def test_streamed_with_one_thread_is_map():
    where = []

    def work(i):
        where.append(threading.get_ident())
        return i + 1

    assert list(streamed(work, range(3), threads=1)) == [1, 2, 3]
    assert set(where) == {threading.get_ident()}


def test_streamed_begins_no_more_items_when_the_caller_stops():
    begun = []
    before = threading.active_count()
    with pytest.raises(RuntimeError, match="cancelled"):
        for _ in streamed(begun.append, range(100), threads=2):
            raise RuntimeError("cancelled")
    assert len(begun) <= 3  # the items drawn ahead, if begun, were finished; no other was begun
    assert threading.active_count() == before


def test_streamed_raises_an_error_in_the_caller_at_its_turn():
    def work(i):
        if i == 1:
            raise ValueError("unreadable photo")
        return i

    got = []
    with pytest.raises(ValueError, match="unreadable photo"):
        for i in streamed(work, range(5), threads=2):
            got.append(i)
    assert got == [0]


def blas_threads():
    """The thread count of every BLAS library loaded (NumPy's and SciPy's OpenBLAS here)."""
    return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]


def test_blas_is_on_one_thread_within_the_block_and_as_before_after_it():
    with threadpool_limits(limits=2, user_api="blas"):  # the tests run with OPENBLAS_NUM_THREADS=1
        assert len(blas_threads()) >= 2 and set(blas_threads()) == {2}
        with blas_on_one_thread():
            assert set(blas_threads()) == {1}
            np.ones((300, 300)) @ np.ones((300, 300))
        assert set(blas_threads()) == {2}
        with pytest.raises(RuntimeError), blas_on_one_thread():
            raise RuntimeError("a failed run")
        assert set(blas_threads()) == {2}


def test_the_solver_runs_with_blas_on_one_thread():
    problem = sphere_scene(n_views=4, height=40, width=50, texture_size=16, seed=2).problem
    seen = []
    with threadpool_limits(limits=2, user_api="blas"):
        solve(problem, SolverParams(max_iter=2, threads=2), progress=lambda f, m: seen.append(blas_threads()))
        after = blas_threads()
    assert seen and all(set(b) == {1} for b in seen)
    assert set(after) == {2}


def test_the_pipeline_runs_with_blas_on_one_thread():
    mesh, cams = band_mesh(), ring_cameras(120, 90)[:4]
    photos = [render(c, mesh, fine_albedo(), lighting()) for c in cams]
    views = [ViewInput(name=f"c{i}", camera=c, photo=p, source="test") for i, (c, p) in enumerate(zip(cams, photos))]
    seen = []
    with threadpool_limits(limits=2, user_api="blas"):
        compute(
            Options(texture_size=32, max_iter=2, threads=2),
            SceneInputs(object_name="band", mesh=mesh, views=views),
            [bake_view(c, mesh) for c in cams],
            progress=lambda f, m: seen.append(blas_threads()),
        )
        after = blas_threads()
    assert len(seen) > 5 and all(set(b) == {1} for b in seen)
    assert set(after) == {2}
