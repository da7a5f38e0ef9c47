"""``nonprehensile cluster``: cluster demonstrated trajectories into a persistent store.

Registered on the main group by :mod:`nonprehensile.cli`. The store is a SQLite file holding
every sample (flattened trajectory), its Hilbert key and cluster id, and the clusterer's state,
so that ``cluster add`` registers new demonstrations without refitting (several processes may
add at once: each takes the write lock for its whole registration). Progress bars and messages
go to stderr; ``--json`` prints one JSON document on stdout.
"""

from __future__ import annotations

import math
import tokenize
import zipfile
import zlib
from pathlib import Path
from typing import Any

import click
import numpy as np
from numpy.typing import NDArray
from rich.table import Table

from nonprehensile.bounds import check_path
from nonprehensile.cli import HelpGroup
from nonprehensile.cli.common import emit_json, handle_errors, out, progress_bar
from nonprehensile.cli.options import SEED, count
from nonprehensile.errors import InputError
from nonprehensile.motion.clustering import HilbertClusterer
from nonprehensile.motion.store import SampleStore
from nonprehensile.motion.stores import display_name, is_postgres_url, open_store, store_exists
from nonprehensile.motion.trajectory import DEFAULT_N_POINTS

__all__ = ["cluster_group"]

#: Name of the clusterer's state in the store's meta table.
STATE = "hilbert_clusterer"
#: Samples registered per step of the progress bar.
CHUNK = 64


#: Largest sample array read from a file, bytes (checked from its header, before reading).
MAX_ARRAY_BYTES = 2**30


def _load_arrays(path: str) -> tuple[NDArray[np.float64], list[str] | None]:
    """Samples from ``.npy`` (an array, shape (n_samples, n_features)) or ``.npz`` (key
    ``X``, optional ``y``: a class per sample).

    Headers are read and checked (shape, dtype, size against the file's and
    :data:`MAX_ARRAY_BYTES`) before any array is allocated; pickled objects are refused.
    """
    p = check_path(path, "--arrays")
    if not p.is_file():
        raise InputError(f"{path}: no such file; give a .npy or .npz file of samples")
    with p.open("rb") as fh:
        head = fh.read(6)
    if head == b"\x93NUMPY":
        with p.open("rb") as fh:
            return _real(_read_npy(fh, p.stat().st_size, path), path), None
    if head[:4] != b"PK\x03\x04":
        raise InputError(
            f"{path}: not a numpy .npy or .npz file (it starts {head!r}); save the samples "
            "with numpy.save, shape (n_samples, n_features)"
        )
    try:
        with zipfile.ZipFile(p) as zf:
            names = zf.namelist()
            if "X.npy" not in names:
                raise InputError(f"{path}: an .npz file needs an array named 'X', it has "
                                 f"{[n.removesuffix('.npy') for n in names]}")
            x = _real(_read_member(zf, "X.npy", path), path)
            y = None
            if "y.npy" in names:
                y = [str(v) for v in _read_member(zf, "y.npy", path).tolist()]
    # zipfile raises NotImplementedError for a compression method it cannot read: bad input
    except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError) as exc:
        raise InputError(f"{path}: a damaged .npz file ({exc}); save it again with "
                         "numpy.savez") from None
    if y is not None and len(y) != len(x):
        raise InputError(f"{path}: 'y' has {len(y)} classes for {len(x)} samples in 'X'; "
                         "give one class per sample")
    return x, y


def _read_member(zf: zipfile.ZipFile, name: str, path: str) -> NDArray[Any]:
    info = zf.getinfo(name)
    with zf.open(info) as fh:
        return _read_npy(fh, info.file_size, f"{path} ({name.removesuffix('.npy')})")


def _read_npy(fh: Any, size: int, what: str) -> NDArray[Any]:
    """An array from an open ``.npy`` stream of ``size`` bytes, header checked first."""
    fmt = np.lib.format
    try:
        major, _ = fmt.read_magic(fh)
        read_header = fmt.read_array_header_1_0 if major == 1 else fmt.read_array_header_2_0
        shape, fortran, dtype = read_header(fh)
    except (ValueError, EOFError, OSError, SyntaxError, tokenize.TokenError) as exc:
        # numpy parses the header's dict literal with tokenize/ast: a damaged one raises these
        raise InputError(f"{what}: not a readable .npy array header ({exc}); save the samples "
                         "with numpy.save") from None
    if dtype.hasobject or dtype.kind not in "biufU":
        raise InputError(f"{what}: an array of {dtype} cannot hold samples; save a float "
                         "array, shape (n_samples, n_features)")
    if not all(type(k) is int and k >= 0 for k in shape):
        # numpy reads any tuple literal: (-1, 12) would become a read of -12 rows
        raise InputError(f"{what}: its header declares shape {shape}, not a shape (the sizes "
                         "must be whole numbers >= 0); the file is damaged, save it again with "
                         "numpy.save")
    count = math.prod(shape)
    nbytes = count * dtype.itemsize
    if nbytes > MAX_ARRAY_BYTES:
        raise InputError(f"{what}: its header declares shape {shape} of {dtype} ({nbytes} "
                         f"bytes), more than the {MAX_ARRAY_BYTES} bytes read at once; split "
                         "the samples into several files")
    data = fh.read(nbytes)
    if len(data) != nbytes or fh.tell() > size:
        raise InputError(f"{what}: its header declares shape {shape} ({nbytes} bytes of data) "
                         f"but the file holds {len(data)}; the file is truncated")
    a = np.frombuffer(data, dtype=dtype, count=count)
    return a.reshape(shape, order="F" if fortran else "C")


def _real(a: NDArray[Any], path: str) -> NDArray[np.float64]:
    """Samples as real floats, shape (n_samples, n_features), or an error naming the file."""
    if not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)
            or a.dtype == np.bool_):
        raise InputError(f"{path}: the samples must be real numbers, got an array of "
                         f"{a.dtype}; save a float array, shape (n_samples, n_features)")
    if a.ndim != 2 or 0 in a.shape:
        raise InputError(f"{path}: the samples must be a 2-D array, shape (n_samples >= 1, "
                         f"n_features >= 1), got shape {a.shape}; reshape it (one row per "
                         "sample)")
    return np.asarray(a, dtype=np.float64)


def _load_dataset(spec: str, quiet: bool) -> tuple[NDArray[np.float64], list[str]]:
    """Flattened demonstrations of a dataset folder (or bundled name) and their skills."""
    from nonprehensile.demonstrations.dataset import load_dataset
    from nonprehensile.references import flatten_demonstrations

    with progress_bar("reading demonstrations", quiet) as tick:
        ds = load_dataset(spec, progress=tick)
    if not ds.demonstrations:
        raise InputError(f"{spec}: the dataset has no demonstration")
    return flatten_demonstrations(ds)


def _samples(dataset: str | None, arrays: str | None, quiet: bool
             ) -> tuple[NDArray[np.float64], list[str] | None]:
    if (dataset is None) == (arrays is None):
        raise InputError("give exactly one of --dataset DIR (or a bundled name) or "
                         "--arrays FILE (.npy or .npz)")
    if dataset is not None:
        return _load_dataset(dataset, quiet)
    assert arrays is not None
    return _load_arrays(arrays)


def _describe(dataset: str | None, arrays: str | None, store: str, fitted: int
              ) -> tuple[str, str]:
    """What the samples are and how to fix a width unlike the store's, for the message."""
    name = display_name(store)
    if dataset is not None:
        per = DEFAULT_N_POINTS * 3  # one marker: its track resampled to the points, x y z
        held = (f"demonstrations of {fitted // per} marker(s)" if fitted % per == 0 else
                f"samples of {fitted} features")
        return (f"{dataset} (the dataset's demonstrations, flattened: {DEFAULT_N_POINTS} "
                "points x 3 coordinates per marker)",
                f"the store {name} holds {held}: add demonstrations that record the markers "
                "it was fitted on (the same 'fingers', 'markers' and 'object_markers' in the "
                "annotations), or fit a new store")
    return (f"{arrays}", f"the store {name} holds samples of {fitted} features: resample "
                         "every trajectory to the same number of points "
                         "(nonprehensile.motion.preprocess) with the same markers, or fit a "
                         "new store")


def _register(c: HilbertClusterer, x: NDArray[np.float64], quiet: bool) -> None:
    with progress_bar("clustering", quiet) as tick:
        for s in range(0, x.shape[0], CHUNK):
            c.partial_fit(x[s : s + CHUNK])
            tick(min(s + CHUNK, x.shape[0]), x.shape[0])


def _close(db: SampleStore) -> None:
    close = getattr(db, "close", None)
    if close is not None:
        close()


def _load(db: SampleStore, path: str) -> HilbertClusterer:
    state = db.get_meta(STATE)
    if state is None:
        raise InputError(
            f"{path}: no clusterer in this store; create one with "
            "`nonprehensile cluster fit STORE --dataset ...` first"
        )
    return HilbertClusterer.load_state(state, db)


def summary(c: HilbertClusterer, path: str) -> dict[str, Any]:
    """The ``cluster show --json`` document: model and clusters (id, size, key range)."""
    clusters = []
    # current labels (method micro: not the stored, as-registered ones) against stored keys
    labels = c.labels_
    all_keys = np.array(c.store.keys(), dtype=np.int64)
    for cid in sorted(set(labels.tolist())):
        keys = all_keys[labels == cid]
        clusters.append({"id": cid, "size": int(keys.size), "key_min": int(keys.min()),
                         "key_max": int(keys.max())})
    return {
        "store": display_name(path),
        "method": c.method,
        "n_samples": c.n_samples_seen_,
        "n_features": c.n_features_in_,
        "n_components": int(c.components_.shape[0]),
        "order": c.order_,
        "n_clusters": len(clusters),
        "n_recalibrations": c.n_recalibrations_,
        "n_outside": c.n_outside_,
        "clusters": clusters,
    }


def _print_summary(doc: dict[str, Any]) -> None:
    out.print(
        f"{doc['store']}: {doc['n_samples']} samples of {doc['n_features']} features, "
        f"method {doc['method']}, {doc['n_components']} components x order {doc['order']}, "
        f"{doc['n_clusters']} clusters, {doc['n_recalibrations']} recalibrations, "
        f"{doc['n_outside']} registered outside the scale bounds"
    )
    t = Table(title="Clusters")
    for col in ("id", "size", "first key", "last key"):
        t.add_column(col, justify="right")
    for cl in doc["clusters"]:
        t.add_row(str(cl["id"]), str(cl["size"]), str(cl["key_min"]), str(cl["key_max"]))
    out.print(t)


def _with_classes(doc: dict[str, Any], c: HilbertClusterer, classes: list[str] | None,
                  start: int) -> dict[str, Any]:
    labels = c.labels_[start:].tolist()
    doc = {**doc, "labels": labels}
    if classes is not None and len(classes) == len(labels) and len(set(classes)) > 1:
        from sklearn.metrics import adjusted_rand_score

        doc["ari_vs_classes"] = float(adjusted_rand_score(classes, labels))
    return doc


# a file path (SQLite) or a postgresql:// URL (PostgreSQL): see nonprehensile.motion.stores
store_argument = click.argument("store")
dataset_option = click.option("--dataset", default=None,
                              help="Demonstration dataset folder, or a bundled name (cube).")
arrays_option = click.option("--arrays", default=None, type=click.Path(dir_okay=False),
                             help="Samples as .npy (n_samples, n_features) or .npz (X, y).")
json_option = click.option("--json", "as_json", is_flag=True, help="Print one JSON document.")


@click.group("cluster", cls=HelpGroup)
def cluster_group() -> None:
    """Cluster demonstrated trajectories on a Hilbert-curve index, in a store.

    A store is a SQLite file path, or a postgresql:// URL (a PostgreSQL database)."""


@cluster_group.command("fit")
@store_argument
@dataset_option
@arrays_option
@click.option("--method", type=click.Choice(["micro", "runs", "paper"]), default="micro",
              show_default=True,
              help="micro: ours (micro-cluster summary); runs: our earlier key runs; paper: "
                   "the paper's recipe.")
@click.option("--n-clusters", type=count(1, 10**7), default=None,
              help="Number of clusters (default: chosen from the data: by BIC for micro, by "
                   "the silhouette for runs and paper).")
@click.option("--init-size", type=count(1, 10**9), default=None,
              help="Samples of the first batch (default: all given here).")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Random seed.")
@json_option
@handle_errors
def cluster_fit(store: str, dataset: str | None, arrays: str | None, method: str,
                n_clusters: int | None, init_size: int | None, seed: int,
                as_json: bool) -> None:
    """Create STORE (replacing its content) and cluster the given samples into it."""
    x, classes = _samples(dataset, arrays, as_json)
    need = HilbertClusterer(n_clusters, method=method).min_fit_samples()  # type: ignore[arg-type]
    if x.shape[0] < need:  # before the store is opened (created) or cleared
        what = (f"{dataset}: {x.shape[0]} demonstration(s)" if dataset is not None else
                f"{arrays}: {x.shape[0]} sample(s)")
        raise InputError(f"{what}, and a fit needs at least {need} (n_clusters + 1, at least "
                         f"3); give more{' or fewer --n-clusters' if n_clusters else ''}")
    db = open_store(store)
    try:
        with db.transaction():
            db.clear()
            c = HilbertClusterer(n_clusters, method=method,  # type: ignore[arg-type]
                                 init_size=init_size if init_size is not None else
                                 max(x.shape[0], 3), store=db, random_state=seed)
            _register(c, x, as_json)
            if not c.n_recalibrations_:
                c.recalibrate()
            db.put_meta(STATE, c.save_state())
            doc = _with_classes(summary(c, store), c, classes, 0)  # as in add, under the lock
    finally:
        _close(db)
    if as_json:
        emit_json(doc)
        return
    _print_summary(doc)
    if "ari_vs_classes" in doc:
        out.print(f"adjusted Rand index against the given classes: {doc['ari_vs_classes']:.3f}")


@cluster_group.command("add")
@store_argument
@dataset_option
@arrays_option
@json_option
@handle_errors
def cluster_add(store: str, dataset: str | None, arrays: str | None, as_json: bool) -> None:
    """Register new demonstrations in STORE without reclustering the stored ones."""
    if not store_exists(store):
        raise InputError(f"{store}: no such store; create it with `nonprehensile cluster fit`")
    x, classes = _samples(dataset, arrays, as_json)
    db = open_store(store)
    try:
        # the write lock for the whole read-modify-write: concurrent adds take turns. The
        # summary is read under it too: the clusterer's labels and the store's keys are
        # separate reads, and another add committed between them (likely under load) made
        # them disagree in length (a crash, exit 1, after the add was stored)
        with db.transaction():
            c = _load(db, store)
            c.check_samples(x, *_describe(dataset, arrays, store, c.n_features_in_))
            start = c.n_samples_seen_
            _register(c, x, as_json)
            db.put_meta(STATE, c.save_state())
            doc = _with_classes(summary(c, store), c, classes, start)
    finally:
        _close(db)
    if as_json:
        emit_json(doc)
        return
    _print_summary(doc)
    out.print(f"registered {x.shape[0]} samples, cluster ids: "
              f"{' '.join(map(str, doc['labels']))}")


@cluster_group.command("show")
@store_argument
@click.option("--histogram", type=click.Path(dir_okay=False), default=None,
              help="Write the histogram of keys coloured by cluster (the paper's Fig. 12(b)) "
                   "to this image file (.png, .svg, .pdf).")
@json_option
@handle_errors
def cluster_show(store: str, histogram: str | None, as_json: bool) -> None:
    """Show the clusters of STORE: sizes and key ranges."""
    if not store_exists(store):
        raise InputError(f"{store}: no such store; create it with `nonprehensile cluster fit`")
    # read only: no write lock (writers go on), and a store on a read-only mount can be shown
    db = open_store(store, readonly=True)
    try:
        c = _load(db, store)
        doc = summary(c, store)
        if histogram is not None:
            from nonprehensile.viz import save_figure
            from nonprehensile.viz.clusters import cluster_histogram_figure

            title = "PostgreSQL store" if is_postgres_url(store) else Path(store).name
            save_figure(cluster_histogram_figure(c, title=title), histogram)
            doc["histogram"] = histogram
    finally:
        _close(db)
    if as_json:
        emit_json(doc)
        return
    _print_summary(doc)
    if histogram is not None:
        out.print(f"wrote {histogram}")
