"""Per-part distance fields of the rest body, on grids in each bone's rest frame.

A part is the flesh a bone carries: the points of the rest volume whose
largest skin weight is that bone's. Its field is the signed distance to the
part (negative inside), the larger of the distance to the skin and the
distance to the part's cut (where another bone's weight takes over), stored
on a grid that covers the part and a margin around it. Posed, a part moves
rigidly with its bone, so whether a point of the posed skin lies inside
another part's flesh is one grid lookup in that bone's rest frame (Vaillant et
al., "Implicit Skinning", 2013, keep one field per bone the same way).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy import ndimage

from ..kernels.bvh import closest, mesh_tree
from .heat import continuous_top_k, dense_weights
from .tetra import _column_crossings, _inside_cells


class PartFields(NamedTuple):
    """One grid per part (bone), values flattened x-major into ``values``.

    ``origin`` (J, 3) the position of node (0, 0, 0) at rest; ``cell`` (J,)
    node spacing, metres; ``dims`` (J, 3) node counts (0 for a bone with no
    flesh); ``ptr`` (J + 1,) each grid's start in ``values`` (float32,
    metres).

    The flesh of a part near its joints is not rigid: skinning blends it with
    the neighbouring bones. So each part also keeps the skin weights of its
    bone set ``sets[sptr[j]:sptr[j + 1]]`` (the bone, its parent, children and
    siblings) on a grid of twice the spacing (``wdims``, ``wptr``; channels
    contiguous per node, summing to 1), with which a posed point is carried
    back to the rest point that skinning would have put there; and
    ``wreach`` (the same layout), each bone's most weight within
    :data:`REACH` weight nodes: how far skinning can carry the flesh there
    from where its own bone would.
    """

    origin: np.ndarray
    cell: np.ndarray
    dims: np.ndarray
    ptr: np.ndarray
    values: np.ndarray
    sptr: np.ndarray
    sets: np.ndarray
    wdims: np.ndarray
    wptr: np.ndarray
    wvalues: np.ndarray
    wreach: np.ndarray


#: How far (in weight-grid nodes) ``PartFields.wreach`` looks around a node.
REACH = 3


def lattice_sampler(TV: np.ndarray, cube: float, TW: np.ndarray):
    """A function giving the (k, J) lattice weights ``TW`` (of lattice nodes
    ``TV``, spacing ``cube``) interpolated at points: trilinear over the
    lattice's cubes, the nearest node's outside them."""
    lo = TV.min(0)
    ijk = np.rint((TV - lo) / cube).astype(np.int64)
    dims = ijk.max(0) + 2
    node = -np.ones(dims, dtype=np.int64)
    node[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = np.arange(len(TV))
    from scipy.spatial import cKDTree            # deferred: set-up only
    kd = cKDTree(TV)

    def sample(P):
        u = (P - lo) / cube
        c = np.floor(u).astype(np.int64)
        f = u - c
        out = np.zeros((len(P), TW.shape[1]))
        wsum = np.zeros(len(P))
        for b in range(8):
            o = np.array([(b >> 0) & 1, (b >> 1) & 1, (b >> 2) & 1])
            q = c + o
            ok = np.all((q >= 0) & (q < dims), axis=1)
            n = np.full(len(P), -1)
            n[ok] = node[q[ok, 0], q[ok, 1], q[ok, 2]]
            w = np.prod(np.where(o, f, 1.0 - f), axis=1) * (n >= 0)
            out += w[:, None] * TW[np.maximum(n, 0)]
            wsum += w
        far = wsum < 0.5                                 # not inside the lattice
        if far.any():
            _, nn = kd.query(P[far])
            out[far] = TW[nn]
            wsum[far] = 1.0
        return out / wsum[:, None]
    return sample


def _surface_weights(tree, W, P, inside, depth, sample_weights):
    """(k, J) weights at points ``P``: the surface's own (at the closest
    surface point) outside the body and near the skin, so skinning a rest
    vertex by them gives where the vertex is; the smooth interior field
    ``sample_weights`` from ``depth`` below the skin inwards (``inside`` (k,)
    bool), mixed linearly in between."""
    dist, C, face, vert = closest(tree, P, band=depth)
    Ws = W[vert].copy()
    on = face >= 0
    if on.any():
        Ft = tree.F[face[on]]
        A, B, Cc = (tree.V[Ft[:, k]] for k in range(3))
        # barycentric coordinates of the closest points
        v0, v1, v2 = B - A, Cc - A, C[on] - A
        d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
        d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
        den = np.maximum(d00 * d11 - d01 * d01, 1e-30)
        b1 = (d11 * d20 - d01 * d21) / den
        b2 = (d00 * d21 - d01 * d20) / den
        b0 = 1.0 - b1 - b2
        Ws[on] = b0[:, None] * W[Ft[:, 0]] + b1[:, None] * W[Ft[:, 1]] + b2[:, None] * W[Ft[:, 2]]
    t = np.where(inside, np.clip(2.0 * dist / depth - 1.0, 0.0, 1.0), 0.0)[:, None]
    deep = t[:, 0] > 0
    if deep.any():
        Ws[deep] = (1.0 - t[deep]) * Ws[deep] + t[deep] * sample_weights(P[deep])
    return Ws


def bone_sets(W: np.ndarray, part: np.ndarray, n_parts: int, least: float = 0.01,
              most: int = 8) -> list:
    """Per part: its bone, then the bones that weigh more than ``least`` at
    some surface vertex of the part (at most ``most``, heaviest first): the
    bones skinning blends into the part's flesh."""
    out = []
    for j in range(n_parts):
        mine = part == j
        peak = W[mine].max(axis=0) if mine.any() else np.zeros(W.shape[1])
        others = [int(b) for b in np.argsort(-peak, kind="stable")
                  if b != j and peak[b] > least]
        out.append([j] + others[:most - 1])
    return out


def part_fields(V: np.ndarray, F: np.ndarray, W: np.ndarray, sample_weights, cell: float,
                pad: float, influences: int, max_nodes: int = 64) -> PartFields:
    """The :class:`PartFields` of a closed rest surface ``V, F``.

    Parameters
    ----------
    W : (n, J) float
        The surface's dense skin weights; a vertex's part is its heaviest bone.
    sample_weights : callable
        ``(k, 3) points -> (k, J)`` dense skin weights inside the body.
    influences : int
        Bones per vertex of the skin (:func:`~skin_node.rigging.heat.continuous_top_k`):
        the weight grids keep as many, so they blend as the skin does.
    cell : float
        Node spacing, metres (grown where a part would need more than
        ``max_nodes`` nodes along an axis).
    pad : float
        How far beyond its skin a part's grid reaches, metres.
    """
    tree = mesh_tree(V, F)
    n_parts = W.shape[1]
    part = np.argmax(W, axis=1)
    sets = bone_sets(dense_weights(*continuous_top_k(W, influences), n_parts), part, n_parts)
    wdims = np.zeros((n_parts, 3), dtype=np.int64)
    wchunks, ochunks = [], []
    origin = np.zeros((n_parts, 3))
    cells = np.zeros(n_parts)
    dims = np.zeros((n_parts, 3), dtype=np.int64)
    chunks = []
    for j in range(n_parts):
        mine = part == j
        if not mine.any():
            chunks.append(np.zeros(0, np.float32))
            wchunks.append(np.zeros(0, np.float32))
            ochunks.append(np.zeros(0, np.float32))
            continue
        lo, hi = V[mine].min(0) - pad, V[mine].max(0) + pad
        h = max(cell, float((hi - lo).max()) / (max_nodes - 1))
        d = np.ceil((hi - lo) / h).astype(np.int64) + 1
        # nodes sit at cell centres of the column test's grid (shifted a hair
        # so no column runs through a vertex)
        o = lo + h * 1e-3 * np.array([np.sqrt(2), np.sqrt(3), np.sqrt(5)])
        ptr, zs = _column_crossings(V, F, o[0] - 0.5 * h, o[1] - 0.5 * h, h, d[0], d[1])
        ins = _inside_cells(ptr, zs, o[2] - 0.5 * h, h, d[0], d[1], d[2])
        g = np.stack(np.meshgrid(*[np.arange(k) for k in d], indexing="ij"), -1).reshape(-1, 3)
        P = o + g * h
        dist = closest(tree, P, band=pad)[0]
        dmesh = np.where(ins.ravel(), -dist, dist).reshape(tuple(d))
        # the part's cut: where this bone stops carrying the most weight
        # (weights inside the body; outside it, those of the nearest inside node)
        own = (np.argmax(sample_weights(P), axis=1) == j).reshape(tuple(d))
        cut = (ndimage.distance_transform_edt(~own, sampling=h)
               - ndimage.distance_transform_edt(own, sampling=h))
        cut = np.where(own, cut + 0.5 * h, cut - 0.5 * h)
        cut = ndimage.gaussian_filter(cut, 1.0, mode="nearest")
        s = np.maximum(dmesh, cut)
        origin[j], cells[j], dims[j] = o, h, d
        chunks.append(s.astype(np.float32).ravel())
        # the bone set's weights, every second node
        wd = (d - 1) // 2 + 1
        wd = np.maximum(wd, 2)
        gw = np.stack(np.meshgrid(*[np.arange(k) for k in wd], indexing="ij"), -1).reshape(-1, 3)
        Pw = o + gw * 2.0 * h
        iw = np.minimum(2 * gw, d - 1)
        Ws = _surface_weights(tree, W, Pw, ins[iw[:, 0], iw[:, 1], iw[:, 2]], 4.0 * h,
                              sample_weights)
        Ws = dense_weights(*continuous_top_k(Ws, influences), n_parts)[:, sets[j]]
        tot = Ws.sum(1, keepdims=True)
        Ws = np.where(tot > 1e-6, Ws / np.maximum(tot, 1e-12), np.eye(len(sets[j]))[0])
        wdims[j] = wd
        wchunks.append(Ws.astype(np.float32).ravel())
        reach = ndimage.maximum_filter(Ws.reshape(*wd, -1), size=(*(3 * [2 * REACH + 1]), 1),
                                       mode="nearest")
        ochunks.append(reach.astype(np.float32).ravel())
    ptr = np.zeros(n_parts + 1, dtype=np.int64)
    ptr[1:] = np.cumsum([len(c) for c in chunks])
    wptr = np.zeros(n_parts + 1, dtype=np.int64)
    wptr[1:] = np.cumsum([len(c) for c in wchunks])
    sptr = np.zeros(n_parts + 1, dtype=np.int64)
    sptr[1:] = np.cumsum([len(c) for c in sets])
    return PartFields(origin=origin, cell=cells, dims=dims, ptr=ptr,
                      values=np.concatenate(chunks), sptr=sptr,
                      sets=np.array([b for c in sets for b in c], dtype=np.int64),
                      wdims=wdims, wptr=wptr, wvalues=np.concatenate(wchunks),
                      wreach=np.concatenate(ochunks))
