"""Numerics of the micro-cluster motion model: deterministic projection, PCA, weighted Ward
and weighted Gaussian mixtures over a bounded summary (issue 14, paper Section VI).

Everything here is pure numpy/scipy on small arrays (a few hundred micro-clusters in a few
dozen dimensions): the cost never depends on the number of samples stored.

Determinism: :func:`project` sums the products of a sample with each principal direction
along the feature axis with numpy's own reduction (never BLAS), so a sample's projection,
and so its key, is the same bit for bit whatever the number of BLAS threads and whatever
other samples share its call. The few BLAS calls (the PCA, the Ward distance matrix, the
mixtures' EM) run inside :func:`one_thread`, which fixes the thread count to one: that is
also faster for these small matrices on a shared machine (issue 16).
"""

from __future__ import annotations

import contextlib
import math
import sys
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "COVARIANCE_TYPES",
    "Mixture",
    "fit_mixture",
    "fit_mixtures",
    "one_thread",
    "pca",
    "project",
    "ward_merges",
    "ward_partition",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
CovarianceType = Literal["spherical", "diag", "tied", "full"]
COVARIANCE_TYPES: tuple[CovarianceType, ...] = ("spherical", "diag", "tied", "full")

#: Default ridge of the mixtures' covariances, relative to the mean variance.
REG_FACTOR = 1e-3
#: Elements of the temporary product in one block of :func:`project`: 512 KiB, which stays
#: in the cache and below the allocator's fresh-pages threshold (16 MiB blocks took 45 %
#: longer, much of it in page faults).
_BLOCK = 1 << 16


#: threadpoolctl's view of the loaded thread pools, and the module count it was taken at.
_CONTROLLER: list[Any] = [None, -1]


def _controller() -> Any:
    """A cached ``threadpoolctl.ThreadpoolController`` (``None`` without threadpoolctl).

    ``threadpool_limits`` scans every loaded shared library on each call (1 to 20 ms: a
    macro step or a compaction would pay it on top of its own work); the controller scans
    once and is rebuilt only when modules were imported since (a new native library comes
    with an import).
    """
    n_modules = len(sys.modules)
    if _CONTROLLER[1] != n_modules:
        try:
            from threadpoolctl import ThreadpoolController
        except ImportError:  # pragma: no cover - scikit-learn depends on threadpoolctl
            _CONTROLLER[:] = [None, len(sys.modules)]
        else:
            _CONTROLLER[:] = [ThreadpoolController(), len(sys.modules)]
    return _CONTROLLER[0]


@contextlib.contextmanager
def one_thread() -> Iterator[None]:
    """BLAS and OpenMP limited to one thread inside (threadpoolctl, when installed).

    One thread makes the results independent of the machine's thread count and, for the
    small matrices here, is faster than two threads fighting over two shared cores.
    """
    ctl = _controller()
    if ctl is None:  # pragma: no cover - scikit-learn depends on threadpoolctl
        yield
        return
    with ctl.limit(limits=1):
        yield


def project(x: FloatArray, mean: FloatArray, components: FloatArray) -> FloatArray:
    """Principal components of samples, ``(x - mean) @ components.T``, deterministically.

    Parameters
    ----------
    x : array, shape (m, d)
    mean : array, shape (d,)
    components : array, shape (k, d)

    Returns
    -------
    z : array, shape (m, k)
        Each entry is numpy's pairwise sum of the ``d`` products along the feature axis: it
        depends on that sample's row alone, never on ``m``, on the blocks, or on BLAS threads.
    """
    m, d = x.shape
    k = components.shape[0]
    out = np.zeros((m, k))
    if m == 0 or k == 0 or d == 0:
        return out
    step = max(1, _BLOCK // max(1, k * d))
    for s in range(0, m, step):
        xc = x[s : s + step] - mean
        np.add.reduce(xc[:, None, :] * components[None, :, :], axis=2, out=out[s : s + step])
    return out


def pca(x: FloatArray, *, variance: float, min_k: int, max_k: int,
        n_components: int | None = None) -> tuple[FloatArray, FloatArray, float]:
    """Mean and principal directions of ``x``, shape (n, d).

    With fewer samples than features, the directions come from the ``n x n`` Gram matrix's
    eigenvectors (``X Xt = U S^2 Ut``, ``V = Xt U / S``): the same subspace as the SVD's at
    a fraction of its cost (issue 16). Each direction's sign makes its largest-magnitude
    loading positive, so the result does not depend on the routine.

    Returns
    -------
    mean : array, shape (d,)
    components : array, shape (k, d)
        Orthonormal rows; ``k`` the fewest explaining ``variance`` of the variance (clipped to
        ``min_k..max_k`` and to the rank), or ``n_components``; zero rows pad a short rank.
    explained : float
        Fraction of the variance the ``k`` directions explain.
    """
    n, d = x.shape
    mean = x.mean(axis=0)
    xc = x - mean
    with one_thread():
        if n < d:
            g = xc @ xc.T
            w, u = np.linalg.eigh(g)
            w, u = w[::-1], u[:, ::-1]
            keep = w > max(float(w[0]), 0.0) * 1e-12 if w.size else w > 0
            s = np.sqrt(w[keep])
            vt = (xc.T @ (u[:, keep] / s)).T
            var = w[keep]
        else:
            _, s, vt = np.linalg.svd(xc, full_matrices=False)
            var = s**2
    np.square(xc, out=xc)  # xc is not needed any more: no second (n, d) temporary
    total = float(np.sum(xc))
    if n_components is None:
        frac = np.cumsum(var) / total if total > 0 else np.ones_like(var)
        k = int(np.searchsorted(frac, variance) + 1) if var.size else min_k
        k = max(min_k, min(max_k, k))
    else:
        k = n_components
    comp = vt[:k]
    explained = float(var[:k].sum() / total) if total > 0 else 1.0
    if comp.shape[0] < k:
        comp = np.vstack([comp, np.zeros((k - comp.shape[0], d))])
    idx = np.argmax(np.abs(comp), axis=1)
    signs = np.sign(comp[np.arange(k), idx])
    signs[signs == 0] = 1.0
    return mean, np.ascontiguousarray(comp * signs[:, None]), explained


# --------------------------------------------------------------------------- weighted Ward


def _sqdist(a: FloatArray) -> FloatArray:
    sq = np.einsum("ij,ij->i", a, a)
    g = a @ a.T
    return np.asarray(np.maximum(sq[:, None] + sq[None, :] - 2.0 * g, 0.0), dtype=np.float64)


def ward_merges(points: FloatArray, weights: FloatArray, stop: int = 1) -> IntArray:
    """Weighted Ward agglomeration: the merges, in order, down to ``stop`` clusters.

    Each point stands for ``weights[i]`` samples at ``points[i]``; merging clusters ``a`` and
    ``b`` raises the within-cluster sum of squares by ``wa wb / (wa + wb) |ca - cb|^2`` (Ward's
    criterion), and the cheapest merge goes first. Distances between merged centroids follow
    the Lance-Williams update, so the cost is O(n^2) a merge, O(n^3) in all: meant for the few
    hundred micro-clusters of a summary.

    Returns
    -------
    merges : array of int, shape (n - stop, 2)
        ``(a, b)``: ``b`` merged into ``a`` (indices of the input points; ``a < b``).
    """
    n = points.shape[0]
    if n <= stop:
        return np.zeros((0, 2), dtype=np.int64)
    w = weights.astype(np.float64).copy()
    d2 = _sqdist(points)
    cost = (w[:, None] * w[None, :] / (w[:, None] + w[None, :])) * d2
    np.fill_diagonal(cost, np.inf)
    merges = np.empty((n - stop, 2), dtype=np.int64)
    alive = np.ones(n, dtype=bool)
    for step in range(n - stop):
        flat = int(np.argmin(cost))
        a, b = divmod(flat, n)
        if a > b:
            a, b = b, a
        wa, wb = w[a], w[b]
        wab = wa + wb
        # |c_ab - c_l|^2 from the distances to a and b (Lance-Williams for centroids)
        row = (wa * d2[a] + wb * d2[b]) / wab - wa * wb * d2[a, b] / wab**2
        row = np.maximum(row, 0.0)
        d2[a, :] = row
        d2[:, a] = row
        d2[a, a] = 0.0
        w[a] = wab
        alive[b] = False
        c = (wab * w / (wab + w)) * row
        c[~alive] = np.inf
        cost[a, :] = c
        cost[:, a] = c
        cost[a, a] = np.inf
        cost[b, :] = np.inf
        cost[:, b] = np.inf
        merges[step] = (a, b)
    return merges


def ward_partition(merges: IntArray, n: int, n_clusters: int) -> IntArray:
    """Cluster numbers ``0..c-1`` of ``n`` points after the first ``n - n_clusters`` merges.

    Clusters are numbered in the order of their first point.
    """
    parent = np.arange(n)
    for a, b in merges[: max(0, n - n_clusters)].tolist():
        parent[b] = a
    # follow the links to the roots (a merged point's parent is merged later or is a root)
    for _ in range(n):
        nxt = parent[parent]
        if np.array_equal(nxt, parent):
            break
        parent = nxt
    _, first, inv = np.unique(parent, return_index=True, return_inverse=True)
    rank = np.argsort(np.argsort(first))
    return rank[inv].astype(np.int64)


# --------------------------------------------------------------------------- weighted GMM


@dataclass(frozen=True)
class Mixture:
    """A Gaussian mixture fitted to a weighted summary.

    Attributes
    ----------
    covariance_type : {"spherical", "diag", "tied", "full"}
    weights : array, shape (c,)
    means : array, shape (c, k)
    covariances : array, shape (c, k, k)
        Full matrices whatever the type (a diagonal or a multiple of the identity for the
        constrained types, the same matrix for every component when tied).
    log_likelihood : float
        Expected log-likelihood of the summarised samples.
    bic : float
        Bayesian information criterion, ``-2 log L + p log n`` (lower is better).
    labels : array of int, shape (n_points,)
        Most probable component of each summary point.
    converged : bool
        Whether EM stopped on its tolerance (rather than on ``max_iter``).
    """

    covariance_type: CovarianceType
    weights: FloatArray
    means: FloatArray
    covariances: FloatArray
    log_likelihood: float
    bic: float
    labels: IntArray
    converged: bool = False


def _n_params(c: int, k: int, cov: CovarianceType) -> int:
    per = {"spherical": c, "diag": c * k, "tied": k * (k + 1) // 2,
           "full": c * k * (k + 1) // 2}[cov]
    return c * k + (c - 1) + per


def _log_prob(z: FloatArray, inner: FloatArray, inner_diag: FloatArray, means: FloatArray,
              covs: FloatArray, diagonal: bool) -> FloatArray:
    """Expected log-density of each point's samples under each component, shape (s, n, c).

    ``inner``: each point's within scatter per sample, flattened, shape (n, k * k); a point
    standing for samples spread around ``z`` loses ``tr(Sigma^-1 inner) / 2`` against a
    point mass; ``inner_diag``: its diagonal, shape (n, k). ``means``: shape (s, c, k),
    ``covs``: (s, c, k, k), for ``s`` mixtures fitted side by side; ``diagonal``: every
    covariance is diagonal. Batched over mixtures and components (numpy's stacked Cholesky
    and inverse).
    """
    k = z.shape[1]
    s, c = means.shape[:2]
    if diagonal:
        # spherical and diagonal covariances: the inverse and determinant elementwise
        var = np.diagonal(covs, axis1=2, axis2=3)  # (s, c, k)
        inv_var = 1.0 / var
        logdet = np.log(var).sum(axis=2)
        dz = z[None, None, :, :] - means[:, :, None, :]
        maha = np.matmul(dz * dz, inv_var[:, :, :, None])[..., 0].transpose(0, 2, 1)
        tr = np.matmul(inner_diag, inv_var.transpose(0, 2, 1))
        return np.asarray(-0.5 * (k * math.log(2 * math.pi) + logdet[:, None, :] + maha + tr))
    chol = np.linalg.cholesky(covs)
    logdet = 2.0 * np.log(np.diagonal(chol, axis1=2, axis2=3)).sum(axis=2)
    prec = np.linalg.inv(covs)
    dz = z[None, None, :, :] - means[:, :, None, :]
    maha = (np.matmul(dz, prec) * dz).sum(axis=3).transpose(0, 2, 1)
    # tr(P S) = sum of the elementwise product of P and S (both symmetric)
    tr = np.matmul(inner, prec.reshape(s, c, k * k).transpose(0, 2, 1))
    return np.asarray(-0.5 * (k * math.log(2 * math.pi) + logdet[:, None, :] + maha + tr))


def _m_step(z: FloatArray, w: FloatArray, scatter: FloatArray, resp: FloatArray,
            cov: CovarianceType, reg: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Weights (s, c), means (s, c, k) and covariances (s, c, k, k) of ``s`` mixtures from
    their responsibilities ``resp`` (s, n, c); ``scatter`` flattened, shape (n, k * k)."""
    k = z.shape[1]
    s, _, c = resp.shape
    rw = resp * w[None, :, None]
    rwt = rw.transpose(0, 2, 1)
    nk = rwt.sum(axis=2) + 1e-300
    means = np.matmul(rwt, z) / nk[:, :, None]
    dz = z[None, None, :, :] - means[:, :, None, :]
    within = np.matmul(resp.transpose(0, 2, 1), scatter).reshape(s, c, k, k)
    between = np.matmul((dz * rwt[:, :, :, None]).transpose(0, 1, 3, 2), dz)
    covs = (within + between) / nk[:, :, None, None]
    eye = np.eye(k)
    if cov == "tied":
        covs[:] = ((nk[:, :, None, None] * covs).sum(axis=1, keepdims=True)
                   / nk.sum(axis=1)[:, None, None, None])
    elif cov == "diag":
        covs = np.diagonal(covs, axis1=2, axis2=3)[..., None] * eye
    elif cov == "spherical":
        covs = (np.trace(covs, axis1=2, axis2=3) / k)[:, :, None, None] * eye
    covs = covs + reg * eye
    return nk / nk.sum(axis=1, keepdims=True), means, covs


def fit_mixture(z: FloatArray, weights: FloatArray, scatter: FloatArray, init: IntArray,
                cov: CovarianceType, *, max_iter: int = 100, tol: float = 1e-5,
                reg: float | None = None, reg_factor: float = REG_FACTOR) -> Mixture:
    """EM for a Gaussian mixture on a weighted summary, started from a partition.

    Parameters
    ----------
    z : array, shape (n, k)
        Summary points (micro-cluster centroids in component space).
    weights : array, shape (n,)
        Samples each point stands for.
    scatter : array, shape (n, k, k)
        Within scatter of each point's samples (sum of outer products of deviations).
    init : array of int, shape (n,)
        Starting partition, clusters ``0..c-1`` (a Ward cut).
    cov : {"spherical", "diag", "tied", "full"}
    reg : float or None
        Added to every covariance's diagonal (default: ``reg_factor`` times the mean
        variance per dimension: a scale-free ridge that keeps a component with fewer samples
        than dimensions from collapsing onto them, whose likelihood would grow without
        bound and win any BIC comparison).
    """
    return fit_mixtures(z, weights, scatter, [init], cov, max_iter=max_iter, tol=tol, reg=reg,
                        reg_factor=reg_factor)[0]


def fit_mixtures(z: FloatArray, weights: FloatArray, scatter: FloatArray,
                 inits: Sequence[IntArray], cov: CovarianceType, *, max_iter: int = 100,
                 tol: float = 1e-5, reg: float | None = None,
                 reg_factor: float = REG_FACTOR) -> list[Mixture]:
    """:func:`fit_mixture` from each of ``inits``, the mixtures fitted side by side.

    Starts with the same number of clusters run their EM steps as one stacked computation,
    each stopping at its own convergence: the same fits as one by one (to rounding: stacked
    products may round differently in the last bits, so a start within a rounding error of
    its tolerance can take one step more or less), at a fraction of the
    per-step overhead that dominates on a summary of a few hundred points (issue 16).
    """
    n, k = z.shape
    total_w = float(weights.sum())
    if reg is None:
        mu = (weights @ z) / total_w
        var = (float(np.einsum("aa->", scatter.sum(axis=0)))
               + float((weights * ((z - mu) ** 2).sum(axis=1)).sum())) / (total_w * max(k, 1))
        reg = reg_factor * var + 1e-12
    flat = scatter.reshape(n, k * k)
    inner = flat / weights[:, None]
    inner_diag = np.ascontiguousarray(inner[:, :: k + 1])
    diagonal = cov in ("spherical", "diag")
    out: list[Mixture | None] = [None] * len(inits)
    groups: dict[int, list[int]] = {}
    for i, init in enumerate(inits):
        groups.setdefault(int(init.max()) + 1, []).append(i)
    log_floor = math.log(1e-300)
    for c, members in groups.items():
        resp = np.zeros((len(members), n, c))
        for r, i in enumerate(members):
            resp[r, np.arange(n), inits[i]] = 1.0
        ll = np.full(len(members), -math.inf)
        converged = np.zeros(len(members), dtype=bool)
        active = np.arange(len(members))
        pis = np.zeros((len(members), c))
        mus = np.zeros((len(members), c, k))
        sigmas = np.zeros((len(members), c, k, k))
        for _ in range(max_iter):
            pi, means, covs = _m_step(z, weights, flat, resp[active], cov, reg)
            logp = (_log_prob(z, inner, inner_diag, means, covs, diagonal)
                    + np.maximum(np.log(pi + 1e-300), log_floor)[:, None, :])
            top = logp.max(axis=2, keepdims=True)
            lse = top[:, :, 0] + np.log(np.exp(logp - top).sum(axis=2))
            resp[active] = np.exp(logp - lse[:, :, None])
            new_ll = lse @ weights
            done = np.abs(new_ll - ll[active]) <= tol * np.maximum(1.0, np.abs(new_ll))
            ll[active] = new_ll
            pis[active], mus[active], sigmas[active] = pi, means, covs
            converged[active[done]] = True
            active = active[~done]
            if active.size == 0:
                break
        penalty = _n_params(c, k, cov) * math.log(max(total_w, 2.0))
        for r, i in enumerate(members):
            out[i] = Mixture(cov, pis[r], mus[r], sigmas[r], float(ll[r]),
                             -2.0 * float(ll[r]) + penalty,
                             np.argmax(resp[r], axis=1).astype(np.int64), bool(converged[r]))
    return [m for m in out if m is not None]
