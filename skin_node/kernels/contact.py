"""Contact between the body's parts through their rest distance fields (numba).

Each surface vertex belongs to one part (its largest-weight bone). Posed, a
vertex of part ``a`` must stay out of every other part ``b``'s flesh, which
moves rigidly with bone ``b``: with ``s_b`` the signed distance to part ``b``
at rest (:mod:`skin_node.rigging.fields`) and ``x_b = M_b^-1 p`` the vertex
carried back into ``b``'s rest frame,

    C_b(p) = s_b(x_b) - s_a(x_a) - min(m, r_b) >= 0,

``m`` a margin, ``r_b`` the same difference at rest (skin that touches, or
sits near a cut, at rest may stay as near). ``C_b = 0`` is the surface where
the two parts' fields meet: skin of both sides stops a margin short of it, so
the sides meet on one crease instead of passing through each other. A
violated constraint is projected along its gradient,
``dp = -C grad C / |grad C|^2`` (Muller et al. 2007).
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from .skinning import _turn

#: Field value outside a part's grid: no contact possible there.
FAR = 1e9
#: ``skin_node.rigging.fields.REACH``: how far the other-weight grid looks.
REACH = 3


@nb.njit(cache=True, nogil=True, inline="always")
def field_at(values, ptr, origin, cell, dims, j, x, y, z, clamp):
    """Trilinear value and gradient of part ``j``'s field at rest point
    ``(x, y, z)``; :data:`FAR` and a zero gradient outside its grid (inside
    the grid's border cells with ``clamp``)."""
    nx, ny, nz = dims[j, 0], dims[j, 1], dims[j, 2]
    if nx < 2:
        return FAR, 0.0, 0.0, 0.0
    h = cell[j]
    u = (x - origin[j, 0]) / h
    v = (y - origin[j, 1]) / h
    w = (z - origin[j, 2]) / h
    if clamp:
        u = min(max(u, 0.0), nx - 1.000001)
        v = min(max(v, 0.0), ny - 1.000001)
        w = min(max(w, 0.0), nz - 1.000001)
    elif u < 0.0 or v < 0.0 or w < 0.0 or u >= nx - 1 or v >= ny - 1 or w >= nz - 1:
        return FAR, 0.0, 0.0, 0.0
    i, k, l = int(u), int(v), int(w)
    fu, fv, fw = u - i, v - k, w - l
    b = ptr[j] + (i * ny + k) * nz + l
    sy, sx = nz, ny * nz
    c000, c001 = values[b], values[b + 1]
    c010, c011 = values[b + sy], values[b + sy + 1]
    c100, c101 = values[b + sx], values[b + sx + 1]
    c110, c111 = values[b + sx + sy], values[b + sx + sy + 1]
    c00 = c000 + (c001 - c000) * fw
    c01 = c010 + (c011 - c010) * fw
    c10 = c100 + (c101 - c100) * fw
    c11 = c110 + (c111 - c110) * fw
    c0 = c00 + (c01 - c00) * fv
    c1 = c10 + (c11 - c10) * fv
    val = c0 + (c1 - c0) * fu
    gx = (c1 - c0) / h
    gy = ((c01 - c00) * (1.0 - fu) + (c11 - c10) * fu) / h
    d0 = (c001 - c000) * (1.0 - fv) + (c011 - c010) * fv
    d1 = (c101 - c100) * (1.0 - fv) + (c111 - c110) * fv
    gz = (d0 * (1.0 - fu) + d1 * fu) / h
    return val, gx, gy, gz


@nb.njit(cache=True, nogil=True, inline="always")
def _blend(Q, sets, s0, s1, wvalues, wptr, wdims, origin, cell, j, x, y, z, exclude):
    """The dual quaternion (real w, x, y, z; translation) that skinning gives
    rest point ``(x, y, z)`` of part ``j``'s flesh: its bone set's weights
    there (trilinear, clamped to the grid) but bone ``exclude``'s, blended as
    in :func:`dqs`."""
    nx, ny, nz = wdims[j, 0], wdims[j, 1], wdims[j, 2]
    h = 2.0 * cell[j]
    u = min(max((x - origin[j, 0]) / h, 0.0), nx - 1.000001)
    v = min(max((y - origin[j, 1]) / h, 0.0), ny - 1.000001)
    w = min(max((z - origin[j, 2]) / h, 0.0), nz - 1.000001)
    i, k, l = int(u), int(v), int(w)
    fu, fv, fw = u - i, v - k, w - l
    ns = s1 - s0
    j0 = sets[s0]
    # the eight corners' trilinear weights and offsets into the grid
    gu, gv, gw = 1.0 - fu, 1.0 - fv, 1.0 - fw
    base = wptr[j] + ((i * ny + k) * nz + l) * ns
    sx, sy = ny * nz * ns, nz * ns
    c000, c001, c010, c011 = gu * gv * gw, gu * gv * fw, gu * fv * gw, gu * fv * fw
    c100, c101, c110, c111 = fu * gv * gw, fu * gv * fw, fu * fv * gw, fu * fv * fw
    b0 = b1 = b2 = b3 = b4 = b5 = b6 = b7 = 0.0
    for c in range(ns):
        o = base + c
        wt = (c000 * wvalues[o] + c001 * wvalues[o + ns] + c010 * wvalues[o + sy]
              + c011 * wvalues[o + sy + ns] + c100 * wvalues[o + sx]
              + c101 * wvalues[o + sx + ns] + c110 * wvalues[o + sx + sy]
              + c111 * wvalues[o + sx + sy + ns])
        b = sets[s0 + c]
        if wt == 0.0 or b == exclude:
            continue
        if Q[b, 0] * Q[j0, 0] + Q[b, 1] * Q[j0, 1] + Q[b, 2] * Q[j0, 2] + Q[b, 3] * Q[j0, 3] < 0:
            wt = -wt
        b0 += wt * Q[b, 0]
        b1 += wt * Q[b, 1]
        b2 += wt * Q[b, 2]
        b3 += wt * Q[b, 3]
        b4 += wt * Q[b, 4]
        b5 += wt * Q[b, 5]
        b6 += wt * Q[b, 6]
        b7 += wt * Q[b, 7]
    norm = np.sqrt(b0 * b0 + b1 * b1 + b2 * b2 + b3 * b3)
    if norm < 1e-9:
        # all the weight here is the excluded bone's: the part's own bone carries it
        b0, b1, b2, b3 = Q[j, 0], Q[j, 1], Q[j, 2], Q[j, 3]
        b4, b5, b6, b7 = Q[j, 4], Q[j, 5], Q[j, 6], Q[j, 7]
        norm = 1.0
    inv = 1.0 / norm
    w0, x0, y0, z0 = b0 * inv, b1 * inv, b2 * inv, b3 * inv
    we, xe, ye, ze = b4 * inv, b5 * inv, b6 * inv, b7 * inv
    tx = 2.0 * (-we * x0 + xe * w0 - ye * z0 + ze * y0)
    ty = 2.0 * (-we * y0 + ye * w0 - ze * x0 + xe * z0)
    tz = 2.0 * (-we * z0 + ze * w0 - xe * y0 + ye * x0)
    return w0, x0, y0, z0, tx, ty, tz


@nb.njit(cache=True, nogil=True, inline="always")
def skinned_field(pf, Q, j, px, py, pz, x, y, z, iterations, clamp, exclude):
    """Part ``j``'s field at posed point ``p`` and its posed gradient.

    ``p`` is carried back to the rest point of part ``j``'s flesh that
    skinning puts there (fixed-point iteration ``x <- T(x)^-1 p`` from the
    guess ``x``, T the part's blend at x), so flesh that skinning bends with
    a third bone is where the skin really is, not where its own bone alone
    would put it. The blend leaves out bone ``exclude`` (-1: none). Returns
    (value, gx, gy, gz, x, y, z), the last three the rest point it settled
    on; value :data:`FAR` outside the grid.
    """
    origin, cell, dims, ptr, values, sptr, sets, wdims, wptr, wvalues = pf[:10]
    w0 = x0 = y0 = z0 = 0.0
    for _ in range(iterations):
        w0, x0, y0, z0, tx, ty, tz = _blend(Q, sets, sptr[j], sptr[j + 1], wvalues, wptr,
                                            wdims, origin, cell, j, x, y, z, exclude)
        x, y, z = _turn(w0, -x0, -y0, -z0, px - tx, py - ty, pz - tz)
    val, gx, gy, gz = field_at(values, ptr, origin, cell, dims, j, x, y, z, clamp)
    if val >= FAR:
        return FAR, 0.0, 0.0, 0.0, x, y, z
    gx, gy, gz = _turn(w0, x0, y0, z0, gx, gy, gz)
    return val, gx, gy, gz, x, y, z


@nb.njit(cache=True, nogil=True, inline="always")
def _to_rest(Minv, j, px, py, pz):
    """Posed point ``p`` carried back by bone ``j`` alone (``Minv[j]``)."""
    return (Minv[j, 0, 0] * px + Minv[j, 0, 1] * py + Minv[j, 0, 2] * pz + Minv[j, 0, 3],
            Minv[j, 1, 0] * px + Minv[j, 1, 1] * py + Minv[j, 1, 2] * pz + Minv[j, 1, 3],
            Minv[j, 2, 0] * px + Minv[j, 2, 1] * py + Minv[j, 2, 2] * pz + Minv[j, 2, 3])


@nb.njit(cache=True, nogil=True, inline="always")
def _reach(pf, Minv, b, a, px, py, pz, xb, yb, zb):
    """How far skinning can carry part ``b``'s flesh near rest point ``x_b``
    from where bone ``b`` alone puts it, for the posed point ``p``: the sum
    over ``b``'s other bones (but ``a``, left out of the blend) of their
    most weight near there (``PartFields.wreach``, the weight node nearest
    ``x_b``) times how far apart they and ``b`` carry ``p`` back."""
    origin, cell, sptr, sets, wdims, wptr, wreach = (pf[0], pf[1], pf[5], pf[6], pf[7], pf[8],
                                                      pf[10])
    h = 2.0 * cell[b]
    nx, ny, nz = wdims[b, 0], wdims[b, 1], wdims[b, 2]
    i = min(max(int(round((xb - origin[b, 0]) / h)), 0), nx - 1)
    k = min(max(int(round((yb - origin[b, 1]) / h)), 0), ny - 1)
    l = min(max(int(round((zb - origin[b, 2]) / h)), 0), nz - 1)
    ns = sptr[b + 1] - sptr[b]
    base = wptr[b] + ((i * ny + k) * nz + l) * ns
    out = 0.0
    for c in range(1, ns):                 # channel 0 is b's own bone
        o = sets[sptr[b] + c]
        if o == a:
            continue
        w = wreach[base + c]
        if w <= 0.0:
            continue
        xo, yo, zo = _to_rest(Minv, o, px, py, pz)
        out += w * math.sqrt((xo - xb) ** 2 + (yo - yb) ** 2 + (zo - zb) ** 2)
    return out


@nb.njit(cache=True, nogil=True, inline="always")
def _gap(lx, ly, lz, hx, hy, hz, x, y, z):
    """Distance from point ``(x, y, z)`` to the box ``l``-``h`` (0 inside)."""
    dx = max(lx - x, x - hx, 0.0)
    dy = max(ly - y, y - hy, 0.0)
    dz = max(lz - z, z - hz, 0.0)
    return math.sqrt(dx * dx + dy * dy + dz * dz)


@nb.njit(cache=True, nogil=True, inline="always")
def _box_gap(box, b, x, y, z):
    """Distance from rest point ``(x, y, z)`` to part ``b``'s box."""
    return _gap(box[b, 0, 0], box[b, 0, 1], box[b, 0, 2], box[b, 1, 0], box[b, 1, 1],
                box[b, 1, 2], x, y, z)


@nb.njit(cache=True, nogil=True, inline="always")
def _grid_gap(origin, cell, dims, j, x, y, z):
    """Distance from rest point ``(x, y, z)`` to part ``j``'s grid (0 inside)."""
    h = cell[j]
    return _gap(origin[j, 0], origin[j, 1], origin[j, 2], origin[j, 0] + (dims[j, 0] - 1) * h,
                origin[j, 1] + (dims[j, 1] - 1) * h, origin[j, 2] + (dims[j, 2] - 1) * h,
                x, y, z)


@nb.njit(cache=True, nogil=True, inline="always")
def _in_grid(origin, cell, dims, j, x, y, z, pad):
    """Whether rest point ``(x, y, z)`` lies within ``pad`` of part ``j``'s grid."""
    h = cell[j]
    return (dims[j, 0] > 1
            and origin[j, 0] - pad <= x <= origin[j, 0] + (dims[j, 0] - 1) * h + pad
            and origin[j, 1] - pad <= y <= origin[j, 1] + (dims[j, 1] - 1) * h + pad
            and origin[j, 2] - pad <= z <= origin[j, 2] + (dims[j, 2] - 1) * h + pad)


@nb.njit(cache=True, nogil=True, inline="always")
def worst_contact(X, V0, i, a, cand, c0, c1, Q, Minv, pf, box, margin, onset, deep, fade,
                  face0, face1, iterations, only, pre, clear, reach, apart):
    """The most violated contact constraint of vertex ``i`` of part ``a``
    among parts ``cand[c0:c1]``: (C, gradient x, y, z, the part); C >= 0
    when none is. ``pre[i]`` (6,) gets the rest points the two parts' fields
    were read at for that part. With ``only`` >= 0 that part alone is tested
    (it was this vertex's worst a moment ago), carried from ``pre[i]`` with
    one iteration: the skin has moved by a fraction of a margin since.

    Each part's flesh is where skinning puts it, blended with every bone but
    the other party's: near their shared joint each side moves as its own
    bone carries it, so skin that the blend swung past the other side's
    (the inside of a deep bend, where skinning folds flesh over itself) is
    seen inside it, while flesh that a third bone blends (a thigh's and the
    pelvis's at the crotch) still moves with that bone. ``box`` (J, 2, 3):
    each part's posed skin carried back by its bone alone, bounded; skin
    outside another part's box is outside its flesh.

    With all parts tested (``only`` < 0), ``clear[i]`` is lowered to a lower
    bound of the vertex's distance from the flesh of each part ``b`` with
    ``apart[a, b]``: the field read, the rigid bound that let it skip the
    carry, its distance from the part's grid or from its box (grown by
    ``reach``) plus ``reach``.

    A pair coming in (``fade[a, b]`` < 1, :func:`contact_pairs`) lets skin
    lie up to ``(1 - fade) * deep[b]`` deep in ``b``'s flesh (``deep``: how
    deep each part's flesh goes): at the angle it is first tested the pair
    pushes nothing, and its contact tightens as it turns on, instead of
    pushing skin that already lay in the other flesh out in one frame.
    """
    origin, cell, dims, ptr, values = pf[0], pf[1], pf[2], pf[3], pf[4]
    px, py, pz = X[i, 0], X[i, 1], X[i, 2]
    rx, ry, rz = V0[i, 0], V0[i, 1], V0[i, 2]
    worst, wx, wy, wz, wb = 0.0, 0.0, 0.0, 0.0, -1
    # one loop for both cases, so the fields are read in one place (each read
    # is inlined: a call would pass, and count references to, a dozen arrays)
    lo, hi = (0, 1) if only >= 0 else (c0, c1)
    for c in range(lo, hi):
        if only >= 0:
            b, n = only, 1
            xb, yb, zb = pre[i, 0], pre[i, 1], pre[i, 2]
            xa, ya, za = pre[i, 3], pre[i, 4], pre[i, 5]
        else:
            b, n = cand[c], iterations
            xb, yb, zb = _to_rest(Minv, b, px, py, pz)
            if not (box[b, 0, 0] <= xb <= box[b, 1, 0] and box[b, 0, 1] <= yb <= box[b, 1, 1]
                    and box[b, 0, 2] <= zb <= box[b, 1, 2]):
                if apart[a, b]:
                    clear[i] = min(clear[i], _box_gap(box, b, xb, yb, zb) + reach)
                continue
            if not _in_grid(origin, cell, dims, b, xb, yb, zb, 0.0):
                if apart[a, b]:
                    clear[i] = min(clear[i], _grid_gap(origin, cell, dims, b, xb, yb, zb))
                continue
            # skinning carries b's flesh by a blend of its bone set (without a):
            # the point's preimage lies no further from where b's bone alone puts
            # it than its other bones' weight there times how far they put the
            # point apart (:func:`_reach`), so the field (1-Lipschitz) cannot be
            # negative there if it is larger than that here (the weights are the
            # most within REACH nodes, which covers the preimage while that
            # distance is within it)
            s_rigid, _, _, _ = field_at(values, ptr, origin, cell, dims, b, xb, yb, zb, False)
            if s_rigid >= FAR:
                if apart[a, b]:
                    clear[i] = 0.0
                continue
            shift = 1.25 * _reach(pf, Minv, b, a, px, py, pz, xb, yb, zb)
            if s_rigid > shift + onset[i] and shift <= REACH * 2.0 * cell[b]:
                if apart[a, b]:
                    clear[i] = min(clear[i], s_rigid - shift)
                continue
            xa, ya, za = rx, ry, rz
        sb, ux, uy, uz, qbx, qby, qbz = skinned_field(pf, Q, b, px, py, pz, xb, yb, zb, n,
                                                      False, a)
        if only < 0 and apart[a, b]:
            # carried out of the grid: at least as far as the grid
            clear[i] = min(clear[i], sb if sb < FAR else
                           _grid_gap(origin, cell, dims, b, qbx, qby, qbz))
        sb += (1.0 - fade[a, b]) * deep[b]
        if sb >= onset[i]:
            continue
        sa, vx, vy, vz, qax, qay, qaz = skinned_field(pf, Q, a, px, py, pz, xa, ya, za, n,
                                                      True, b)
        C = _gated(sb, sa, ux, uy, uz, vx, vy, vz, margin[i], onset[i], pf, a, b, rx, ry, rz,
                   face0, face1)
        if C < worst:
            worst, wx, wy, wz, wb = C, ux - vx, uy - vy, uz - vz, b
            pre[i, 0], pre[i, 1], pre[i, 2] = qbx, qby, qbz
            pre[i, 3], pre[i, 4], pre[i, 5] = qax, qay, qaz
    return worst, wx, wy, wz, wb


@nb.njit(cache=True, nogil=True, inline="always")
def _gated(sb, sa, ux, uy, uz, vx, vy, vz, margin, onset, pf, a, b, rx, ry, rz, face0, face1):
    """The constraint ``s_b - s_a - min(m, rest)`` of a vertex in or near part
    ``b``'s flesh (``sb`` < ``onset``), faded in from ``onset`` outside it
    to a margin of depth and out where the two parts' gradients agree; >= 0
    when satisfied.

    Faded in from the flesh's surface, the constraint moved skin in the first
    margin of depth a fraction of the way out and skin on the surface not at
    all; on a fine mesh that is harmless, but the flat triangles of a coarse
    limb sink below its round surface between the vertices (by the chord's
    sagitta), so where one lay on another their triangles crossed while every
    vertex stayed outside (CesiumMan's arms on its hips). ``onset`` is a few
    such sagittas: on fine skin a fraction of a millimetre."""
    origin, cell, dims, ptr, values = pf[0], pf[1], pf[2], pf[3], pf[4]
    ra, _, _, _ = field_at(values, ptr, origin, cell, dims, a, rx, ry, rz, True)
    rb, _, _, _ = field_at(values, ptr, origin, cell, dims, b, rx, ry, rz, False)
    C = sb - sa - min(margin, rb - ra)
    if C >= 0.0:
        return C
    # the constraint fades in from ``onset`` outside the other part's flesh
    # to a margin inside it, so nothing jumps
    t = min(1.0, (onset - sb) / max(onset + margin, 1e-9))
    C *= t * t * (3.0 - 2.0 * t)
    # where the two parts' skins run on into each other (across a cut) their
    # fields rise together and their difference says nothing: fade out
    nu = np.sqrt((ux * ux + uy * uy + uz * uz) * (vx * vx + vy * vy + vz * vz))
    cos = (ux * vx + uy * vy + uz * vz) / max(nu, 1e-12)
    t = min(1.0, max(0.0, (face0 - cos) / (face0 - face1)))
    return C * t * t * (3.0 - 2.0 * t)


@nb.njit(cache=True, nogil=True, parallel=True)
def project_contacts(X, V0, verts, side, cand_ptr, cand, Q, Minv, pf, box, margin, onset,
                     deep, fade, face0, face1, iterations, steps, moved, plane, hit, recheck,
                     pre, clear, reach, apart):
    """Project every vertex of ``verts`` out of the other parts' flesh, up to
    ``steps`` Newton steps each (vertices are independent: Jacobi, so they
    run in parallel and the result does not depend on the threads). Parts to
    test for a vertex of part ``a`` are ``cand[cand_ptr[a]:cand_ptr[a + 1]]``.
    ``moved[i]`` is set for every vertex that moved, ``hit[i]`` to the part it
    was projected out of, and ``plane[i]`` (n, 6) holds where it went and the
    unit gradient of its constraint there: the constraint's tangent
    half-space (:func:`hold_planes`). With ``recheck`` a vertex that was
    projected out of a part before is tested against that part alone (the
    frame's other parts were tested and were not in contact with it),
    carried from where it was read last (``pre``, see :func:`worst_contact`).
    Wherever a vertex is tested against all its candidates, ``clear[i]`` is
    lowered to a lower bound of its distance from the flesh of those ``apart``
    from its part (see :func:`worst_contact`; ``reach``: how far the boxes
    were grown)."""
    for k in nb.prange(verts.shape[0]):
        i = verts[k]
        a = side[i]
        c0, c1 = cand_ptr[a], cand_ptr[a + 1]
        if c0 == c1:
            continue
        # most skin lies outside every candidate's box: that test alone first
        inside = False
        gap = np.inf
        for c in range(c0, c1):
            b = cand[c]
            xb, yb, zb = _to_rest(Minv, b, X[i, 0], X[i, 1], X[i, 2])
            if (box[b, 0, 0] <= xb <= box[b, 1, 0] and box[b, 0, 1] <= yb <= box[b, 1, 1]
                    and box[b, 0, 2] <= zb <= box[b, 1, 2]):
                inside = True
                break
            if apart[a, b]:
                gap = min(gap, _box_gap(box, b, xb, yb, zb))
        if not inside:
            clear[i] = min(clear[i], gap + reach)
            continue
        gx = gy = gz = 0.0
        went = False
        only = hit[i] if recheck else -1
        for _ in range(steps):
            C, gx, gy, gz, b = worst_contact(X, V0, i, a, cand, c0, c1, Q, Minv, pf, box,
                                             margin, onset, deep, fade, face0, face1,
                                             iterations, only, pre, clear, reach, apart)
            if C >= 0.0:
                break
            hit[i] = b
            # the next steps follow the part this one left (carried from
            # where its field was just read: the step is a fraction of a margin)
            only = b
            # where the two fields run nearly parallel their difference is flat:
            # never step further than twice the violation
            g2 = max(gx * gx + gy * gy + gz * gz, 0.25)
            s = -C / g2
            X[i, 0] += s * gx
            X[i, 1] += s * gy
            X[i, 2] += s * gz
            went = True
        if went:
            moved[i] = True
            # written whenever the vertex moved (a flat gradient holds nothing),
            # so no frame reads another frame's plane
            g = np.sqrt(gx * gx + gy * gy + gz * gz)
            g = 1.0 / g if g > 1e-12 else 0.0
            plane[i, 0], plane[i, 1], plane[i, 2] = X[i, 0], X[i, 1], X[i, 2]
            plane[i, 3], plane[i, 4], plane[i, 5] = gx * g, gy * g, gz * g


@nb.njit(cache=True, nogil=True)
def hold_planes(X, verts, moved, plane):
    """Keep every moved vertex of ``verts`` on the free side of its
    constraint's tangent plane (``plane[i]``: a point and the unit normal),
    the constraint linearised where the last projection left it: between two
    exact projections, smoothing and this cost a dot product a vertex."""
    for k in range(verts.shape[0]):
        i = verts[k]
        if not moved[i]:
            continue
        d = ((X[i, 0] - plane[i, 0]) * plane[i, 3] + (X[i, 1] - plane[i, 1]) * plane[i, 4]
             + (X[i, 2] - plane[i, 2]) * plane[i, 5])
        if d < 0.0:
            X[i, 0] -= d * plane[i, 3]
            X[i, 1] -= d * plane[i, 4]
            X[i, 2] -= d * plane[i, 5]


@nb.njit(cache=True, nogil=True)
def contact_pairs(X, order, pptr, M, Minv, has, lo, hi, reach, min_angle, width, box,
                  cand_ptr, cand, fade, apart, apart_angle):
    """The part pairs to test in pose ``M`` (J, 4, 4), and each part's box.

    ``box[b]`` (2, 3): part ``b``'s posed skin (vertices ``order[pptr[b]:
    pptr[b+1]]`` of ``X``) carried back by its bone alone, bounded, grown by
    ``reach``. Part ``b`` is a candidate for the skin of part ``a`` when ``b``
    has a field (``has``), ``a``'s posed skin box carried into ``b``'s rest
    frame overlaps ``b``'s grid (``lo``, ``hi``), and their bones turned at
    least ``min_angle`` from each other since rest. Writes the candidates of
    part ``a`` to ``cand[cand_ptr[a]:cand_ptr[a + 1]]``; returns how many.
    ``fade[a, b]`` (J, J) gets how far the pair's contact has come in: from 0
    at ``min_angle`` to 1 at ``min_angle + width`` (smoothstep), so a pair
    that starts being tested does not push its skin out all at once (1 for
    every pair when ``min_angle`` is 0). Pairs ``apart[a, b]`` (J, J) take
    ``apart_angle`` for ``min_angle``."""
    J = M.shape[0]
    plo, phi = np.empty((J, 3)), np.empty((J, 3))
    for a in range(J):
        # both bounds in one pass over the part's skin, in scalars (kept in
        # the arrays, each would be stored and read back for every vertex)
        lx = ly = lz = rlx = rly = rlz = np.inf
        hx = hy = hz = rhx = rhy = rhz = -np.inf
        for q in range(pptr[a], pptr[a + 1]):
            i = order[q]
            px, py, pz = X[i, 0], X[i, 1], X[i, 2]
            lx, hx = min(lx, px), max(hx, px)
            ly, hy = min(ly, py), max(hy, py)
            lz, hz = min(lz, pz), max(hz, pz)
            x, y, z = _to_rest(Minv, a, px, py, pz)
            rlx, rhx = min(rlx, x), max(rhx, x)
            rly, rhy = min(rly, y), max(rhy, y)
            rlz, rhz = min(rlz, z), max(rhz, z)
        plo[a, 0], plo[a, 1], plo[a, 2] = lx, ly, lz
        phi[a, 0], phi[a, 1], phi[a, 2] = hx, hy, hz
        box[a, 0, 0], box[a, 0, 1], box[a, 0, 2] = rlx - reach, rly - reach, rlz - reach
        box[a, 1, 0], box[a, 1, 1], box[a, 1, 2] = rhx + reach, rhy + reach, rhz + reach
    n = 0
    corner = np.empty(3)
    for a in range(J):
        cand_ptr[a] = n
        if pptr[a + 1] == pptr[a]:
            continue
        for b in range(J):
            if b == a or not has[b]:
                continue
            # the bones' turn since rest: the angle of R_a^T R_b
            tr = 0.0
            for r in range(3):
                for c in range(3):
                    tr += M[a, c, r] * M[b, c, r]
            angle = math.acos(min(1.0, max(-1.0, 0.5 * (tr - 1.0))))
            least = apart_angle if apart[a, b] else min_angle
            if angle < least:
                continue
            # no threshold, nothing to come in over: every pair in full
            t = min(1.0, (angle - least) / max(width, 1e-9)) if least > 0.0 else 1.0
            fade[a, b] = t * t * (3.0 - 2.0 * t)
            clo = np.full(3, np.inf)
            chi = np.full(3, -np.inf)
            for c in range(8):
                corner[0] = phi[a, 0] if c & 1 else plo[a, 0]
                corner[1] = phi[a, 1] if c & 2 else plo[a, 1]
                corner[2] = phi[a, 2] if c & 4 else plo[a, 2]
                x, y, z = _to_rest(Minv, b, corner[0], corner[1], corner[2])
                clo[0], chi[0] = min(clo[0], x), max(chi[0], x)
                clo[1], chi[1] = min(clo[1], y), max(chi[1], y)
                clo[2], chi[2] = min(clo[2], z), max(chi[2], z)
            if (clo[0] <= hi[b, 0] and chi[0] >= lo[b, 0] and clo[1] <= hi[b, 1]
                    and chi[1] >= lo[b, 1] and clo[2] <= hi[b, 2] and chi[2] >= lo[b, 2]):
                cand[n] = b
                n += 1
    cand_ptr[J] = n
    return n


@nb.njit(cache=True, nogil=True)
def boxed_vertices(X, order, pptr, cptr, cand_ptr, cand, Minv, box, reach, apart, clear,
                   out):
    """The vertices that may lie in another part's box (see
    :func:`project_contacts`), found chunk by chunk: ``order`` holds each
    part's vertices (``order[pptr[a]:pptr[a+1]]``) in spatially coherent
    chunks ``order[cptr[c]:cptr[c+1]]``; a chunk's posed bounding box is
    carried into each candidate part's rest frame (its eight corners) and
    only where that meets the candidate's box are its vertices kept. The
    boxes bound the vertices, so no vertex that a per-vertex test would keep
    is dropped. Writes them to ``out``; returns how many. The vertices of a
    chunk left out get ``clear``: at least how far they are from the flesh of
    every candidate ``apart`` from their part (the chunk's distance from its
    box, grown by ``reach``, plus ``reach``)."""
    n = 0
    J = pptr.shape[0] - 1
    c = 0
    for a in range(J):
        c0, c1 = cand_ptr[a], cand_ptr[a + 1]
        while c < cptr.shape[0] - 1 and cptr[c] < pptr[a + 1]:
            q0, q1 = cptr[c], cptr[c + 1]
            c += 1
            if c0 == c1:
                continue
            lx = ly = lz = np.inf
            hx = hy = hz = -np.inf
            for q in range(q0, q1):
                i = order[q]
                lx, hx = min(lx, X[i, 0]), max(hx, X[i, 0])
                ly, hy = min(ly, X[i, 1]), max(hy, X[i, 1])
                lz, hz = min(lz, X[i, 2]), max(hz, X[i, 2])
            keep = False
            gap = np.inf
            for e in range(c0, c1):
                b = cand[e]
                blx = bly = blz = np.inf
                bhx = bhy = bhz = -np.inf
                for k in range(8):
                    x, y, z = _to_rest(Minv, b, hx if k & 1 else lx, hy if k & 2 else ly,
                                       hz if k & 4 else lz)
                    blx, bhx = min(blx, x), max(bhx, x)
                    bly, bhy = min(bly, y), max(bhy, y)
                    blz, bhz = min(blz, z), max(bhz, z)
                if (blx <= box[b, 1, 0] and bhx >= box[b, 0, 0] and bly <= box[b, 1, 1]
                        and bhy >= box[b, 0, 1] and blz <= box[b, 1, 2] and bhz >= box[b, 0, 2]):
                    keep = True
                    break
                if not apart[a, b]:
                    continue
                dx = max(blx - box[b, 1, 0], box[b, 0, 0] - bhx, 0.0)
                dy = max(bly - box[b, 1, 1], box[b, 0, 1] - bhy, 0.0)
                dz = max(blz - box[b, 1, 2], box[b, 0, 2] - bhz, 0.0)
                gap = min(gap, math.sqrt(dx * dx + dy * dy + dz * dz))
            if keep:
                for q in range(q0, q1):
                    out[n] = order[q]
                    n += 1
            else:
                for q in range(q0, q1):
                    clear[order[q]] = gap + reach
    return n


@nb.njit(cache=True, nogil=True)
def flesh_depth(V0, verts, T, b, pf, excess, out):
    """How deep rest points ``V0[verts]``, moved by ``T`` (4, 4) into part
    ``b``'s rest frame, lie in ``b``'s flesh (its field, rigid: the parts'
    middles, away from the joints skinning blends): returns the deepest
    (negative: the least clearance of any, with none inside; -:data:`FAR`
    with none in the field's grid). The points deeper than ``excess`` add the field's
    gradient there into ``out[1:4]`` and themselves into ``out[4:7]`` (both
    in ``b``'s rest frame), their count into ``out[0]``: each counts
    alike, as the gradient deep inside a part turns with which side of it
    is nearest."""
    origin, cell, dims, ptr, values = pf[0], pf[1], pf[2], pf[3], pf[4]
    worst = -FAR
    for k in range(verts.shape[0]):
        i = verts[k]
        px, py, pz = V0[i, 0], V0[i, 1], V0[i, 2]
        x = T[0, 0] * px + T[0, 1] * py + T[0, 2] * pz + T[0, 3]
        y = T[1, 0] * px + T[1, 1] * py + T[1, 2] * pz + T[1, 3]
        z = T[2, 0] * px + T[2, 1] * py + T[2, 2] * pz + T[2, 3]
        v, gx, gy, gz = field_at(values, ptr, origin, cell, dims, b, x, y, z, False)
        d = -v                  # -FAR outside the grid
        worst = max(worst, d)
        if d > excess:
            out[0] += 1.0
            out[1] += gx
            out[2] += gy
            out[3] += gz
            out[4] += x
            out[5] += y
            out[6] += z
    return worst


@nb.njit(cache=True, nogil=True)
def pair_depths(V0, vptr, vidx, pairs, M, Minv, centre, ball, pf, excess, worst, sums):
    """:func:`flesh_depth` of part ``a``'s skin in part ``b``'s flesh for each
    row ``(a, b)`` of ``pairs`` whose posed skins' bounding balls meet
    (``centre`` (J, 3) rest, ``ball`` (J,) radii; part ``a``'s vertices
    ``vidx[vptr[a]:vptr[a + 1]]``), moved by the skinning matrices ``M``
    (``Minv`` their inverses):
    the deepest into ``worst`` (-:data:`FAR` where the balls part) and the sums into
    ``sums`` (P, 7), with ``excess`` (P,) per row."""
    T = np.empty((4, 4))
    out = np.zeros(7)
    for p in range(pairs.shape[0]):
        a, b = pairs[p, 0], pairs[p, 1]
        worst[p] = -FAR
        sums[p, :] = 0.0
        d2 = 0.0
        for r in range(3):
            ca = (M[a, r, 0] * centre[a, 0] + M[a, r, 1] * centre[a, 1]
                  + M[a, r, 2] * centre[a, 2] + M[a, r, 3])
            cb = (M[b, r, 0] * centre[b, 0] + M[b, r, 1] * centre[b, 1]
                  + M[b, r, 2] * centre[b, 2] + M[b, r, 3])
            d2 += (ca - cb) ** 2
        if d2 > (ball[a] + ball[b]) ** 2:
            continue
        # a's rest frame to b's
        for r in range(4):
            for c in range(4):
                s = 0.0
                for k in range(4):
                    s += Minv[b, r, k] * M[a, k, c]
                T[r, c] = s
        out[:] = 0.0
        worst[p] = flesh_depth(V0, vidx[vptr[a]:vptr[a + 1]], T, b, pf, excess[p], out)
        sums[p, :] = out
    return worst

