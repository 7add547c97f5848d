"""Exact self-intersection counts (skin_node.kernels.intersect)."""
from fractions import Fraction

import numpy as np
import pytest
import trimesh

from skin_node.kernels.collision import fit_tree
from skin_node.kernels.intersect import (SelfIntersections, crossing_pairs, node_parts,
                                         triangles_intersect)


def _exact_intersect(T1, T2) -> bool:
    """Whether two triangles meet, in rational arithmetic: some edge of one
    crosses the other (boundaries included; coplanar pairs apart)."""
    P = [[Fraction(float(x)) for x in r] for r in np.vstack([T1, T2])]

    def sub(a, b):
        return [a[i] - b[i] for i in range(3)]

    def cross(a, b):
        return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]

    def dot(a, b):
        return sum(a[i] * b[i] for i in range(3))

    def edge_crosses(p, q, a, b, c):
        n = cross(sub(b, a), sub(c, a))
        dp, dq = dot(n, sub(p, a)), dot(n, sub(q, a))
        if dp * dq > 0 or (dp == 0 and dq == 0):
            return False
        t = dp / (dp - dq)
        x = [p[i] + (q[i] - p[i]) * t for i in range(3)]
        s = [dot(n, cross(sub(v, u), sub(x, u))) for u, v in ((a, b), (b, c), (c, a))]
        return all(v >= 0 for v in s) or all(v <= 0 for v in s)

    A, B = P[:3], P[3:]
    return (any(edge_crosses(A[i], A[(i + 1) % 3], *B) for i in range(3))
            or any(edge_crosses(B[i], B[(i + 1) % 3], *A) for i in range(3)))


def test_the_pair_test_agrees_with_exact_arithmetic_on_random_triangles():
    rng = np.random.default_rng(3)
    got, want = [], []
    for _ in range(1500):
        X = rng.normal(size=(6, 3))
        got.append(triangles_intersect(X, 0, 1, 2, 3, 4, 5))
        want.append(_exact_intersect(X[:3], X[3:]))
    assert got == want
    assert 200 < sum(want) < 1300                     # both answers are exercised


def test_a_triangle_through_another_and_beside_it():
    X = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0],      # in z = 0
                  [0.2, 0.2, -0.5], [0.3, 0.2, 0.5], [0.2, 0.3, 0.5]])    # pierces it
    assert triangles_intersect(X, 0, 1, 2, 3, 4, 5)
    assert triangles_intersect(X, 3, 4, 5, 0, 1, 2)
    X[3:, 2] += 0.6                                    # lifted clear of the plane
    assert not triangles_intersect(X, 0, 1, 2, 3, 4, 5)
    X[3:] = [[2.0, 2.0, -0.5], [2.1, 2.0, 0.5], [2.0, 2.1, 0.5]]   # through the plane, beside
    assert not triangles_intersect(X, 0, 1, 2, 3, 4, 5)
    X[3:] = [[0.2, 0.2, 0.0], [0.5, 0.2, 0.0], [0.2, 0.5, 0.0]]    # lying on it
    assert not triangles_intersect(X, 0, 1, 2, 3, 4, 5)


def test_a_closed_surface_has_none_until_skin_is_pushed_through_skin():
    s = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    V, F = np.array(s.vertices), np.array(s.faces, dtype=np.int64)
    edge = float(np.median(s.edges_unique_length))
    count = SelfIntersections(V, F, apart=3 * edge)
    assert count(V) == (0, 0)
    # The top vertex pushed down through the bottom of the sphere: its fan of
    # triangles passes through skin that was a diameter away.
    top = int(np.argmax(V[:, 2]))
    X = V.copy()
    X[top, 2] = -0.13
    through, crumpled = count(X)
    fan = np.flatnonzero((F == top).any(axis=1))
    assert through >= len(fan) and crumpled == 0
    pairs = count.pairs(X)
    assert np.isin(pairs, fan).any(axis=1).all()       # every pair has one of the fan's
    assert (pairs[:, 0] < pairs[:, 1]).all() and len(np.unique(pairs, axis=0)) == len(pairs)
    for f, g in pairs:
        assert _exact_intersect(X[F[f]], X[F[g]])


def test_pairs_nearer_than_apart_at_rest_count_as_crumpled():
    s = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    V, F = np.array(s.vertices), np.array(s.faces, dtype=np.int64)
    X = V.copy()
    X[int(np.argmax(V[:, 2])), 2] = -0.13
    through, crumpled = SelfIntersections(V, F, apart=0.01)(X)
    assert through > 0 and crumpled == 0
    # the same pairs, all nearer than a distance longer than the sphere
    assert SelfIntersections(V, F, apart=0.5)(X) == (0, through)


def test_skipping_a_query_s_own_part_finds_the_same_pairs_in_the_same_order():
    s = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    V, F = np.array(s.vertices), np.array(s.faces, dtype=np.int64)
    # three parts (bands by height); the top part's cap pushed down through
    # the others' skin
    fpart = np.digitize(V[F].mean(axis=1)[:, 2], [-0.03, 0.03]).astype(np.int64)
    X = V.copy()
    X[V[:, 2] > 0.08, 2] -= 0.2
    si = SelfIntersections(V, F, 0.0)
    t = si.tree
    fit_tree(X, t, si.fit, True)
    npart = node_parts(t, si.tris, fpart)
    assert (npart >= 0).any() and (npart == -1).any()   # both kinds of node
    for k in range(len(npart)):                         # a node's part is its triangles'
        if npart[k] >= 0:
            leaves = [k]
            under = []
            while leaves:
                n = leaves.pop()
                if t.child[n, 0] >= 0:
                    leaves += list(t.child[n])
                else:
                    under += list(si.tris[t.slot[t.first[n]:t.first[n] + t.count[n]]])
            assert (fpart[under] == npart[k]).all()
    inq = np.ones(len(F), dtype=np.bool_)
    out = np.empty((4096, 2), dtype=np.int64)

    def search(parts):
        n = crossing_pairs(X, F, si.tris, inq, fpart, parts, t.roots, t.child, t.first,
                           t.count, t.slot, si.tris, *si.fit[:4], out)
        return out[:n].copy()

    plain = search(np.full(len(npart), -1, dtype=np.int64))
    assert len(plain) > 20 and (fpart[plain[:, 0]] != fpart[plain[:, 1]]).all()
    np.testing.assert_array_equal(search(npart), plain)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_skin_counts_nothing_rather_than_failing(bad):
    s = trimesh.creation.icosphere(subdivisions=1, radius=0.1)
    V, F = np.array(s.vertices), np.array(s.faces, dtype=np.int64)
    X = V.copy()
    X[0] = bad
    through, crumpled = SelfIntersections(V, F, apart=0.05)(X)
    assert through >= 0 and crumpled >= 0
