"""One stateless numba function per constraint, in the shape of XPBD.

Each function reads positions ``X`` at the constraint's vertex indices, the
inverse masses ``w``, the rest value, a PBD stiffness ``k`` in [0, 1], an XPBD
compliance ``alpha`` (already divided by the squared substep) and the
constraint's Lagrange multiplier ``lam``; it writes the position corrections
into the scratch array ``dp`` (rows in the order of the constraint's
vertices) and returns the multiplier increment ``dlam``. It never writes
``X``: the solver loops in :mod:`skin_node.kernels.solver` apply ``dp``.

For a constraint ``C(p) = 0`` (Müller et al. 2007; Macklin et al. 2016):

    dlam  = k * (-C - alpha * lam) / (sum_j w_j |grad_j C|^2 + alpha)
    dp_i  = w_i * dlam * grad_i C

With ``alpha = 0`` this is the paper's PBD step scaled by stiffness ``k``;
with ``k = 1`` and ``alpha > 0`` it is XPBD, whose converged result no longer
depends on the iteration count. A degenerate gradient returns ``dlam = 0``.
"""
from __future__ import annotations

import math

import numba as nb

_EPS = 1e-12


@nb.njit(cache=True, inline="always")
def _step(C, wsum, k, alpha, lam):
    # A vanishing gradient moves nothing, whatever the compliance: without this
    # the multiplier would soak up the whole violation of a collapsed element.
    if wsum < 1e-30:
        return 0.0
    return k * (-C - alpha * lam) / (wsum + alpha)


@nb.njit(cache=True, inline="always")
def stretch_constraint(X, i0, i1, w0, w1, rest, k, alpha, lam, dp):
    """Distance between two vertices: ``C = |p1 - p2| - d``.

    Gradient: ``grad_1 C = n``, ``grad_2 C = -n`` with ``n = (p1 - p2) / |p1 - p2|``.
    """
    dx = X[i0, 0] - X[i1, 0]
    dy = X[i0, 1] - X[i1, 1]
    dz = X[i0, 2] - X[i1, 2]
    L = math.sqrt(dx * dx + dy * dy + dz * dz)
    if L < _EPS:
        dp[0, :] = 0.0
        dp[1, :] = 0.0
        return 0.0
    nx, ny, nz = dx / L, dy / L, dz / L
    dlam = _step(L - rest, w0 + w1, k, alpha, lam)
    dp[0, 0] = w0 * dlam * nx
    dp[0, 1] = w0 * dlam * ny
    dp[0, 2] = w0 * dlam * nz
    dp[1, 0] = -w1 * dlam * nx
    dp[1, 1] = -w1 * dlam * ny
    dp[1, 2] = -w1 * dlam * nz
    return dlam


@nb.njit(cache=True, inline="always")
def _cross(ax, ay, az, bx, by, bz):
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


@nb.njit(cache=True)
def tet_volume(X, i1, i2, i3, i4):
    """Signed volume ``(1/6) [(p1 - p2) x (p1 - p3)] . (p1 - p4)`` of one tet."""
    ax, ay, az = X[i1, 0] - X[i2, 0], X[i1, 1] - X[i2, 1], X[i1, 2] - X[i2, 2]
    bx, by, bz = X[i1, 0] - X[i3, 0], X[i1, 1] - X[i3, 1], X[i1, 2] - X[i3, 2]
    cx, cy, cz = X[i1, 0] - X[i4, 0], X[i1, 1] - X[i4, 1], X[i1, 2] - X[i4, 2]
    ux, uy, uz = _cross(ax, ay, az, bx, by, bz)
    return (ux * cx + uy * cy + uz * cz) / 6.0


@nb.njit(cache=True, inline="always")
def _volume_gradient(X, i1, i2, i3, i4):
    """Signed volume of a tet and the gradients at its vertices 2, 3, 4
    (``grad_1 = -(grad_2 + grad_3 + grad_4)``), as a flat tuple."""
    ax, ay, az = X[i1, 0] - X[i2, 0], X[i1, 1] - X[i2, 1], X[i1, 2] - X[i2, 2]
    bx, by, bz = X[i1, 0] - X[i3, 0], X[i1, 1] - X[i3, 1], X[i1, 2] - X[i3, 2]
    cx, cy, cz = X[i1, 0] - X[i4, 0], X[i1, 1] - X[i4, 1], X[i1, 2] - X[i4, 2]
    g2x, g2y, g2z = _cross(bx, by, bz, cx, cy, cz)
    g3x, g3y, g3z = _cross(cx, cy, cz, ax, ay, az)
    g4x, g4y, g4z = _cross(ax, ay, az, bx, by, bz)
    vol = (g4x * cx + g4y * cy + g4z * cz) / 6.0
    s = -1.0 / 6.0
    return (vol, s * g2x, s * g2y, s * g2z, s * g3x, s * g3y, s * g3z,
            s * g4x, s * g4y, s * g4z)


@nb.njit(cache=True, inline="always")
def volume_constraint(X, t, w, rest, k, alpha, lam, dp):
    """Tet volume: ``C = (1/6) [(p1 - p2) x (p1 - p3)] . (p1 - p4) - V0``.

    With ``a = p1 - p2, b = p1 - p3, c = p1 - p4``: ``grad_2 C = -(b x c)/6``,
    ``grad_3 C = -(c x a)/6``, ``grad_4 C = -(a x b)/6`` and
    ``grad_1 C = -(grad_2 + grad_3 + grad_4)``. ``t`` holds the 4 indices.
    The signed form pushes an inverted tet back through zero towards ``V0``.
    """
    i1, i2, i3, i4 = t[0], t[1], t[2], t[3]
    vol, g2x, g2y, g2z, g3x, g3y, g3z, g4x, g4y, g4z = _volume_gradient(X, i1, i2, i3, i4)
    g1x, g1y, g1z = -(g2x + g3x + g4x), -(g2y + g3y + g4y), -(g2z + g3z + g4z)
    w1, w2, w3, w4 = w[i1], w[i2], w[i3], w[i4]
    wsum = (w1 * (g1x * g1x + g1y * g1y + g1z * g1z) + w2 * (g2x * g2x + g2y * g2y + g2z * g2z)
            + w3 * (g3x * g3x + g3y * g3y + g3z * g3z) + w4 * (g4x * g4x + g4y * g4y + g4z * g4z))
    dlam = _step(vol - rest, wsum, k, alpha, lam)
    dp[0, 0], dp[0, 1], dp[0, 2] = w1 * dlam * g1x, w1 * dlam * g1y, w1 * dlam * g1z
    dp[1, 0], dp[1, 1], dp[1, 2] = w2 * dlam * g2x, w2 * dlam * g2y, w2 * dlam * g2z
    dp[2, 0], dp[2, 1], dp[2, 2] = w3 * dlam * g3x, w3 * dlam * g3y, w3 * dlam * g3z
    dp[3, 0], dp[3, 1], dp[3, 2] = w4 * dlam * g4x, w4 * dlam * g4y, w4 * dlam * g4z
    return dlam


@nb.njit(cache=True, inline="always")
def bind_constraint(X, i, w, ax, ay, az, bx, by, bz, rest, k, alpha, lam, dp):
    """Distance to the posed bone: ``C = |p - p'| - d``.

    ``p'`` is the projection of ``p`` on the bone segment ``a``-``b`` (posed
    with its joint, so it has no inverse mass), ``d`` the rest distance.
    Gradient ``grad_p C = (p - p') / |p - p'|``.
    """
    ex, ey, ez = bx - ax, by - ay, bz - az
    px, py, pz = X[i, 0] - ax, X[i, 1] - ay, X[i, 2] - az
    ee = ex * ex + ey * ey + ez * ez
    s = 0.0
    if ee > _EPS:
        s = (px * ex + py * ey + pz * ez) / ee
        s = min(1.0, max(0.0, s))
    dx, dy, dz = px - s * ex, py - s * ey, pz - s * ez
    L = math.sqrt(dx * dx + dy * dy + dz * dz)
    if L < _EPS:
        dp[0, :] = 0.0
        return 0.0
    wi = w[i]
    dlam = _step(L - rest, wi, k, alpha, lam)
    dp[0, 0] = wi * dlam * dx / L
    dp[0, 1] = wi * dlam * dy / L
    dp[0, 2] = wi * dlam * dz / L
    return dlam


@nb.njit(cache=True, inline="always")
def _centroid(X, t, m):
    """Mass-weighted centroid of a tet and its total mass."""
    M = m[t[0]] + m[t[1]] + m[t[2]] + m[t[3]]
    cx = cy = cz = 0.0
    for a in range(4):
        cx += m[t[a]] * X[t[a], 0]
        cy += m[t[a]] * X[t[a], 1]
        cz += m[t[a]] * X[t[a], 2]
    return cx / M, cy / M, cz / M, M


@nb.njit(cache=True)
def energy_value(X, t, m, ks, rest):
    """The energy constraint's value ``C = 1/2 sum_i k_i (|p_i - p0| - d_i)^2``."""
    cx, cy, cz, M = _centroid(X, t, m)
    C = 0.0
    for a in range(4):
        dx, dy, dz = X[t[a], 0] - cx, X[t[a], 1] - cy, X[t[a], 2] - cz
        e = math.sqrt(dx * dx + dy * dy + dz * dz) - rest[a]
        C += 0.5 * ks[a] * e * e
    return C


@nb.njit(cache=True, inline="always")
def _spring(X, i, cx, cy, cz, ka, ra):
    """One spring of the energy constraint: ``g_i`` (below), ``|p_i - p0| - d_i``
    and its energy ``1/2 k_i (|p_i - p0| - d_i)^2``."""
    dx, dy, dz = X[i, 0] - cx, X[i, 1] - cy, X[i, 2] - cz
    L = math.sqrt(dx * dx + dy * dy + dz * dz)
    e = L - ra
    if L > _EPS:
        f = ka * e / L
        return f * dx, f * dy, f * dz, e, 0.5 * ka * e * e
    return 0.0, 0.0, 0.0, e, 0.5 * ka * e * e


@nb.njit(cache=True, inline="always")
def energy_step(X, t, w, m, ks, rest, k, alpha, lam):
    """Energy conservation (Chen & Pan 2017): springs from each vertex of a tet
    to its mass-weighted centroid ``p0 = sum m_i p_i / sum m_i``::

        C = 1/2 sum_i k_i (|p_i - p0| - d_i)^2

    The paper's gradient ``g_i = k_i (|p_i - p0| - d_i) (p_i - p0) / |p_i - p0|``
    holds ``p0`` fixed. ``p0`` moves with every ``p_i`` (``dp0/dp_i = m_i / M``),
    so the full gradient is ``grad_i C = g_i - (m_i / M) sum_l g_l``; its terms
    sum to zero, which is what keeps the correction from moving the tet's
    centre of mass. ``C >= 0`` has a double root, so one projection halves it.
    ``m`` are the masses, ``ks`` the four spring constants, ``rest`` the ``d_i``.

    Written out for the four corners of ``t`` in scalars (about half the time of
    loops over a scratch array, 15,708 tets): returns ``dlam`` and the twelve
    components of the corrections ``dp_0 .. dp_3``.
    """
    t0, t1, t2, t3 = t[0], t[1], t[2], t[3]
    cx, cy, cz, M = _centroid(X, t, m)
    g0x, g0y, g0z, e0, C0 = _spring(X, t0, cx, cy, cz, ks[0], rest[0])
    g1x, g1y, g1z, e1, C1 = _spring(X, t1, cx, cy, cz, ks[1], rest[1])
    g2x, g2y, g2z, e2, C2 = _spring(X, t2, cx, cy, cz, ks[2], rest[2])
    g3x, g3y, g3z, e3, C3 = _spring(X, t3, cx, cy, cz, ks[3], rest[3])
    emax = max(abs(e0), abs(e1), abs(e2), abs(e3))
    C = C0 + C1 + C2 + C3
    sx, sy, sz = g0x + g1x + g2x + g3x, g0y + g1y + g2y + g3y, g0z + g1z + g2z + g3z
    r = m[t0] / M
    g0x, g0y, g0z = g0x - r * sx, g0y - r * sy, g0z - r * sz
    r = m[t1] / M
    g1x, g1y, g1z = g1x - r * sx, g1y - r * sy, g1z - r * sz
    r = m[t2] / M
    g2x, g2y, g2z = g2x - r * sx, g2y - r * sy, g2z - r * sz
    r = m[t3] / M
    g3x, g3y, g3z = g3x - r * sx, g3y - r * sy, g3z - r * sz
    n0 = g0x * g0x + g0y * g0y + g0z * g0z
    n1 = g1x * g1x + g1y * g1y + g1z * g1z
    n2 = g2x * g2x + g2y * g2y + g2z * g2z
    n3 = g3x * g3x + g3y * g3y + g3z * g3z
    w0, w1, w2, w3 = w[t0], w[t1], w[t2], w[t3]
    dlam = _step(C, w0 * n0 + w1 * n1 + w2 * n2 + w3 * n3, k, alpha, lam)
    # C >= 0 can have a minimum above zero (springs that cannot all be met), where
    # its gradient vanishes and the step C / |grad C| grows without bound: a tet
    # near one would throw its vertices centimetres and flip between frames. No
    # vertex moves farther than the tet's largest spring error.
    big2 = max(w0 * w0 * n0, w1 * w1 * n1, w2 * w2 * n2, w3 * w3 * n3) * dlam * dlam
    if big2 > emax * emax:                  # compared squared: no root per vertex
        dlam *= emax / math.sqrt(big2)
    s0, s1, s2, s3 = w0 * dlam, w1 * dlam, w2 * dlam, w3 * dlam
    return (dlam, g0x * s0, g0y * s0, g0z * s0, g1x * s1, g1y * s1, g1z * s1,
            g2x * s2, g2y * s2, g2z * s2, g3x * s3, g3y * s3, g3z * s3)


@nb.njit(cache=True, inline="always")
def energy_constraint(X, t, w, m, ks, rest, k, alpha, lam, dp):
    """:func:`energy_step` of tet ``t`` with the corrections written into ``dp``,
    in the form of the other constraints (the sweeps call :func:`energy_step`)."""
    (dlam, dp[0, 0], dp[0, 1], dp[0, 2], dp[1, 0], dp[1, 1], dp[1, 2], dp[2, 0], dp[2, 1],
     dp[2, 2], dp[3, 0], dp[3, 1], dp[3, 2]) = energy_step(X, t, w, m, ks, rest, k, alpha,
                                                           lam)
    return dlam


@nb.njit(cache=True, inline="always")
def contact_constraint(X, i, w, cx, cy, cz, nx, ny, nz, dp):
    """One-sided contact with a plane: ``C = n . (p - c) >= 0``.

    Past the paper: where two limbs fold onto each other, each tet vertex of
    the fold must stay on its own side of the contact plane through the joint
    (``n`` unit, pointing to the vertex's side). Enforced inside the solve, the
    volume constraints then push the squeezed flesh outwards instead of letting
    the post-process flatten it away. Returns ``C`` (negative when projected).
    """
    C = nx * (X[i, 0] - cx) + ny * (X[i, 1] - cy) + nz * (X[i, 2] - cz)
    if C >= 0.0 or w[i] == 0.0:
        dp[0, 0] = dp[0, 1] = dp[0, 2] = 0.0
        return 0.0
    dp[0, 0], dp[0, 1], dp[0, 2] = -C * nx, -C * ny, -C * nz
    return C


@nb.njit(cache=True)
def zone_volume_constraint(X, T, tets, verts, w, rest, k, g):
    """Total volume of a set of tets: ``C = sum_t V_t - V0`` (``V0`` their rest sum).

    Past the paper: one constraint over a whole joint zone. Its gradient is the
    sum of the tets' volume gradients, which cancels at interior vertices and
    is the area-weighted normal on the zone's boundary, so one projection
    inflates (or deflates) the zone's skin evenly: flesh squeezed at a fold
    reappears as a bulge around it in one step instead of diffusing tet by
    tet. ``verts`` are the tets' vertices (each once). Its vertices are many,
    so it writes its gradient into ``g`` (k,3), rows by vertex id, instead of
    corrections into ``dp``: ``dp_i = w_i dlam g_i`` with
    ``dlam = -k C / (sum_j w_j |g_j|^2)``, applied by
    :func:`skin_node.kernels.solver.zone_volume_sweep`. Returns ``(dlam, C)``.
    """
    for a in range(verts.shape[0]):
        i = verts[a]
        g[i, 0] = g[i, 1] = g[i, 2] = 0.0
    vol = 0.0
    for a in range(tets.shape[0]):
        i1, i2, i3, i4 = T[tets[a], 0], T[tets[a], 1], T[tets[a], 2], T[tets[a], 3]
        v, g2x, g2y, g2z, g3x, g3y, g3z, g4x, g4y, g4z = _volume_gradient(X, i1, i2, i3, i4)
        vol += v
        g[i2, 0] += g2x
        g[i2, 1] += g2y
        g[i2, 2] += g2z
        g[i3, 0] += g3x
        g[i3, 1] += g3y
        g[i3, 2] += g3z
        g[i4, 0] += g4x
        g[i4, 1] += g4y
        g[i4, 2] += g4z
        g[i1, 0] -= g2x + g3x + g4x
        g[i1, 1] -= g2y + g3y + g4y
        g[i1, 2] -= g2z + g3z + g4z
    C = vol - rest
    wsum = 0.0
    for a in range(verts.shape[0]):
        i = verts[a]
        wsum += w[i] * (g[i, 0] ** 2 + g[i, 1] ** 2 + g[i, 2] ** 2)
    if wsum < _EPS * _EPS:
        return 0.0, C
    return -k * C / wsum, C
