"""Robustness sweeps, success rates and physics-informed planning (issue 21, items 5-7)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings, strategies as st
from scipy.optimize import brentq

from nonprehensile.cli import main
from nonprehensile.errors import InputError
from nonprehensile.inference import expand
from nonprehensile.io import read_skills
from nonprehensile.planning import NoPlanError, RobustnessCosts, plan
from nonprehensile.states import State, states_by_step
from nonprehensile.success_rates import (
    Rate,
    SuccessRates,
    TransitionKey,
    read_success_rates,
    wilson_interval,
)

ROOT = Path(__file__).resolve().parents[1]
CUBE_SKILLS = ROOT / "examples" / "cube_skills.json"


# ------------------------------------------------------------------------ Wilson interval
@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 400), frac=st.floats(0, 1))
def test_wilson_interval_solves_the_score_equation(n: int, frac: float) -> None:
    k = round(frac * n)
    lo, hi = wilson_interval(k, n)
    p_hat, z = k / n, 1.959963984540054

    # independent truth: the interval's ends are the roots of |p_hat - p| = z sqrt(p(1-p)/n)
    def score(p: float) -> float:
        return abs(p_hat - p) - z * math.sqrt(p * (1 - p) / n)

    # (p_hat itself is a root of neither side: bracket each root away from it)
    want_lo = 0.0 if k == 0 else brentq(score, 1e-15, p_hat - 1e-13)
    want_hi = 1.0 if k == n else brentq(score, p_hat + 1e-13, 1 - 1e-15)
    assert lo == pytest.approx(want_lo, abs=1e-9) and hi == pytest.approx(want_hi, abs=1e-9)
    assert 0.0 <= lo <= p_hat <= hi <= 1.0


def test_wilson_interval_textbook_values() -> None:
    assert wilson_interval(0, 20)[1] == pytest.approx(0.1611, abs=1e-4)
    assert wilson_interval(10, 20) == pytest.approx((0.2993, 0.7007), abs=1e-4)
    assert wilson_interval(0, 0) == (0.0, 1.0)
    with pytest.raises(InputError):
        wilson_interval(3, 2)


# ------------------------------------------------------------------------ the rates file
def _rates(entries: dict[tuple[str, str, str], tuple[int, int]], loop: str = "closed",
           obj: str = "cube") -> SuccessRates:
    return SuccessRates({(TransitionKey.of(s, State.parse(a), State.parse(b)), loop):
                         Rate(k, n) for (s, a, b), (k, n) in entries.items()}, obj, {"seed": 1})


def test_rates_file_round_trip(tmp_path: Path) -> None:
    r = _rates({("push-roll", "a:0", "d:0"): (17, 20), ("twist:reverse", "a:90", "a:0"):
                (20, 20)})
    path = r.write(tmp_path / "rates.json")
    back = read_success_rates(path)
    assert back.rates == r.rates and back.object == "cube" and back.meta["seed"] == 1
    # angles are normalised: 360 is 0
    assert back.get(TransitionKey.of("push-roll", State("a", 360.0), State("d", 0)),
                    "closed") == Rate(17, 20)


@pytest.mark.parametrize("doc", [
    {"format": "something-else"},
    {"format": "nonprehensile-success-rates/1", "object": "cube"},
    {"format": "nonprehensile-success-rates/1", "object": "cube",
     "transitions": [{"skill": "x", "from": {"face": "a"}, "to": {"face": "b", "theta": 0}}]},
    {"format": "nonprehensile-success-rates/1", "object": "cube",
     "transitions": [{"skill": "x", "from": {"face": "a", "theta": 0},
                      "to": {"face": "b", "theta": 0}, "closed": {"k": 5, "n": 3}}]},
    {"format": "nonprehensile-success-rates/1", "object": "cube",
     "transitions": [{"skill": "x", "from": {"face": "a", "theta": 0},
                      "to": {"face": "b", "theta": 0}, "open": {"k": 1.5, "n": 3}}]},
])
def test_bad_rates_files_are_refused(tmp_path: Path, doc: dict[str, object]) -> None:
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(InputError):
        read_success_rates(p)


# ------------------------------------------------------------------------ planning
@pytest.fixture(scope="module")
def cube() -> tuple[object, object]:
    poly, skills = read_skills(CUBE_SKILLS)
    return poly, expand(poly, skills, states_by_step(poly, 90))


def test_rates_change_the_route_and_the_plan_says_why(cube: tuple[object, object]) -> None:
    poly, exp = cube
    blind = plan(poly, exp, State("b", 200), State("e", 110))  # type: ignore[arg-type]
    first = blind.steps[0].transition
    bad = (first.skill.name, str(first.start), str(first.end))
    rates = _rates({bad: (3, 20)})
    got = plan(poly, exp, State("b", 200), State("e", 110),  # type: ignore[arg-type]
               robustness=RobustnessCosts(rates))
    used = [(s.transition.skill.name, s.transition.start, s.transition.end)
            for s in got.steps]
    assert (first.skill.name, first.start, first.end) not in used
    doc = got.to_dict()["robustness"]
    assert [a["skill"] for a in doc["avoided"]] == [bad[0]]
    assert "3/20" in doc["avoided"][0]["reason"] and "below the threshold 80" in \
        doc["avoided"][0]["reason"]
    assert doc["without_rates"][0]["skill"] == bad[0]
    assert doc["without_rates"][0]["success"]["k"] == 3
    # a threshold of 0 avoids nothing: the route is the rate-blind one
    same = plan(poly, exp, State("b", 200), State("e", 110),  # type: ignore[arg-type]
                robustness=RobustnessCosts(rates, threshold=0.0, weight=0.0))
    assert [s.transition.skill.name for s in same.steps] == \
        [s.transition.skill.name for s in blind.steps]
    assert "without_rates" not in same.to_dict()["robustness"]


def test_arc_cost_is_minus_log_of_the_smoothed_rate(cube: tuple[object, object]) -> None:
    poly, exp = cube
    blind = plan(poly, exp, State("a", 0), State("d", 0))  # type: ignore[arg-type]
    assert len(blind.steps) == 1
    t = blind.steps[0].transition
    rates = _rates({(t.skill.name, str(t.start), str(t.end)): (18, 20)})
    got = plan(poly, exp, State("a", 0), State("d", 0),  # type: ignore[arg-type]
               robustness=RobustnessCosts(rates, weight=2.0))
    assert got.steps[0].cost == pytest.approx(1.0 - 2.0 * math.log(19 / 22))
    assert got.steps[0].success_rate == Rate(18, 20)
    assert got.to_dict()["steps"][0]["success_rate"]["k"] == 18


def test_only_avoided_routes_raise_naming_them(cube: tuple[object, object]) -> None:
    poly, exp = cube
    # every transition out of b fails: nothing leaves b
    rates = _rates({(t.skill.name, str(t.start), str(t.end)): (0, 20)
                    for t in exp.transitions if t.start.face == "b"})  # type: ignore[attr-defined]
    with pytest.raises(NoPlanError, match="lower --robustness-threshold"):
        plan(poly, exp, State("b", 0), State("e", 90),  # type: ignore[arg-type]
             robustness=RobustnessCosts(rates))


def test_robustness_costs_check_their_inputs() -> None:
    rates = _rates({("push-roll", "a:0", "d:0"): (1, 2)}, loop="open")
    with pytest.raises(InputError, match="no closed-loop"):
        RobustnessCosts(rates)
    with pytest.raises(InputError, match="threshold"):
        RobustnessCosts(rates, loop="open", threshold=1.5)
    with pytest.raises(InputError, match="weight"):
        RobustnessCosts(rates, loop="open", weight=float("nan"))


def test_plan_cli_robustness(tmp_path: Path, cube: tuple[object, object]) -> None:
    poly, exp = cube
    blind = plan(poly, exp, State("b", 200), State("e", 110))  # type: ignore[arg-type]
    t = blind.steps[0].transition
    path = _rates({(t.skill.name, str(t.start), str(t.end)): (0, 20)}).write(
        tmp_path / "r.json")
    runner = CliRunner()
    base = ["plan", str(CUBE_SKILLS), "--from", "b:200", "--to", "e:110", "--step", "90"]
    res = runner.invoke(main, [*base, "--robustness", str(path), "--json"])
    assert res.exit_code == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["robustness"]["avoided"][0]["skill"] == t.skill.name
    res = runner.invoke(main, [*base, "--robustness", str(path)])
    assert res.exit_code == 0 and "avoided" in res.stdout and "0/20" in res.stdout
    other = _rates({("x", "a:0", "b:0"): (1, 1)}, obj="hexprism").write(tmp_path / "h.json")
    for bad, word in [(["--robustness", str(other)], "hexprism"),
                      (["--robustness", str(path), "--robustness-threshold", "nan"],
                       "robustness-threshold"),
                      (["--robustness", str(tmp_path / "missing.json")], "no such file")]:
        res = runner.invoke(main, [*base, *bad])
        assert res.exit_code == 2 and word in res.stderr, (bad, res.stderr)
        # one line naming the culprit (click's usage lines above an option's error)
        assert word in res.stderr.strip().splitlines()[-1] and "Traceback" not in res.stderr


# ------------------------------------------------------------------------ the sweep
if not os.environ.get("DISPLAY"):
    os.environ.setdefault("MUJOCO_GL", "egl")
mujoco = pytest.importorskip("mujoco", reason="the sim extra (mujoco) is not installed")

from nonprehensile.sim import SimParams, Simulator  # noqa: E402
from nonprehensile.sim.distribution import DEFAULT_DISTRIBUTION  # noqa: E402
from nonprehensile.sim.robustness import (  # noqa: E402
    SweepResult,
    SweepSpec,
    available_loops,
    run_sweep,
    transition_units,
)
from nonprehensile.sim.scene import SceneTuner  # noqa: E402


@pytest.fixture(scope="module")
def small_spec(cube: tuple[object, object]) -> SweepSpec:
    from nonprehensile.pipeline import motions_from_dataset

    poly, exp = cube
    ds, motions = motions_from_dataset("cube", skills=None, poly=poly)  # type: ignore[arg-type]
    units = transition_units(poly, exp, motions, scale=ds.scale, angle_tol=1e-6,
                             sources=["push-roll", "twist"])
    pick = units[:3]
    return SweepSpec(poly, ds.scale, tuple(pick),  # type: ignore[arg-type]
                     DEFAULT_DISTRIBUTION.for_object(poly, ds.scale),  # type: ignore[arg-type]
                     seed=3, n_samples=2, loops=("open",), fingers=dict(ds.fingers))


@pytest.fixture(scope="module")
def one_process_sweep(small_spec: SweepSpec) -> SweepResult:
    """The small sweep on one process: the reference the pool of two and Dask must equal
    (run once; the tests only read it)."""
    return run_sweep(small_spec, workers=1, chunk_size=1)


def test_a_sweep_is_the_same_on_one_process_or_two(small_spec: SweepSpec,
                                                   one_process_sweep: SweepResult) -> None:
    one = one_process_sweep
    two = run_sweep(small_spec, workers=2, chunk_size=1)
    assert [r.outcome() for r in one.records] == [r.outcome() for r in two.records]
    assert len(one.records) == 3 * 2
    # execution i of unit u ran sample i of stream u
    for r in one.records:
        assert r.values == small_spec.sample(r.unit, r.sample).values()
    assert len({r.values["friction_table"] for r in one.records}) == 6
    # the rates add up
    n = sum(v["open"].n for v in one.per_source().values())
    assert n == 6 == one.overall()["open"].n
    assert sum(b["open"].n for b in one.bins(3)["mass"]) == 6


def test_dask_local_cluster_equals_the_process_pool(small_spec: SweepSpec,
                                                   one_process_sweep: SweepResult) -> None:
    distributed = pytest.importorskip("distributed",
                                      reason="the scale extra (dask.distributed) is absent")
    pool = one_process_sweep
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        dsk = run_sweep(small_spec, scheduler=client, chunk_size=1)
    assert [r.outcome() for r in dsk.records] == [r.outcome() for r in pool.records]
    assert dsk.how == "dask"


def test_a_missing_loop_is_refused_never_replaced(small_spec: SweepSpec,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    from dataclasses import replace

    import nonprehensile.sim.robustness as rob

    # an installation without the closed-loop executor
    monkeypatch.setattr(rob, "EXECUTORS", {"open": rob.EXECUTORS["open"]})
    with pytest.raises(InputError, match="closed-loop execution is not available"):
        replace(small_spec, loops=("closed", "open"))
    assert rob.available_loops() == ["open"]


def test_retuning_a_scene_equals_compiling_it_whatever_ran_before() -> None:
    from nonprehensile.geometry.build import cube as make_cube

    poly = make_cube()
    samples = DEFAULT_DISTRIBUTION.samples(3, 11)

    def rounded(p: SimParams) -> SimParams:  # the scene document writes 6 digits
        from dataclasses import asdict

        return SimParams(**{k: float(f"{v:.6g}") for k, v in asdict(p).items()})

    a = Simulator(poly, scale=0.05, n_fingers=2)
    ta = SceneTuner(a.model, a.data, a.params)
    b = Simulator(poly, scale=0.05, n_fingers=2)
    tb = SceneTuner(b.model, b.data, b.params)
    target = rounded(samples[2].params)
    ta.tune(rounded(samples[0].params))
    ta.tune(rounded(samples[1].params))
    ta.tune(target)
    tb.tune(target)
    fresh = Simulator(poly, scale=0.05, n_fingers=2, params=target)
    names = ["body_mass", "body_inertia", "pair_friction", "pair_solref", "geom_size",
             "geom_rbound", "actuator_gainprm", "actuator_biasprm", "actuator_forcerange",
             "dof_damping", "dof_invweight0", "body_invweight0", "dof_M0"]
    for name in names:
        x, y, z = (np.asarray(getattr(s.model, name)) for s in (a, b, fresh))
        assert np.array_equal(x, y), name  # history leaves no trace
        # what the compiler makes (the document writes derived values, damping, to 6 digits)
        assert np.allclose(x, z, rtol=1e-5, atol=1e-12), name
    with pytest.raises(InputError, match="timestep"):
        ta.tune(SimParams(timestep=0.002))


def test_simulate_robustness_cli(tmp_path: Path) -> None:
    runner = CliRunner()
    base = ["simulate", "robustness", str(CUBE_SKILLS), "--step", "90"]
    rates, fig = tmp_path / "r.json", tmp_path / "f.png"
    res = runner.invoke(main, [*base, "--skill", "twist", "--samples", "1", "--loop", "open",
                               "--workers", "1", "--json", "-o", str(rates), "--figure",
                               str(fig)])
    assert res.exit_code == 0, res.stderr
    doc = json.loads(res.stdout)
    assert len(doc["units"]) == 24 and len(doc["records"]) == 24
    assert doc["overall"]["open"]["n"] == 24
    assert set(doc["per_source_skill"]) == {"twist"}
    assert fig.stat().st_size > 10_000
    back = read_success_rates(rates)
    assert sum(r.n for r in back.rates.values()) == 24 and back.loops() == ["open"]
    # the rates drive the planner
    res = runner.invoke(main, ["plan", str(CUBE_SKILLS), "--from", "a:0", "--to", "a:90",
                               "--step", "90", "--robustness", str(rates), "--json"])
    assert res.exit_code == 0, res.stderr
    assert json.loads(res.stdout)["robustness"]["loop"] == "open"
    for bad, word in [(["--samples", "0"], "--samples"), (["--seed", "-1"], "--seed"),
                      (["--from", "a:0"], "--to"), (["--skill", "nope"], "nope"),
                      (["--from", "a:0", "--to", "d:0", "-o", str(rates)], "-o"),
                      (["--workers", "2", "--scheduler", "tcp://x:1"], "--scheduler")]:
        res = runner.invoke(main, [*base, "--loop", "open", *bad])
        assert res.exit_code == 2, (bad, res.stderr)
        assert word in res.stderr.strip().splitlines()[-1] and "Traceback" not in res.stderr
    if "closed" not in available_loops():
        res = runner.invoke(main, [*base, "--loop", "closed"])
        assert res.exit_code == 2 and "not available" in res.stderr


def test_closed_and_open_loop_run_the_same_samples(small_spec: SweepSpec) -> None:
    from dataclasses import replace

    spec = replace(small_spec, units=small_spec.units[:1], n_samples=1,
                   loops=("closed", "open"))
    res = run_sweep(spec, workers=1)
    assert [r.loop for r in res.records] == ["closed", "open"]
    closed, opened = res.records
    assert closed.values == opened.values == spec.sample(0, 0).values()
    assert closed.physics_steps > 0 and opened.physics_steps > 0
    assert set(res.overall()) == {"closed", "open"}


def test_record_under_the_distribution_varies_the_scene_take_by_take(tmp_path: Path) -> None:
    from nonprehensile.sim.distribution import PhysicsDistribution
    from nonprehensile.sim.record import record_dataset

    ds, stats = record_dataset(CUBE_SKILLS, only=["push-roll"], n_per_skill=2, scale=0.05,
                               distribution=PhysicsDistribution(), seed=5)
    phys = stats["push-roll"]["physics"]
    assert len(phys) == 2 == len(ds.demonstrations)
    assert phys[0] != phys[1]
    for p in phys:
        assert 0.3 <= p["friction_table"] <= 1.0 and 0.05 <= p["mass"] <= 0.4
        assert 0.005 <= p["finger_radius"] <= 0.012


def test_an_executor_that_raises_is_a_failed_sample_not_a_lost_sweep(
        small_spec: SweepSpec, monkeypatch: pytest.MonkeyPatch) -> None:
    from dataclasses import replace

    import nonprehensile.sim.robustness as rob

    calls = {"n": 0}
    real = rob.EXECUTORS["open"]

    def flaky(worker: object, unit: object, sample: object) -> dict[str, object]:
        calls["n"] += 1
        if calls["n"] == 2:
            raise RuntimeError("boom")
        return real(worker, unit, sample)  # type: ignore[arg-type]

    monkeypatch.setitem(rob.EXECUTORS, "open", flaky)
    res = run_sweep(replace(small_spec, units=small_spec.units[:2], n_samples=1), workers=1)
    assert len(res.records) == 2  # nothing dropped
    bad = [r for r in res.records if not r.success and r.extra.get("executor_error")]
    assert len(bad) == 1 and "RuntimeError: boom" in bad[0].reason
    assert res.overall()["open"].n == 2
