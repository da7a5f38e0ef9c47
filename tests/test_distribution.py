"""The physics distribution (issue 21, item 4): seeded samples, perturbations, new scene
parameters and their command-line options."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

if not os.environ.get("DISPLAY"):
    os.environ.setdefault("MUJOCO_GL", "egl")
pytest.importorskip("mujoco", reason="the sim extra (mujoco) is not installed")

from nonprehensile.errors import InputError
from nonprehensile.geometry.build import cube, prism
from nonprehensile.sim import SimParams, Simulator, pose_of_state, scene_xml
from nonprehensile.sim.distribution import (
    CUBE_VOLUME,
    DEFAULT_DISTRIBUTION,
    Perturbation,
    PhysicsDistribution,
    finger_noise,
)
from nonprehensile.states import State

CUBE = cube()


def test_samples_are_seeded_by_index_not_by_order() -> None:
    d = DEFAULT_DISTRIBUTION
    batch = d.samples(6, 7)
    # drawn alone, in another order, or from a later start: the same values
    assert d.sample(7, index=4).to_dict() == batch[4].to_dict()
    assert [s.to_dict() for s in d.samples(3, 7, start=3)] == [b.to_dict() for b in batch[3:]]
    assert d.samples(6, 8)[4].to_dict() != batch[4].to_dict()
    assert len({s.perturbation.noise_seed for s in batch}) == 6


def test_samples_stay_in_the_documented_ranges() -> None:
    d = DEFAULT_DISTRIBUTION
    vals = [s.values() for s in d.samples(400, 1)]
    want = {"friction_table": (0.3, 1.0), "friction_finger": (0.5, 1.2), "mass": (0.05, 0.4),
            "finger_radius": (0.005, 0.012), "stiffness": (600, 3000), "max_force": (8, 15),
            "contact_timeconst": (0.004, 0.02), "start_offset": (0, 0.003),
            "start_yaw": (-3, 3)}
    for name, (lo, hi) in want.items():
        x = np.array([v[name] for v in vals])
        assert x.min() >= lo and x.max() <= hi, name
        # uniform: the draws fill the range (not stuck at a default)
        assert x.max() - x.min() > 0.9 * (hi - lo), name
    assert all(v["tracking_noise"] == 0.0005 and v["finger_noise"] == 0.001 for v in vals)
    # uniform in the disc: about a quarter of the offsets within half the radius
    r = np.array([v["start_offset"] for v in vals])
    assert 0.15 < float(np.mean(r < 0.0015)) < 0.35


def test_a_generator_draws_too() -> None:
    rng = np.random.default_rng(3)
    a = DEFAULT_DISTRIBUTION.sample(rng, index=2)
    b = DEFAULT_DISTRIBUTION.sample(np.random.default_rng(3), index=2)
    assert a == b and a.seed == -1


def test_mass_scales_with_volume_for_other_objects() -> None:
    hexp = prism(6, 0.5, 1.0, name="hexprism")
    d = DEFAULT_DISTRIBUTION.for_object(hexp, 0.04)
    v = hexp.volume * 0.04**3
    assert d.mass == pytest.approx((0.05 * v / CUBE_VOLUME, 0.4 * v / CUBE_VOLUME))
    # the density range is the cube's: 400 - 3200 kg/m^3
    assert d.mass[0] / v == pytest.approx(400.0) and d.mass[1] / v == pytest.approx(3200.0)
    assert DEFAULT_DISTRIBUTION.for_object(CUBE, 0.05).mass == pytest.approx((0.05, 0.4))


@pytest.mark.parametrize("kw", [{"friction_table": (0.5, 0.3)},
                                {"mass": (float("nan"), 1.0)},
                                {"contact_timeconst": (0.0005, 0.02)},
                                {"start_yaw": -1.0}, {"finger_noise": 0.5}])
def test_bad_distributions_are_refused(kw: dict[str, object]) -> None:
    with pytest.raises(InputError):
        PhysicsDistribution(**kw)  # type: ignore[arg-type]


@settings(max_examples=30, deadline=None)
@given(dx=st.floats(-0.05, 0.05), dy=st.floats(-0.05, 0.05), yaw=st.floats(-45, 45),
       theta=st.floats(0, 359), face=st.sampled_from(["a", "b", "c"]))
def test_start_error_moves_the_centre_of_mass_and_turns_about_it(
        dx: float, dy: float, yaw: float, theta: float, face: str) -> None:
    pose = pose_of_state(CUBE, State(face, theta), (0.1, 0.2), 0.05)
    moved = Perturbation((dx, dy, yaw)).start_pose(pose)
    # the pose is consistent: the model's centre of mass lands on the stated com
    assert np.allclose(moved.to_world(CUBE.com), moved.com, atol=1e-12)
    assert np.allclose(moved.com - pose.com, [dx, dy, 0.0], atol=1e-12)
    # turned about the vertical by yaw: same tilt, heading changed by yaw
    rel = moved.rotation @ pose.rotation.T
    assert rel[2, 2] == pytest.approx(1.0)
    assert math.degrees(math.atan2(rel[1, 0], rel[0, 0])) == pytest.approx(yaw, abs=1e-9)


def test_finger_noise_has_the_stated_deviation_and_correlation() -> None:
    rng = np.random.default_rng(0)
    x = finger_noise(rng, 200_000, 1000.0, 0.001, tau=0.05)
    assert x.std(axis=0) == pytest.approx([0.001] * 3, rel=0.05)
    lag = 50  # one correlation time at 1 kHz: correlation e^-1
    c = np.mean(x[:-lag] * x[lag:], axis=0) / x.var(axis=0)
    assert c == pytest.approx([math.exp(-1)] * 3, abs=0.05)


def test_noise_streams_are_independent_and_reproducible() -> None:
    p = Perturbation(finger_noise=0.001, noise_seed=5)
    tg = {1: np.zeros((100, 3)), 2: np.zeros((100, 3))}
    a = p.finger_targets(tg, 120.0, "finger/step1")
    b = p.finger_targets(tg, 120.0, "finger/step1")
    c = p.finger_targets(tg, 120.0, "finger/step2")
    assert np.array_equal(a[1], b[1]) and not np.array_equal(a[1], c[1])
    assert not np.array_equal(a[1], a[2])
    assert np.array_equal(Perturbation().finger_targets(tg, 120.0)[1], tg[1])


@pytest.mark.parametrize("kw", [{"start_error": (0.0, 0.0, float("nan"))},
                                {"start_error": (0.2, 0.0, 0.0)}, {"tracking_noise": -1e-3},
                                {"finger_noise": 0.1}, {"noise_seed": -1}])
def test_bad_perturbations_are_refused(kw: dict[str, object]) -> None:
    with pytest.raises(InputError):
        Perturbation(**kw)  # type: ignore[arg-type]


def test_contact_timeconst_and_torsion_reach_the_scene() -> None:
    xml = scene_xml(CUBE, scale=0.05, n_fingers=2,
                    params=SimParams(contact_timeconst=0.004, torsional_friction=0.01))
    assert xml.count('solref="0.004 1"') == 5  # object-table and two pairs per finger
    assert xml.count("0.01 0.0001 0.0001") == 2
    with pytest.raises(InputError, match="two physics steps"):
        SimParams(contact_timeconst=0.0015)
    with pytest.raises(InputError, match="torsional_friction"):
        SimParams(torsional_friction=-0.1)


def test_a_stiffer_contact_sinks_less() -> None:
    sink = {}
    for tc in (0.004, 0.02):
        sim = Simulator(CUBE, scale=0.05, n_fingers=1, params=SimParams(contact_timeconst=tc))
        sim.run(pose_of_state(CUBE, State("a", 0), (0, 0), 0.05), {}, 100.0, settle=0.5)
        sink[tc] = 0.025 - float(sim.pose().com[2])
    # MuJoCo's contact spring: penetration at rest grows with the time constant squared
    assert 0 < sink[0.004] < sink[0.02] < 2e-4
    assert sink[0.02] / sink[0.004] == pytest.approx(25.0, rel=0.2)


def test_cli_physics_options_refuse_bad_values_in_one_line() -> None:
    from click.testing import CliRunner

    from nonprehensile.cli import main

    runner = CliRunner()
    base = ["simulate", "dataset", "cube", "--skill", "push-roll"]
    # the option's own name (cli.options.Number): the message names what the user typed
    for bad, word in [(["--force-limit", "nan"], "--force-limit"),
                      (["--contact-timeconst", "-1"], "--contact-timeconst"),
                      (["--start-error", "0", "0", "nan"], "--start-error"),
                      (["--start-error", "1", "0", "0"], "--start-error"),
                      (["--finger-noise", "-0.001"], "--finger-noise"),
                      (["--tracking-noise", "inf"], "--tracking-noise"),
                      (["--seed", "-1"], "--seed")]:
        res = runner.invoke(main, [*base, *bad])
        assert res.exit_code == 2, (bad, res.stderr)
        assert word in res.stderr and "Traceback" not in res.stderr
        assert len(res.stderr.strip().splitlines()) == 1, res.stderr
