"""Re-keying an archive beyond one machine: a pure function over chunks, run on Dask.

After a recalibration every stored sample needs its new Hilbert key. :func:`rekey_chunk` is
that re-key for one chunk of samples, a pure function of the chunk and a frozen
:class:`KeyModel` (mean, principal directions, scale bounds, order); :func:`rekey_parquet` and
:func:`rekey_store` map it over the chunks of a Parquet export (:func:`export_parquet`) or of a
store (SQLite or PostgreSQL, each task opening its own connection) on a Dask scheduler (a
``distributed`` cluster, or Dask's local threads) and gather the keys in id order.

Keys are identical whatever the chunking and the number of BLAS threads: the projection
``z = (x - mean) @ components.T`` is not a BLAS product (whose blocking, and so whose rounding,
depends on the matrix shapes and the thread count: the same re-key with a multithreaded BLAS
gave different keys to 13 of 400 000 samples) but one float64 reduction per component and
sample (:func:`project`), over the sample's own values in a fixed order, so each sample's
components depend on that sample alone.

Needs the ``scale`` extra (dask[distributed], pyarrow).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from nonprehensile.errors import InputError
from nonprehensile.motion.hilbert import encode, quantize
from nonprehensile.motion.store import SampleStore

__all__ = ["KeyModel", "export_parquet", "project", "recluster_chunk", "rekey_chunk",
           "rekey_parquet", "rekey_store", "write_keys"]

FloatArray = NDArray[np.float64]
Keys = NDArray[np.uint64]

#: Rows per chunk (and per Parquet row group) by default.
DEFAULT_CHUNK = 4096
#: Rows projected at once inside a chunk (bounds a temporary of _BLOCK x d floats).
_BLOCK = 256


@dataclass(frozen=True, eq=False)
class KeyModel:
    """What a re-key needs: the frozen projection and grid of a recalibrated clusterer.

    Attributes
    ----------
    mean : array, shape (d,)
    components : array, shape (k, d)
        Principal directions, orthonormal rows.
    lower, upper : array, shape (k,)
        Scale bounds: ``2**order`` cells per component between them.
    order : int
        Hilbert order (bits per component).
    """

    mean: FloatArray
    components: FloatArray
    lower: FloatArray
    upper: FloatArray
    order: int
    centers: FloatArray | None = None
    ids: NDArray[np.int64] | None = None

    @classmethod
    def from_clusterer(cls, c: Any) -> KeyModel:
        """The model of a fitted :class:`~nonprehensile.motion.HilbertClusterer`, with its
        clusters' centres in component space (``cluster_centers_``) and ids."""
        if not getattr(c, "order_", 0):
            raise InputError("the clusterer is not fitted yet: nothing to re-key with")
        centers = getattr(c, "cluster_centers_", None)
        ids = getattr(c, "cluster_ids_", None)
        ok = (centers is not None and ids is not None and np.ndim(centers) == 2
              and len(centers) == len(ids) and len(ids) > 0)
        return cls(np.array(c.mean_, dtype=np.float64), np.array(c.components_, dtype=np.float64),
                   np.array(c.lower_, dtype=np.float64), np.array(c.upper_, dtype=np.float64),
                   int(c.order_),
                   np.array(centers, dtype=np.float64) if ok else None,
                   np.array(ids, dtype=np.int64) if ok else None)


def project(x: FloatArray, mean: FloatArray, components: FloatArray) -> FloatArray:
    """``(x - mean) @ components.T``, shape (m, k), the same bits whatever ``m`` and the BLAS.

    Each entry is one float64 reduction (numpy's pairwise sum along the row, no BLAS) of the
    sample's own centred values times the component: it depends on that sample and the model
    only, not on the other rows of the chunk nor on threads.
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    z = np.empty((x.shape[0], components.shape[0]))
    # blocks of rows bound the temporary's memory; a row's result does not depend on them
    for s in range(0, x.shape[0], _BLOCK):
        xc = x[s : s + _BLOCK] - mean
        for j in range(components.shape[0]):
            z[s : s + _BLOCK, j] = np.add.reduce(xc * components[j], axis=1)
    return z


def rekey_chunk(x: FloatArray, model: KeyModel) -> tuple[Keys, NDArray[np.bool_]]:
    """Hilbert keys of a chunk of samples, shape (m,), and whether each is outside the bounds.

    A pure function of ``x`` (shape (m, d)) and ``model``.
    """
    z = project(x, model.mean, model.components)
    grid, outside = quantize(z, model.lower, model.upper, model.order)
    return np.asarray(encode(grid, model.order), dtype=np.uint64), outside


def recluster_chunk(x: FloatArray, model: KeyModel) -> tuple[Keys, NDArray[np.int64]]:
    """Keys and cluster ids of a chunk, shape (m,) each: a pure function of ``x`` and the model.

    A sample takes the id of the nearest cluster centre in component space (squared
    distances summed over the components in a fixed order; ties to the lower index), so its
    id, like its key, depends on that sample and the model only.
    """
    if model.centers is None or model.ids is None:
        raise InputError("the model has no cluster centres: build it with "
                         "KeyModel.from_clusterer from a recalibrated clusterer")
    z = project(x, model.mean, model.components)
    grid, _ = quantize(z, model.lower, model.upper, model.order)
    d2 = np.zeros((z.shape[0], model.centers.shape[0]))
    for j in range(z.shape[1]):
        d2 += (z[:, j : j + 1] - model.centers[None, :, j]) ** 2
    return (np.asarray(encode(grid, model.order), dtype=np.uint64),
            model.ids[np.argmin(d2, axis=1)])


# ---------------------------------------------------------------------------- Parquet


def export_parquet(store: SampleStore, path: str | Path, *,
                   rows_per_group: int = DEFAULT_CHUNK) -> int:
    """Write a store's samples to Parquet: columns ``id``, ``key``, ``label`` (int64) and
    ``vector`` (fixed-size list of float64), one row group per ``rows_per_group`` samples.

    Returns the number of samples written.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    if rows_per_group < 1:
        raise InputError(f"rows_per_group must be >= 1, got {rows_per_group}")
    n, d = store.n_samples, store.n_features or 0
    keys = np.array(store.keys(), dtype=np.int64)
    labels = store.labels()
    schema = pa.schema([("id", pa.int64()), ("key", pa.int64()), ("label", pa.int64()),
                        ("vector", pa.list_(pa.float64(), d))])
    with pq.ParquetWriter(str(path), schema) as writer:
        for s in range(0, n, rows_per_group):
            e = min(n, s + rows_per_group)
            vec = store.vectors(s, e)
            flat = pa.array(np.ascontiguousarray(vec).ravel(), type=pa.float64())
            table = pa.table({"id": np.arange(s, e, dtype=np.int64), "key": keys[s:e],
                              "label": labels[s:e],
                              "vector": pa.FixedSizeListArray.from_arrays(flat, d)},
                             schema=schema)
            writer.write_table(table, row_group_size=rows_per_group)
    return n


Part = tuple[NDArray[np.int64], Keys, NDArray[np.int64] | None]


def _work(ids: NDArray[np.int64], x: FloatArray, model: KeyModel, labels: bool) -> Part:
    if labels:
        keys, lab = recluster_chunk(x, model)
        return ids, keys, lab
    return ids, rekey_chunk(x, model)[0], None


def _parquet_chunk(path: str, group: int, model: KeyModel, labels: bool) -> Part:
    import pyarrow.parquet as pq

    t = pq.ParquetFile(path).read_row_group(group, columns=["id", "vector"])
    ids = t.column("id").to_numpy()
    vec = t.column("vector").combine_chunks()
    d = vec.type.list_size
    x = vec.flatten().to_numpy(zero_copy_only=False).reshape(-1, d)
    return _work(ids, x, model, labels)


def _gather(parts: Sequence[Part], labels: bool) -> Any:
    ids = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, dtype=np.int64)
    order = np.argsort(ids, kind="stable")
    keys = (np.concatenate([p[1] for p in parts]) if parts
            else np.zeros(0, dtype=np.uint64))[order]
    if not labels:
        return keys
    lab = np.concatenate([p[2] for p in parts if p[2] is not None]) if parts else \
        np.zeros(0, dtype=np.int64)
    return keys, lab[order]


def _compute(tasks: list[Any], scheduler: Any) -> list[Any]:
    from dask.base import compute

    if scheduler is None:
        return list(compute(*tasks, scheduler="threads"))  # type: ignore[no-untyped-call]
    if hasattr(scheduler, "compute") and hasattr(scheduler, "gather"):  # a distributed Client
        return list(scheduler.gather(scheduler.compute(tasks)))
    return list(compute(*tasks, scheduler=scheduler))  # type: ignore[no-untyped-call]


def rekey_parquet(path: str | Path, model: KeyModel, *, scheduler: Any = None,
                  labels: bool = False) -> Any:
    """Keys of every sample of a Parquet export, in id order, one Dask task per row group.

    With ``labels=True``: keys and cluster ids (:func:`recluster_chunk`), a pair of arrays.

    Parameters
    ----------
    path : str or Path
        Written by :func:`export_parquet`.
    model : KeyModel
    scheduler : distributed.Client, Dask scheduler name, or None
        Where the tasks run (None: Dask's local threads).
    """
    import pyarrow.parquet as pq
    from dask.delayed import delayed

    n_groups = pq.ParquetFile(str(path)).num_row_groups
    tasks = [delayed(_parquet_chunk)(str(path), g, model, labels) for g in range(n_groups)]
    return _gather(_compute(tasks, scheduler), labels)


def _store_chunk(spec: str, name: str | None, start: int, stop: int, model: KeyModel,
                 labels: bool) -> Part:
    from nonprehensile.motion.stores import open_store

    store = open_store(spec, name=name)
    try:
        x = store.vectors(start, stop)
    finally:
        getattr(store, "close", lambda: None)()
    return _work(np.arange(start, stop, dtype=np.int64), x, model, labels)


def rekey_store(spec: str | Path, model: KeyModel, *, name: str | None = None,
                chunk: int = DEFAULT_CHUNK, scheduler: Any = None, labels: bool = False) -> Any:
    """Keys of every sample of a store (a SQLite path or a PostgreSQL URL), in id order.

    With ``labels=True``: keys and cluster ids (:func:`recluster_chunk`), a pair of arrays.

    Each Dask task opens the store itself and reads its chunk of ids (a range scan of the
    primary key), so the tasks run on any worker that reaches the database.
    """
    from dask.delayed import delayed

    from nonprehensile.motion.stores import open_store

    if chunk < 1:
        raise InputError(f"chunk must be >= 1, got {chunk}")
    store = open_store(spec, name=name)
    try:
        n = store.n_samples
    finally:
        getattr(store, "close", lambda: None)()
    tasks = [delayed(_store_chunk)(str(spec), name, s, min(n, s + chunk), model, labels)
             for s in range(0, n, chunk)]
    return _gather(_compute(tasks, scheduler), labels)


def write_keys(store: SampleStore, keys: Keys, labels: NDArray[np.int64] | None = None,
               *, batch: int = DEFAULT_CHUNK * 4) -> None:
    """Write re-keyed samples back, in batches, all in one transaction (all or nothing)."""
    if keys.shape != (store.n_samples,):
        raise InputError(f"{keys.shape[0]} keys for a store of {store.n_samples} samples")
    lab = store.labels() if labels is None else np.asarray(labels, dtype=np.int64)
    with store.transaction():
        for s in range(0, keys.size, batch):
            store.update(s, [int(k) for k in keys[s : s + batch].tolist()], lab[s : s + batch])
