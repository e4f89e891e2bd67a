"""core.parallel: work items on threads, one job begun beside the caller's work, and BLAS kept to one thread."""

import threading

import numpy as np
import pytest
import scipy.linalg  # noqa: F401  (loads SciPy's own BLAS, which must be limited too)
from test_detail import band_mesh, fine_albedo, lighting, render, ring_cameras
from threadpoolctl import threadpool_info, threadpool_limits

from core.evaluate.synthetic import sphere_scene
from core.geometry.bake import bake_view
from core.parallel import blas_on_one_thread, joined, prefetched, start, thread_map
from core.pipeline import Options, compute
from core.scene import SceneInputs, ViewInput
from core.solve.solver import SolverParams
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


def test_prefetched_makes_the_next_item_while_the_caller_uses_this_one():
    made = [threading.Event() for _ in range(4)]
    makers = set()

    def items():
        for i in range(4):
            makers.add(threading.get_ident())
            made[i].set()
            yield i

    out = []
    for i in prefetched(items(), threads=2):
        if i < 3:
            assert made[i + 1].wait(10)  # made while item i is in use: never set if it were made on demand
        out.append(i)
    assert out == [0, 1, 2, 3]
    assert makers and threading.get_ident() not in makers


def test_prefetched_with_one_thread_is_the_items_themselves():
    makers = []

    def items():
        for i in range(3):
            makers.append(threading.get_ident())
            yield i

    assert list(prefetched(items(), threads=1)) == [0, 1, 2]
    assert set(makers) == {threading.get_ident()}


def test_prefetched_stops_making_items_when_the_caller_stops():
    made = []

    def items():
        for i in range(100):
            made.append(i)
            yield i

    with pytest.raises(RuntimeError, match="cancelled"):
        for _ in prefetched(items(), threads=2):
            raise RuntimeError("cancelled")
    assert made in ([0], [0, 1])  # the one made ahead, if begun, was finished; no other was begun


def test_prefetched_raises_an_error_of_the_items_in_the_caller():
    def items():
        yield 1
        raise ValueError("unreadable photo")

    got = []
    with pytest.raises(ValueError, match="unreadable photo"):
        for i in prefetched(items(), threads=2):
            got.append(i)
    assert got == [1]


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
