"""Time left, the progress bar's text and the headless progress lines (core.progress)."""

import io

import pytest

from core.evaluate.synthetic import sphere_scene
from core.progress import ProgressPrinter, ProgressState, TimeLeft, format_time_left, short_message, stage_progress
from core.solve.params import SolverParams
from core.solve.stages import solve


class Clock:
    """A clock the test moves by hand."""

    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


def test_time_left_is_none_early_then_follows_a_steady_rate():
    t = TimeLeft(warmup=2.0, min_progress=0.01)
    assert t.update(0.3, 10.0) is None  # the first pair only starts the clock
    assert t.update(0.305, 10.5) is None  # too soon, too little progress
    assert t.update(0.32, 11.0) is None  # still in the warm-up
    # 0.05 of the run every second from 0.3: at 0.5 (t=14) there are 10 s left.
    assert t.update(0.5, 14.0) == pytest.approx(10.0)
    for k in range(1, 5):
        assert t.update(0.5 + 0.05 * k, 14.0 + k) == pytest.approx(10.0 - k)
    assert t.update(1.0, 30.0) == 0.0


def test_time_left_is_smoothed_and_counts_down_between_updates():
    t = TimeLeft(warmup=0.0, min_progress=0.0, smoothing=0.3)
    t.update(0.0, 0.0)
    assert t.update(0.1, 1.0) == pytest.approx(9.0)
    # A slow step (0.1 -> 0.2 in 3 s) makes the raw estimate jump from 9 s to 16 s: the estimate moves a share
    # of the way from the last one (aged by the 3 s), not all of it.
    raw = 4.0 * 0.8 / 0.2
    smoothed = t.update(0.2, 4.0)
    aged = 9.0 - 3.0
    assert smoothed == pytest.approx(aged + 0.3 * (raw - aged))
    assert t.estimate(6.0) == pytest.approx(smoothed - 2.0)  # counts down without updates
    assert t.estimate(1000.0) == 0.0
    with pytest.raises(ValueError):
        TimeLeft(smoothing=0.0)


def test_time_left_does_not_count_what_came_before_its_first_pair():
    # The GUI's bake (0 -> 0.3) happens before the estimate starts: the rate is that of the rest.
    t = TimeLeft(warmup=0.0, min_progress=0.0)
    t.update(0.3, 50.0)
    assert t.update(0.65, 55.0) == pytest.approx(5.0)


@pytest.mark.parametrize(
    "seconds,text",
    [
        (None, ""),
        (0.4, ""),
        (3, "a few seconds left"),
        (34, "about 35 s left"),
        (59, "about 60 s left"),
        (125, "about 2 min left"),
        (4000, "about 1 h 07 min left"),
    ],
)
def test_format_time_left(seconds, text):
    assert format_time_left(seconds) == text


def test_short_message_on_the_solvers_own_messages():
    scene = sphere_scene(n_views=3, height=240, width=320, texture_size=128, seed=1)
    seen = []
    solve(
        scene.problem,
        SolverParams(levels=3, coarse_iter=2, max_iter=3, min_iter=3),
        progress=stage_progress(lambda f, m: seen.append(m), "solve"),
    )
    short = [short_message(m, max_iter=3) for m in seen]
    assert any(m.startswith("solve: coarse level") for m in seen)
    assert "solve: iteration 1/3" in short and "solve: iteration 3/3" in short
    coarse = [m for m in short if m.startswith("solve: coarse level")]
    assert coarse and all("energy" not in m and "/" not in m for m in coarse)
    assert any(m.endswith(", iteration 2") for m in coarse)
    # Nested coarse levels name the one being solved.
    assert (
        short_message("solve: coarse level 64: coarse level 32: iteration 4, energy 2", 3)
        == "solve: coarse level 32, iteration 4"
    )
    assert short_message("bake: baking cam (2/4)", 3) == "bake: baking cam (2/4)"
    assert short_message("solve: iteration 7, energy 1.5e+03") == "solve: iteration 7"


def test_progress_state_gives_the_bar():
    clock = Clock()
    state = ProgressState(max_iter=40, clock=clock)
    assert state.bar() == (0.0, "starting")
    state(0.3, "solve: building the texture-domain problem")
    clock.now += 10
    state(0.3 + 0.6 * 12 / 40, "solve: iteration 12, energy 3.5")
    factor, text = state.bar()
    assert factor == pytest.approx(0.48)
    # 0.18 of the run in 10 s: 0.52 more takes about 29 s.
    assert text == "solve: iteration 12/40 — about 30 s left"
    state(0.5)  # no message: the last one stays
    assert state.bar()[1].startswith("solve: iteration 12/40")
    state(7.0, "write: done")
    assert state.bar() == (1.0, "write: done")


def test_progress_printer_adds_the_time_left():
    clock, out = Clock(), io.StringIO()
    p = ProgressPrinter(out, step=0.05, clock=clock)
    p(0.0, "bake: a")
    clock.now += 5
    p(0.25, "bake: b")
    clock.now += 5
    p(0.5, "solve: c")
    assert out.getvalue().splitlines() == [
        "delight:   0.0% bake: a",
        "delight:  25.0% bake: b (about 15 s left)",
        "delight:  50.0% solve: c (about 10 s left)",
    ]


def test_time_left_measures_the_rate_from_the_end_of_the_gather():
    # The photos take 0 -> 0.05 in 40 s; then the run goes at 0.01 a second, but its solve spends 10 s building
    # its problem before its first step: the rate since the gather holds through it.
    t = TimeLeft(warmup=0.0, min_progress=0.0, smoothing=1.0)
    t.update(0.0, 0.0, "gather")
    assert t.update(0.05, 40.0, "gather") is None
    t.update(0.05, 40.0, "bake")
    assert t.update(0.25, 60.0, "bake") == pytest.approx(75.0)  # 0.75 left at 0.01 a second
    assert t.update(0.25, 70.0, "solve") == pytest.approx(0.75 * 30 / 0.2)  # 10 s of no progress slow it
    assert t.update(0.45, 80.0, "solve") == pytest.approx(0.55 * 40 / 0.4)
    assert t.update(0.85, 120.0, "detail") == pytest.approx(0.15 * 80 / 0.8)  # a new stage goes on with it
    # Without stages the rate is the run's since the first pair.
    plain = TimeLeft(warmup=0.0, min_progress=0.0, smoothing=1.0)
    plain.update(0.1, 0.0)
    plain.update(0.4, 300.0)
    assert plain.update(0.52, 312.0) == pytest.approx(312.0 * 0.48 / 0.42)


def test_progress_lines_name_their_stage():
    from core.progress import stage_of

    assert stage_of("detail: photo 3/50") == "detail" and stage_of("solve") == "solve"
    assert stage_of("reading") is None and stage_of("") is None


def test_shares_are_consecutive_and_in_proportion():
    from core.progress import shares

    out = shares({"a": 1.0, "b": 0.0, "c": 3.0}, 0.2, 0.6)
    assert out["a"] == pytest.approx((0.2, 0.3)) and out["b"] == pytest.approx((0.3, 0.3))
    assert out["c"] == (pytest.approx(0.3), 0.6)  # the last ends at the end, exactly


def test_piecewise_redraws_a_callees_shares():
    from core.progress import piecewise

    seen = []
    report = piecewise(lambda f, m="": seen.append((round(f, 6), m)), [(0.0, 0.1), (0.6, 0.3), (1.0, 0.9)])
    for x in (0.0, 0.3, 0.6, 0.8, 1.0, 1.5, -0.5):
        report(x, "m")
    assert [f for f, _ in seen] == [0.1, 0.2, 0.3, 0.6, 0.9, 0.9, 0.1] and {m for _, m in seen} == {"m"}
    piecewise(None, [(0.0, 0.0), (1.0, 1.0)])(0.5)  # no callback: nothing


def test_step_counter_counts_the_steps_of_several_threads():
    from concurrent.futures import ThreadPoolExecutor

    from core.progress import StepCounter

    seen = []
    steps = StepCounter(lambda f, m="": seen.append(f), 300, "searching")
    with ThreadPoolExecutor(3) as pool:
        list(pool.map(lambda _: [steps.add() for _ in range(100)], range(3)))
    assert seen == sorted(seen) and seen[-1] == 1.0 and len(seen) == 300
    steps.add(5)  # more than the total: stays at the end
    assert seen[-1] == 1.0


def test_a_solve_that_stops_early_moves_the_bar_at_the_pace_of_its_convergence():
    from core.solve.solver import _CONVERGED_SHARE, converged_share, solve_joint

    assert converged_share(0.1, 0.1, 1e-4) == 0.0 and converged_share(0.1, 1e-4, 1e-4) == _CONVERGED_SHARE
    assert converged_share(0.1, (0.1 * 1e-4) ** 0.5, 1e-4) == pytest.approx(_CONVERGED_SHARE / 2)
    assert converged_share(1e-5, 1e-6, 1e-4) == 0.0  # started below the stop: nothing to measure

    scene = sphere_scene(n_views=4, height=60, width=80, texture_size=32, seed=1)
    seen = []
    params = SolverParams(lam=5.0, max_iter=400, levels=1, tol=1e-3)
    r = solve_joint(scene.problem, params, progress=lambda f, m="": seen.append((f, m)))
    steps = [f for f, m in seen if m.startswith("iteration")]
    assert 5 < r.iterations < 100, r.iterations  # stopped by the test, far before max_iter
    # Measured: the bar at 0.30 after 21 and 0.95 after 42 iterations, where 42 / 400 of them drew 0.1.
    assert steps == sorted(steps) and steps[-1] > 0.8 and steps[len(steps) // 2] > 0.2, steps
