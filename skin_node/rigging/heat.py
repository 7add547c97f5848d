"""Smooth automatic skin weights: bone heat (Baran & Popovic 2007).

Each bone's weight is the equilibrium temperature of the surface when the
bone is a heat source: ``(-L + M H) w_j = M H p_j``, with ``L`` the cotangent
Laplacian, ``M`` the lumped mass, ``H_ii = c / d_i^2`` for ``d_i`` the distance
from vertex ``i`` to its nearest bone that it can see through the body, and
``p_ij = 1`` where bone ``j`` is that bone. One sparse factorisation serves
every bone. Where the paper's inverse-distance weights switch their candidate
bones from one vertex to the next (and tear the skin along the switch), heat
weights vary smoothly over the surface, and a bone is never weighted by a
vertex that only sees it through air (the torso side under the armpit is the
chest's, not the upper arm's).

The tet-mesh vertices take the same field: its harmonic extension into the
lattice, held to the surface's values where the surface is embedded.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..kernels.bvh import crossings, mesh_tree
from ..skeleton import Skeleton
from .weights import point_segment_distance


def cotangent_laplacian(V: np.ndarray, F: np.ndarray) -> sp.csr_matrix:
    """(n, n) cotangent Laplacian ``L``: ``L_ij = (cot a_ij + cot b_ij) / 2``
    off the diagonal, rows summing to zero (negative semi-definite)."""
    n = len(V)
    L = []
    I, J = [], []
    for k in range(3):
        i, j, o = F[:, (k + 1) % 3], F[:, (k + 2) % 3], F[:, k]
        u, v = V[i] - V[o], V[j] - V[o]
        cot = np.einsum("ij,ij->i", u, v) / np.maximum(np.linalg.norm(np.cross(u, v), axis=1),
                                                       1e-20)
        I += [i, j]
        J += [j, i]
        L += [0.5 * cot, 0.5 * cot]
    W = sp.coo_matrix((np.concatenate(L), (np.concatenate(I), np.concatenate(J))),
                      shape=(n, n)).tocsr()
    return W - sp.diags(np.asarray(W.sum(axis=1)).ravel())


def lumped_mass(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(n,) a third of the area of every triangle around each vertex."""
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]),
                                axis=1)
    m = np.zeros(len(V))
    np.add.at(m, F.ravel(), np.repeat(area / 3.0, 3))
    return m


def vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(n, 3) area-weighted unit vertex normals."""
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    N = np.zeros_like(V)
    for k in range(3):
        np.add.at(N, F[:, k], fn)
    return N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-20)


def _closest_on_segments(P, A, B):
    """(n, S, 3) closest point of every segment to every point."""
    AB = B - A
    t = np.einsum("nsk,sk->ns", P[:, None, :] - A[None], AB) / np.maximum(
        np.einsum("sk,sk->s", AB, AB), 1e-18)
    return A[None] + np.clip(t, 0.0, 1.0)[..., None] * AB[None]


def visible_bones(V: np.ndarray, F: np.ndarray, skel: Skeleton):
    """The nearest bone each surface vertex sees through the body.

    A bone is visible from a vertex when the segment from the vertex (moved a
    hair inwards) to the bone's closest point crosses no triangle.

    Returns
    -------
    P : (n, J) float
        ``P[i, j]`` = 1 for the nearest visible bone of vertex ``i``, else 0.
    d : (n,) float
        Distance to that bone, metres; ``inf`` where no bone is visible.
    """
    seg_joint, A, B = skel.bone_segments()
    Ds = point_segment_distance(V, A, B)                     # (n, S)
    C = _closest_on_segments(V, A, B)
    tree = mesh_tree(V, F)
    N = vertex_normals(V, F)
    edge = float(np.median(np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1)))
    start = V - 1e-3 * edge * N
    order = np.argsort(Ds, axis=1, kind="stable")
    n, S = Ds.shape
    best = np.full(n, -1, dtype=np.int64)
    todo = np.arange(n)
    for r in range(S):                                        # r-th nearest segment
        if not len(todo):
            break
        s = order[todo, r]
        hits = crossings(tree, start[todo], C[todo, s], np.arange(n)[todo])
        ok = hits == 0
        best[todo[ok]] = s[ok]
        todo = todo[~ok]
    d = np.full(n, np.inf)
    seen = best >= 0
    d[seen] = Ds[seen, best[seen]]
    P = np.zeros((n, skel.n_joints))
    P[np.flatnonzero(seen), seg_joint[best[seen]]] = 1.0
    return P, d


def dense_weights(Widx: np.ndarray, Wval: np.ndarray, J: int) -> np.ndarray:
    """(n, J) dense weights from sparse ``Widx, Wval`` (n, K)."""
    W = np.zeros((len(Widx), J))
    np.add.at(W, (np.repeat(np.arange(len(Widx)), Widx.shape[1]), Widx.ravel()), Wval.ravel())
    return W


def continuous_top_k(W: np.ndarray, k: int):
    """The ``k`` largest weights of every row, made continuous: the
    ``(k+1)``-th largest is subtracted from them, so a weight that drops out of
    the top ``k`` reaches zero exactly where it does (a hard cut would leave a
    jump there), then rows are renormalised.

    Returns
    -------
    Widx, Wval : (n, k) int64, float64
        Bone indices and weights, rows summing to 1, non-negative.
    """
    n, J = W.shape
    W = np.maximum(W, 0.0)
    if J < k:
        W = np.hstack([W, np.zeros((n, k - J))])
        J = k
    order = np.argsort(-W, axis=1, kind="stable")
    idx = order[:, :k]
    val = np.take_along_axis(W, idx, axis=1)
    if J > k:
        val = val - np.take_along_axis(W, order[:, k:k + 1], axis=1)
    val = np.maximum(val, 0.0)
    s = val.sum(1, keepdims=True)
    bad = s[:, 0] <= 1e-12             # every bone equal: keep the first
    val[bad] = 0.0
    val[bad, 0] = 1.0
    s[bad] = 1.0
    val = val / s
    idx = np.where(val > 0.0, idx, idx[:, :1])
    return np.ascontiguousarray(idx, dtype=np.int64), np.ascontiguousarray(val)


def bone_heat(V: np.ndarray, F: np.ndarray, skel: Skeleton, c: float = 1.0) -> np.ndarray:
    """(n, J) dense bone-heat weights of the surface ``V, F``, rows summing to 1.

    ``c`` scales the heat sources' strength (Baran & Popovic's 1): larger
    keeps each bone's weight closer to where it is nearest, smaller blends
    wider.
    """
    P, d = visible_bones(V, F, skel)
    L = cotangent_laplacian(V, F)
    m = lumped_mass(V, F)
    H = np.where(np.isfinite(d), c / np.maximum(d, 1e-6) ** 2, 0.0)
    A = (-L + sp.diags(m * H)).tocsc()
    solve = spla.factorized(A)
    rhs = (m * H)[:, None] * P
    W = np.column_stack([solve(rhs[:, j]) if rhs[:, j].any() else np.zeros(len(V))
                         for j in range(skel.n_joints)])
    W = np.clip(W, 0.0, None)
    s = W.sum(1, keepdims=True)
    return W / np.where(s > 0, s, 1.0)


def lattice_extension(Ws: np.ndarray, E: np.ndarray, n_lattice: int, Etet: np.ndarray,
                      Ebary: np.ndarray, stiffness: float = 100.0) -> np.ndarray:
    """(k, J) weights of the tet-lattice vertices: the smoothest field over
    the lattice's edges ``E`` whose barycentric interpolation at every
    embedded surface vertex (tet corners ``Etet``, coordinates ``Ebary``) matches the
    surface weights ``Ws`` (n, J), by least squares with weight ``stiffness``."""
    n = len(Ws)
    rows = np.repeat(np.arange(n), 4)
    cols = Etet.reshape(-1)
    B = sp.coo_matrix((Ebary.reshape(-1), (rows, cols)), shape=(n, n_lattice)).tocsr()
    G = sp.coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n_lattice, n_lattice))
    G = G + G.T
    Lu = sp.diags(np.asarray(G.sum(axis=1)).ravel()) - G
    A = (Lu + stiffness * (B.T @ B) + 1e-9 * sp.eye(n_lattice)).tocsc()
    solve = spla.factorized(A)
    rhs = stiffness * (B.T @ Ws)
    W = np.column_stack([solve(np.ascontiguousarray(rhs[:, j])) for j in range(Ws.shape[1])])
    W = np.clip(W, 0.0, None)
    s = W.sum(1, keepdims=True)
    return W / np.where(s > 0, s, 1.0)
