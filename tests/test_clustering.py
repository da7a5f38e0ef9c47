"""HilbertClusterer: the paper's recipe step by step, ours, streams, persistence, bad input."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from hilbertcurve.hilbertcurve import HilbertCurve
from hypothesis import given, settings, strategies as st
from sklearn.decomposition import PCA
from sklearn.metrics import adjusted_rand_score

from nonprehensile.errors import InputError
from nonprehensile.motion import flatten
from nonprehensile.motion.clustering import HilbertClusterer
from nonprehensile.motion.store import SQLiteStore


def _skill_trajectories(n_per: int, seed: int, n_skills: int = 2) -> tuple[np.ndarray,
                                                                            np.ndarray]:
    """Fingertip paths of ``n_skills`` skills (different arcs), 400 points, flattened."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, 400)
    rows, y = [], []
    for s in range(n_skills):
        for _ in range(n_per):
            amp = 0.03 * (1 + s) + rng.normal(scale=0.002)
            path = np.stack([0.1 * t, amp * np.sin(np.pi * t * (1 + s)),
                             0.02 * t**2 + rng.normal(scale=0.001)], axis=1)
            path = path + rng.normal(scale=0.001, size=path.shape)
            rows.append(flatten(path[:, None, :]))
            y.append(s)
    return np.array(rows), np.array(y)


def _blobs(n: int, k: int, d: int, seed: int, sep: float = 6.0) -> tuple[np.ndarray,
                                                                         np.ndarray]:
    rng = np.random.default_rng(seed)
    centers = rng.normal(scale=sep, size=(k, d))
    y = rng.integers(0, k, n)
    return centers[y] + rng.normal(size=(n, d)), y


# --------------------------------------------------------------------------- paper


def _paper_reference(x: np.ndarray, k: int) -> tuple[list[int], np.ndarray]:
    """The paper's recipe with independent tools: scikit-learn's PCA, hilbertcurve."""
    pca = PCA(n_components=2).fit(x)
    comp = pca.components_.copy()
    # the sign convention HilbertClusterer documents: largest loading positive
    idx = np.argmax(np.abs(comp), axis=1)
    comp *= np.sign(comp[np.arange(2), idx])[:, None]
    z = (x - x.mean(axis=0)) @ comp.T
    lo, hi = z.min(axis=0), z.max(axis=0)
    grid = np.minimum(np.floor((z - lo) / (hi - lo) * 32), 31).astype(int)  # 0..31
    keys = HilbertCurve(5, 2).distances_from_points(grid.tolist())
    srt = np.sort(keys)
    gaps = np.diff(srt)
    cut_at = np.sort(np.argsort(-gaps, kind="stable")[: k - 1])
    starts = srt[cut_at + 1]
    labels = np.searchsorted(starts, keys, side="right")
    return list(keys), labels


def test_paper_method_reproduces_the_recipe() -> None:
    x, y = _skill_trajectories(30, seed=1)  # the paper's 60 trajectories, 30 per skill
    c = HilbertClusterer(2, method="paper", random_state=0).fit(x)
    keys, labels = _paper_reference(x, 2)
    assert c.order_ == 5 and c.components_.shape == (2, 1200)
    assert [int(v) for v in c.transform(x)] == keys
    assert c.store.keys() == keys
    np.testing.assert_array_equal(c.labels_, labels)
    assert adjusted_rand_score(y, c.labels_) == 1.0


def test_paper_registers_without_reclustering_then_recalibrates() -> None:
    x, _ = _skill_trajectories(30, seed=2)
    rng = np.random.default_rng(0)
    x = x[rng.permutation(60)]
    c = HilbertClusterer(2, method="paper", init_size=20, recalibration_period=20,
                         recalibration_size=15, random_state=3)
    c.partial_fit(x[:20])
    first = c.labels_.copy()
    keys_before = c.store.keys()
    c.partial_fit(x[20:39])
    # registered by the run its key falls in; nothing stored moved
    assert c.n_recalibrations_ == 1
    assert c.store.keys()[:20] == keys_before
    np.testing.assert_array_equal(c.labels_[:20], first)
    np.testing.assert_array_equal(c.labels_[20:], c.predict(x[20:39]))
    c.partial_fit(x[39:40])  # the 40th sample completes the period
    assert c.n_recalibrations_ == 2
    # re-keyed with the recalibrated components, bounds from every stored sample
    assert c.store.keys() == [int(v) for v in c.transform(x[:40])]
    assert not c.outside(x[:40]).any()


# --------------------------------------------------------------------------- ours


@pytest.mark.parametrize("method", ["micro", "runs"])
def test_clusters_separated_skills_in_batch_and_streams(method: str) -> None:
    x, y = _blobs(600, 5, 40, seed=4, sep=1.0)
    batch = HilbertClusterer(5, method=method, random_state=0).fit(x)  # type: ignore[arg-type]
    assert adjusted_rand_score(y, batch.labels_) > 0.99
    order = np.argsort(y, kind="stable")
    for idx in (np.random.default_rng(1).permutation(600), order):
        c = HilbertClusterer(5, method=method, init_size=60,  # type: ignore[arg-type]
                             random_state=0)
        for s in range(0, 600, 25):
            c.partial_fit(x[idx[s : s + 25]])
        assert adjusted_rand_score(y[idx], c.labels_) > 0.97
    if method == "runs":
        assert c.n_clusters_ == 5


@pytest.mark.parametrize("method", ["micro", "runs"])
def test_chooses_the_number_of_clusters(method: str) -> None:
    x, y = _blobs(300, 4, 10, seed=5)
    c = HilbertClusterer(None, method=method, random_state=0).fit(x)  # type: ignore[arg-type]
    assert c.n_clusters_ == 4 and adjusted_rand_score(y, c.labels_) == 1.0


@pytest.fixture(scope="module")
def whole_fits() -> dict[str, HilbertClusterer]:
    """One batch fit per method for every generated cut list (it does not depend on them;
    the tests only read it)."""
    return {}


@pytest.mark.parametrize("method", ["micro", "runs", "paper"])
@settings(max_examples=8)
@given(cuts=st.lists(st.integers(1, 239), max_size=4, unique=True))
def test_fit_equals_partial_fit_sequence(method: str, cuts: list[int],
                                         whole_fits: dict[str, HilbertClusterer]) -> None:
    x, _ = _blobs(240, 3, 12, seed=6, sep=2.0)
    kw = {"method": method, "init_size": 30, "random_state": 7}
    if method not in whole_fits:
        whole_fits[method] = HilbertClusterer(3, **kw).fit(x)
    whole = whole_fits[method]
    parts = HilbertClusterer(3, **kw)
    bounds = [0, *sorted(cuts), 240]
    for a, b in itertools.pairwise(bounds):
        parts.partial_fit(x[a:b])
    np.testing.assert_array_equal(parts.labels_, whole.labels_)
    assert parts.store.keys() == whole.store.keys()
    np.testing.assert_array_equal(parts.components_, whole.components_)
    assert parts.n_recalibrations_ == whole.n_recalibrations_


def test_stored_keys_stay_until_a_recalibration_and_ids_are_stable() -> None:
    x, y = _blobs(1000, 4, 8, seed=8)
    c = HilbertClusterer(4, method="runs", init_size=100, random_state=0)
    c.partial_fit(x[:100])
    keys, labels = c.store.keys(), c.labels_
    c.partial_fit(x[100:199])  # the next recalibration is due at 200
    assert c.n_recalibrations_ == 1 and c.store.keys()[:100] == keys
    c.partial_fit(x[199:])
    assert c.n_recalibrations_ >= 3
    # the same skills keep the same ids through every recalibration
    np.testing.assert_array_equal(c.labels_[:100], labels)
    assert adjusted_rand_score(y, c.labels_) == 1.0


def test_recalibrations_grow_geometrically() -> None:
    x, _ = _blobs(4000, 3, 6, seed=9)
    c = HilbertClusterer(3, method="runs", init_size=100, random_state=0)
    for s in range(0, 4000, 100):
        c.partial_fit(x[s : s + 100])
    # a stationary stream: one at the first batch, then at 200, 400, ..., 3200
    assert c.n_recalibrations_ == 6


def test_micro_keeps_at_most_one_component_per_ten_samples() -> None:
    # isotropic noise: a 95 % cut would keep nearly every direction (capped at 24)
    x = np.random.default_rng(12).normal(size=(120, 100))
    c = HilbertClusterer(2, init_size=60, random_state=0)
    c.partial_fit(x[:60])
    assert c.components_.shape[0] == 6
    c.partial_fit(x[60:])  # the count doubles: recalibrated on the 120 samples of the reservoir
    assert c.n_recalibrations_ == 2 and c.components_.shape[0] == 12
    assert HilbertClusterer(2, max_components=4, random_state=0).fit(x).components_.shape[0] == 4


def test_outside_samples_are_flagged_and_get_a_new_cluster() -> None:
    x, y = _blobs(200, 2, 5, seed=10)
    c = HilbertClusterer(2, method="runs", random_state=0).fit(x)
    far = x[y == 0][:3] + 1000.0  # one new skill, far outside
    assert c.outside(far).all()
    c.partial_fit(far)
    assert c.n_outside_ == 3 and c.n_novel_ == 3
    new = c.labels_[-3:]
    assert len(set(new.tolist())) == 1 and new[0] not in set(c.labels_[:200].tolist())
    # the stored key is the end cell's, flagged rather than silently taken as inside
    assert c.store.keys()[-3:] == [int(k) for k in c.transform(far)]


def test_macro_steps_between_searches_refit_the_chosen_mixture() -> None:
    x, y = _blobs(800, 3, 10, seed=13, sep=3.0)
    idx = np.random.default_rng(0).permutation(800)
    every = HilbertClusterer(3, init_size=100, search_growth=1.0, random_state=0)
    default = HilbertClusterer(3, init_size=100, random_state=0)
    for c in (every, default):
        for s in range(0, 800, 20):
            c.partial_fit(x[idx[s : s + 20]])
        assert adjusted_rand_score(y[idx], c.labels_) == 1.0
    m, m1 = default._micro, every._micro
    assert m1.n_refits == 0 and m1.n_searches == m1.n_macro_steps
    # a search on the first step and after each of the recalibrations at 200, 400 and 800;
    # the others (every 10 % of growth) refit
    assert m.n_macro_steps == m1.n_macro_steps and m.n_searches == 4
    assert m.n_refits == m.n_macro_steps - m.n_searches > 10
    with pytest.raises(InputError, match="search_growth"):
        HilbertClusterer(3, search_growth=0.5)


def test_a_refit_that_empties_a_cluster_becomes_a_search(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from nonprehensile.motion import summary

    x, _ = _blobs(400, 3, 8, seed=15)
    c = HilbertClusterer(3, init_size=100, random_state=0)
    c.partial_fit(x[:100])
    real = summary.fit_mixture

    def emptied(*args: object, **kw: object) -> object:
        mix = real(*args, **kw)  # type: ignore[arg-type]
        labels = mix.labels.copy()
        labels[labels == 1] = 0  # clusters {0, 2}: the middle one left empty
        return summary.Mixture(mix.covariance_type, mix.weights, mix.means,
                               mix.covariances, mix.log_likelihood, mix.bic, labels)

    monkeypatch.setattr(summary, "fit_mixture", emptied)
    m = c._micro
    searches, refits = m.n_searches, m.n_refits
    c.partial_fit(x[100:130])  # macro steps due, no recalibration: refits, all refused
    assert m.n_macro_steps > 1 and m.n_refits == refits and m.n_searches > searches
    assert c.n_clusters_ == 3


def test_the_search_for_the_number_of_clusters_stops_past_the_minimum(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from nonprehensile.motion import summary

    x, y = _blobs(300, 3, 6, seed=14)
    tried: set[int] = set()
    real = summary.fit_mixtures

    def spy(*args: object, **kw: object) -> object:
        tried.update(int(s.max()) + 1 for s in args[3])  # type: ignore[attr-defined]
        return real(*args, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(summary, "fit_mixtures", spy)
    c = HilbertClusterer(None, random_state=0).fit(x)
    assert c.n_clusters_ == 3 and adjusted_rand_score(y, c.labels_) == 1.0
    # the criterion rose at 4 and 5 clusters: 6 .. max_auto_clusters are never fitted
    assert max(tried) == 5


def test_new_skill_in_an_ordered_stream_becomes_a_cluster() -> None:
    x, y = _blobs(400, 2, 20, seed=11, sep=2.0)
    order = np.argsort(y, kind="stable")
    c = HilbertClusterer(None, init_size=100, random_state=0)
    c.partial_fit(x[order])
    assert adjusted_rand_score(y[order], c.labels_) == 1.0


# --------------------------------------------------------------------------- persistence


def test_state_round_trip_through_sqlite(tmp_path: Path) -> None:
    x, _ = _blobs(500, 3, 10, seed=12)
    path = tmp_path / "c.db"
    ref = HilbertClusterer(3, init_size=50, random_state=1)
    ref.partial_fit(x)
    store = SQLiteStore(path)
    c = HilbertClusterer(3, init_size=50, random_state=1, store=store)
    c.partial_fit(x[:300])
    store.put_meta("model", c.save_state())
    store.close()
    store = SQLiteStore(path)
    state = store.get_meta("model")
    assert state is not None
    again = HilbertClusterer.load_state(state, store)
    np.testing.assert_array_equal(again.predict(x[300:]), c.predict(x[300:]))
    again.partial_fit(x[300:])
    np.testing.assert_array_equal(again.labels_, ref.labels_)
    assert store.keys() == ref.store.keys()
    with pytest.raises(InputError, match="already holds 500 samples"):
        HilbertClusterer(3, store=store)


# --------------------------------------------------------------------------- bad input


def test_bad_arrays_get_clear_errors() -> None:
    x, _ = _blobs(50, 2, 6, seed=13)
    c = HilbertClusterer(2, random_state=0)
    with pytest.raises(InputError, match="not fitted"):
        c.predict(x)
    bad = x.copy()
    bad[3, 2] = np.nan
    with pytest.raises(InputError, match="sample 3, feature 2 is nan"):
        c.fit(bad)
    with pytest.raises(InputError, match=r"reshape\(1, -1\)"):
        c.fit(x[0])
    with pytest.raises(InputError, match=r"shape \(n_samples, n_features\)"):
        c.fit(x[None])
    with pytest.raises(InputError, match="at least 3 samples"):
        c.fit(x[:2])
    with pytest.raises(InputError, match="array of numbers"):
        c.fit([[1.0, "a"]])
    c.fit(x)
    with pytest.raises(InputError, match="5 features per sample, shorter than the 6"):
        c.partial_fit(x[:, :5])
    with pytest.raises(InputError, match="longer"):
        c.predict(np.hstack([x, x]))
    for kw, msg in [({"method": "kmeans"}, "method must be"),
                    ({"method": "runs", "n_components": 8, "order": 10}, "signed 64-bit"),
                    ({"variance": 1.5}, "variance must be"),
                    ({"capacity": 1}, "capacity must be >= 2"),
                    ({"growth": 1.0}, "growth must be"),
                    ({"n_clusters": 0}, "n_clusters must be >= 1"),
                    ({"merge": "x"}, "merge must be"),
                    ({"store": object()}, "must implement SampleStore")]:
        with pytest.raises(InputError, match=msg):
            HilbertClusterer(**kw)  # type: ignore[arg-type]


# --------------------------------------------------------------------------- CLI, figure


def test_cli_fit_add_show(tmp_path: Path) -> None:
    import json

    from click.testing import CliRunner

    from nonprehensile.cli.cluster import cluster_group

    x, y = _blobs(150, 3, 12, seed=14)
    np.savez(tmp_path / "a.npz", X=x[:120], y=y[:120])
    np.save(tmp_path / "b.npy", x[120:])
    db = str(tmp_path / "c.db")
    run = CliRunner()
    res = run.invoke(cluster_group, ["fit", db, "--arrays", str(tmp_path / "a.npz"),
                                     "--n-clusters", "3", "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert doc["n_samples"] == 120 and doc["ari_vs_classes"] == 1.0
    assert sum(c["size"] for c in doc["clusters"]) == 120
    res = run.invoke(cluster_group, ["add", db, "--arrays", str(tmp_path / "b.npy"), "--json"])
    assert res.exit_code == 0, res.output
    added = json.loads(res.stdout)["labels"]
    # the new samples join the clusters of their skills, named as in the first fit
    first = dict(zip(y[:120].tolist(), doc["labels"], strict=True))
    assert added == [first[v] for v in y[120:].tolist()]
    png = tmp_path / "h.png"
    res = run.invoke(cluster_group, ["show", db, "--histogram", str(png), "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["n_samples"] == 150 and png.stat().st_size > 1000
    # bad input: exit code 2 and a message naming the culprit
    np.save(tmp_path / "bad.npy", x[:5, :4])
    res = run.invoke(cluster_group, ["add", db, "--arrays", str(tmp_path / "bad.npy")])
    assert res.exit_code == 2 and "4 features per sample" in res.output
    res = run.invoke(cluster_group, ["show", str(tmp_path / "none.db")])
    assert res.exit_code == 2 and "no such store" in res.output


def test_histogram_counts_match_the_clusters() -> None:
    from nonprehensile.viz.clusters import cluster_histogram_figure

    x, y = _skill_trajectories(30, seed=15)
    c = HilbertClusterer(2, method="paper", random_state=0).fit(x)
    fig = cluster_histogram_figure(c, truth=y.tolist(), title="Fig. 12(b)")
    ax = fig.axes[0]
    # one stacked step patch per cluster; its bins add up to the cluster's size
    heights: dict[str, float] = {}
    for patch in ax.patches:
        values, _, baseline = patch.get_data()
        heights[str(patch.get_label())] = float(np.sum(values - baseline))
    sizes = np.bincount(c.labels_)
    # stacked steps sit on those below (their baselines), their heights are their own counts
    assert sorted(heights.values()) == sorted(sizes.tolist())
    legend = ax.get_legend()
    assert legend is not None
    assert sorted(t.get_text() for t in legend.get_texts()) == ["0", "1"]
    assert ax.get_xlim() == (0.0, 1024.0)  # 10-bit keys: the paper's indices 0..1023
    assert len(fig.axes) == 2


def test_histogram_panels_name_their_shared_scale_once() -> None:
    """Clusters above, true classes below, on one x scale: its numbers and name are shown
    under the lower panel only (issue 16); the upper keeps its tick marks at the same places.
    Alone (no truth), the one panel has both."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from nonprehensile.viz.clusters import cluster_histogram_figure

    x, y = _skill_trajectories(30, seed=15)
    c = HilbertClusterer(2, method="paper", random_state=0).fit(x)
    fig = cluster_histogram_figure(c, truth=y.tolist())
    FigureCanvasAgg(fig).draw()
    upper, lower = fig.axes

    def shown(ax: object) -> list[str]:
        return [t.get_text() for t in ax.xaxis.get_ticklabels()  # type: ignore[attr-defined]
                if t.get_visible() and t.get_text()]

    assert shown(upper) == [] and upper.get_xlabel() == ""
    assert shown(lower) and lower.get_xlabel() == "Hilbert index"
    assert list(upper.get_xticks()) == list(lower.get_xticks())
    assert all(t.tick1line.get_visible() for t in upper.xaxis.get_major_ticks())
    (alone,) = cluster_histogram_figure(c).axes
    FigureCanvasAgg(alone.figure).draw()
    assert shown(alone) and alone.get_xlabel() == "Hilbert index"


def test_histogram_draws_what_matplotlibs_stairs_draws() -> None:
    """The key histogram's step patches are added without growing the axes' limits around
    each (issue 16: the limits are set from the counts): the picture is, pixel for pixel,
    what matplotlib's own ``stairs`` draws with the same counts."""
    import io

    from matplotlib.figure import Figure
    from PIL import Image

    from nonprehensile.viz.clusters import plot_key_histogram

    keys = [5, 9, 9, 200, 700, 701, 1000, 1020, 30, 31]
    groups = ["a", "b", "a", "b", "c", "a", "c", "c", "b", "a"]
    ours = Figure(figsize=(4, 3), dpi=80)
    plot_key_histogram(ours.add_axes((0.15, 0.15, 0.8, 0.8)), keys, groups, n_bits=10,
                       bins=16)
    theirs = Figure(figsize=(4, 3), dpi=80)
    ax = theirs.add_axes((0.15, 0.15, 0.8, 0.8))
    edges = np.linspace(0.0, 1024.0, 17)
    below = np.zeros(16)
    for i, name in enumerate(["a", "b", "c"]):
        counts = np.histogram([k for k, g in zip(keys, groups, strict=True) if g == name],
                              bins=edges)[0].astype(float)
        ax.stairs(below + counts, edges, baseline=below.copy(), fill=True,
                  color=f"C{i}", label=name)
        below += counts
    ax.set_ylim(0.0, float(below.max()) * 1.05)
    ax.set_xlim(0.0, 1024.0)
    ax.legend(title="cluster", fontsize="small")
    ax.set_xlabel("Hilbert index")
    ax.set_ylabel("trajectories")

    def pixels(fig: Figure) -> np.ndarray:
        buf = io.BytesIO()
        fig.savefig(buf, format="png")
        return np.asarray(Image.open(buf))

    assert [p.get_label() for p in ours.axes[0].patches] == ["a", "b", "c"]
    np.testing.assert_array_equal(pixels(ours), pixels(theirs))


def test_cluster_add_of_other_markers_names_the_dataset_and_the_store(tmp_path: Path) -> None:
    """A dataset whose recordings have other markers than the fitted store's: the message names
    the dataset, the store and the markers (it said 'X has 9600 features per sample' and told
    a command-line user to resample with a library function)."""
    import json

    from click.testing import CliRunner

    from nonprehensile.cli.cluster import cluster_group
    from nonprehensile.demonstrations.synth import synthesize

    fingers, tracked = tmp_path / "fingers", tmp_path / "tracked"
    synthesize(fingers, seed=1, n_per_skill=1, mentors=1)
    synthesize(tracked, seed=2, n_per_skill=1, mentors=1, track_object=True)
    db, run = str(tmp_path / "c.db"), CliRunner()
    res = run.invoke(cluster_group, ["fit", db, "--dataset", str(fingers), "--json"])
    assert res.exit_code == 0, res.output
    n = json.loads(res.stdout)["n_samples"]
    res = run.invoke(cluster_group, ["add", db, "--dataset", str(tracked)])
    assert res.exit_code == 2, res.output
    line = res.output.strip()
    assert "\n" not in line and str(tracked) in line and "c.db" in line, line
    assert "holds demonstrations of 4 marker(s)" in line and "'markers'" in line, line
    assert "nonprehensile.motion.preprocess" not in line, line
    res = run.invoke(cluster_group, ["show", db, "--json"])
    assert json.loads(res.stdout)["n_samples"] == n  # nothing registered


def test_cluster_fit_of_too_few_samples_names_them_and_creates_no_store(tmp_path: Path) -> None:
    """Too few samples for a first fit: the message was 'recalibration needs at least 6
    samples, 3 are stored; add more first' (no file named), and an empty store file was left
    behind, which `cluster show` then called a store without a clusterer."""
    from click.testing import CliRunner

    from nonprehensile.cli.cluster import cluster_group

    np.save(tmp_path / "few.npy", np.random.default_rng(0).normal(size=(3, 5)))
    db = tmp_path / "c.db"
    res = CliRunner().invoke(cluster_group, ["fit", str(db), "--arrays",
                                             str(tmp_path / "few.npy"), "--n-clusters", "5"])
    assert res.exit_code == 2, res.output
    line = res.output.strip()
    assert "\n" not in line and "few.npy: 3 sample(s)" in line and "at least 6" in line, line
    assert "--n-clusters" in line and not db.exists()
