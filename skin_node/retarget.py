"""Retarget BVH motion onto a :class:`~skin_node.skeleton.Skeleton`.

Method (world-space deltas, so rest-pose and joint-frame differences cancel):

1. ``C`` (3x3) maps source world vectors to target world vectors (e.g. CMU
   y-up, facing +z to the target's z-up, facing +x).
2. For each mapped source joint ``s`` the world rotation relative to the
   reference frame ``r`` is ``D_s(t) = G_s(t) @ G_s(r)^T`` (source world), or
   ``D'(t) = C @ D_s(t) @ C^T`` in the target world.
3. The target joint ``j`` (parent ``p``) must have world rotation
   ``W_j(t) = D'(t) @ W_j(ref)``, where ``W_j(ref)`` is its world rotation in
   the pose that matches the source's reference pose: the rest pose, or the
   pose given by ``rest_offsets`` (e.g. a target in an A-pose retargeted from
   a T-pose reference). Since ``W_j = W_p @ R(q_j) @ Rrest_j`` and
   ``W_j(ref) = W_p(ref) @ R(o_j) @ Rrest_j``::

       R(q_j)(t) = W_p(t)^T @ D'(t) @ W_p(ref) @ R(o_j)

   with ``W_p(t)`` the target parent's world rotation actually reached
   (unmapped joints keep ``q = 0`` and are carried along). The source
   reference frame therefore maps to ``q = rest_offsets`` (zero by default),
   and rotating a source limb by a world rotation ``Q`` rotates the target
   limb by ``C @ Q @ C^T``.
4. ``R(q_j)`` becomes the target channels ``(rx, ry, rz)`` with
   ``R = Rz @ Ry @ Rx`` (:func:`skin_node.skeleton.matrix_to_euler_xyz`),
   then made continuous in time (:func:`continuous_euler`: no 2 pi wraps,
   no branch flips when ``ry`` passes +-90 degrees).
5. The root translation is the source root's displacement from the reference
   frame, mapped by ``C`` and scaled by the hip-height ratio (target / source)
   or a fixed ``scale``.

Mapping file (YAML)::

    source_root: Hips          # source joint giving the root translation
    scale: auto                # or a number (target metres per source metre)
    source_up: +y              # source world up / forward at the reference frame
    source_forward: +z
    target_up: +z              # target world up / forward (defaults shown)
    target_forward: +x
    # axes: [[0,0,1],[1,0,0],[0,1,0]]   # explicit C (target = C @ source)
    joints: {pelvis: Hips, l_knee: LeftLeg, ...}    # target: source
    rest_offsets: {l_shoulder: [45, 0, 0]}          # degrees, rx ry rz
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from skin_node.io.bvh import Bvh
from skin_node.skeleton import Skeleton, euler_xyz_to_matrix, matrix_to_euler_xyz

_KEYS = {"source_root", "scale", "source_up", "source_forward", "target_up",
         "target_forward", "axes", "joints", "rest_offsets", "reference_frame"}


def _axis_vector(spec, key: str, where: str) -> np.ndarray:
    """'+y' / '-z' / 'x' -> unit vector."""
    s = str(spec).strip().lower()
    sign = -1.0 if s.startswith("-") else 1.0
    s = s.lstrip("+-")
    if s not in ("x", "y", "z"):
        raise ValueError(f"{where}: '{key}' must be one of +x, -x, +y, -y, +z, -z; got '{spec}'")
    v = np.zeros(3)
    v["xyz".index(s)] = sign
    return v


def axis_conversion(mapping: dict) -> np.ndarray:
    """The 3x3 rotation ``C`` taking source world vectors to target world vectors.

    Uses ``axes`` if given, else builds ``C`` from the up/forward axes (the
    third axis, left = up x forward, follows in both right-handed frames).

    Returns
    -------
    (3, 3) float
    """
    where = mapping.get("_file", "<mapping>")
    if mapping.get("axes") is not None:
        C = np.asarray(mapping["axes"], dtype=np.float64)
        if C.shape != (3, 3) or not np.allclose(C @ C.T, np.eye(3), atol=1e-6) \
                or np.linalg.det(C) < 0:
            raise ValueError(f"{where}: 'axes' must be a 3x3 rotation matrix (orthonormal, det +1)")
        return C
    bases = []
    for up_key, fw_key, up_d, fw_d in (("source_up", "source_forward", "+y", "+z"),
                                       ("target_up", "target_forward", "+z", "+x")):
        u = _axis_vector(mapping.get(up_key, up_d), up_key, where)
        f = _axis_vector(mapping.get(fw_key, fw_d), fw_key, where)
        if abs(u @ f) > 0.5:
            raise ValueError(f"{where}: '{up_key}' and '{fw_key}' must be different axes")
        bases.append(np.stack([f, u, np.cross(u, f)], axis=1))  # columns: forward, up, left
    S, Tb = bases
    return Tb @ S.T


def template_axes(mapping: dict, skeleton: Skeleton) -> np.ndarray:
    """``axes`` for a template's mapping used on a skeleton fitted to that
    template: the mapping's source axes onto the fit's own forward, up and
    left (the root's rest rotation has the mesh's forward, left and up as
    columns, whatever way the mesh was modelled)."""
    where = mapping.get("_file", "<mapping>")
    u = _axis_vector(mapping.get("source_up", "+y"), "source_up", where)
    f = _axis_vector(mapping.get("source_forward", "+z"), "source_forward", where)
    S = np.stack([f, u, np.cross(u, f)], axis=1)
    R0 = skeleton.rest_rotations[0]
    Tb = np.stack([R0[:, 0], R0[:, 2], R0[:, 1]], axis=1)    # forward, up, left
    return Tb @ S.T


def validate_mapping(mapping: dict, skeleton: Skeleton | None = None,
                     bvh: Bvh | None = None) -> None:
    """Check a mapping's structure and, if given, its joint names.

    Raises
    ------
    ValueError
        Naming the offending key or joint and the mapping file.
    """
    where = mapping.get("_file", "<mapping>")
    unknown = sorted(set(k for k in mapping if not k.startswith("_")) - _KEYS)
    if unknown:
        raise ValueError(f"{where}: unknown keys {unknown} (allowed: {sorted(_KEYS)})")
    joints = mapping.get("joints")
    if not isinstance(joints, dict) or not joints:
        raise ValueError(f"{where}: 'joints' must be a non-empty mapping target_joint: source_joint")
    sources = list(joints.values())
    dup = sorted({s for s in sources if sources.count(s) > 1})
    if dup:
        # Allowed by the maths, but almost always a typo in a hand-written file.
        raise ValueError(f"{where}: source joints mapped more than once: {dup}")
    offsets = mapping.get("rest_offsets") or {}
    if not isinstance(offsets, dict):
        raise ValueError(f"{where}: 'rest_offsets' must map target joints to [rx, ry, rz] degrees")
    for k, v in offsets.items():
        if np.shape(v) != (3,):
            raise ValueError(f"{where}: rest_offsets of '{k}' must be 3 angles in degrees, got {v!r}")
    scale = mapping.get("scale", "auto")
    if not (scale == "auto" or (isinstance(scale, (int, float)) and not isinstance(scale, bool)
                                and scale > 0)):
        raise ValueError(f"{where}: 'scale' must be 'auto' or a positive number, got {scale!r}")
    axis_conversion(mapping)
    if skeleton is not None:
        for t in list(joints) + list(offsets):
            if t not in skeleton.names:
                raise ValueError(f"{where}: unknown target joint '{t}' "
                                 f"(skeleton joints: {skeleton.names})")
    if bvh is not None:
        root = mapping.get("source_root", bvh.names[0])
        for s in sources + [root]:
            if s not in bvh.names:
                raise ValueError(f"{where}: unknown source joint '{s}' not in {bvh.path} "
                                 f"(joints: {bvh.names})")


def load_mapping(path: str | Path, skeleton: Skeleton | None = None,
                 bvh: Bvh | None = None) -> dict:
    """Read and check a YAML retarget mapping.

    Parameters
    ----------
    path : str or Path
        The YAML file (see the module docstring for its keys).
    skeleton, bvh : optional
        If given, every target / source joint name is checked against them.

    Returns
    -------
    dict
        The mapping, with ``_file`` set to ``str(path)`` for later messages.
    """

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise ValueError(f"{path}: not valid YAML: {e}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping at the top level")
    data["_file"] = str(path)
    validate_mapping(data, skeleton, bvh)
    return data


def hip_height_source(bvh: Bvh, G: np.ndarray, frame: int, root: int, up: np.ndarray) -> float:
    """Height of the source root above its lowest joint or end site at ``frame``, metres."""
    pts = np.concatenate([G[frame, :, :3, 3], bvh.end_site_positions(G[frame:frame + 1])[0]])
    h = pts @ up
    return float(G[frame, root, :3, 3] @ up - h.min())


def hip_height_target(skeleton: Skeleton, up: np.ndarray) -> float:
    """Height of the target root above its lowest joint or leaf tip at rest, metres."""
    pts = np.concatenate([skeleton.rest_positions,
                          skeleton.tips[np.all(np.isfinite(skeleton.tips), axis=1)]])
    h = pts @ up
    return float(skeleton.rest_positions[0] @ up - h.min())


def nominal_fps(frame_time: float) -> float:
    """``1 / frame_time``, snapped to a whole number when within 0.01 %.

    BVH files store rounded frame times (``.0083333`` for 120 fps).
    """
    fps = 1.0 / frame_time
    r = round(fps)
    return float(r) if r > 0 and abs(fps - r) < 1e-4 * fps else fps


def retarget_bvh(bvh: Bvh, skeleton: Skeleton, mapping: dict,
                 reference_frame: int | None = None):
    """Retarget a BVH clip onto ``skeleton``.

    Parameters
    ----------
    bvh : Bvh
        Source motion (lengths in metres as loaded).
    skeleton : Skeleton
        Target; its rest pose (``q = 0``, or ``rest_offsets``; with none, a
        skeleton fitted to a template in another rest pose takes
        :func:`reference_pose`) is taken to match the source's reference frame.
    mapping : dict
        From :func:`load_mapping` (or an equivalent dict).
    reference_frame : int, optional
        Source frame whose pose corresponds to the target's rest pose; frame
        0 is the synthetic T-pose of CMU files. Defaults to the mapping's
        ``reference_frame`` or 0.

    Returns
    -------
    channel_names : list of str
        ``skeleton.channel_names``.
    frames : (T, 3 + 3 J) float64
        Target poses: root translation in metres, rotations in radians.
    fps : float
        Frames per second (:func:`nominal_fps`).
    """
    validate_mapping(mapping, skeleton, bvh)
    where = mapping.get("_file", "<mapping>")
    if reference_frame is None:
        reference_frame = int(mapping.get("reference_frame", 0))
    T = bvh.n_frames
    if T == 0:
        raise ValueError(f"{bvh.path}: no frames to retarget")
    if not -T <= reference_frame < T:
        raise ValueError(f"reference_frame {reference_frame} outside the {T} frames of {bvh.path}")
    ref = reference_frame % T

    C = axis_conversion(mapping)
    G = bvh.world_matrices()                              # (T, Js, 4, 4)
    Gs = G[..., :3, :3]
    J = skeleton.n_joints
    q = np.zeros((T, skeleton.n_channels))

    # Pose matching the source reference, and its world rotations.
    q_ref = np.zeros(skeleton.n_channels)
    offsets = mapping.get("rest_offsets")
    if not offsets and skeleton.reference is not None:
        # fitted to a template in another rest pose: its template's rest pose
        q_ref = reference_pose(skeleton)
    for name, ang in (offsets or {}).items():
        j = skeleton.index(name)
        q_ref[3 + 3 * j: 6 + 3 * j] = np.deg2rad(np.asarray(ang, dtype=np.float64))
    W_ref = skeleton.world_matrices(q_ref)[:, :3, :3]     # (J, 3, 3)
    R_off = euler_xyz_to_matrix(q_ref[3:].reshape(J, 3))

    joints = mapping["joints"]
    W = np.empty((T, J, 3, 3))                            # target world rotations reached
    ang = np.broadcast_to(q_ref[3:].reshape(J, 3), (T, J, 3)).copy()
    mapped = np.zeros(J, dtype=bool)
    for j in range(J):  # parents first; each step vectorised over frames
        p = skeleton.parents[j]
        Wp = np.broadcast_to(np.eye(3), (T, 3, 3)) if p < 0 else W[:, p]
        Wp_ref = np.eye(3) if p < 0 else W_ref[p]
        name = skeleton.names[j]
        if name in joints:
            s = bvh.index(joints[name])
            D = Gs[:, s] @ Gs[ref, s].T                   # source-world delta
            D = C @ D @ C.T                               # target-world delta
            Rq = np.swapaxes(Wp, -1, -2) @ D @ (Wp_ref @ R_off[j])
            ang[:, j] = matrix_to_euler_xyz(Rq)
            mapped[j] = True
        # Carry the rotation the channels really encode (exact away from gimbal lock;
        # both Euler branches chosen below encode the same matrix).
        W[:, j] = Wp @ euler_xyz_to_matrix(ang[:, j]) @ skeleton.rest_rotations[j]
    if T > 1 and mapped.any():
        ang[:, mapped] = continuous_euler(ang[:, mapped], ref)
    q[:, 3:] = ang.reshape(T, 3 * J)

    # Root translation: reference-relative displacement, axis-converted and scaled.
    root = bvh.index(mapping.get("source_root", bvh.names[0]))
    scale = mapping.get("scale", "auto")
    if scale == "auto":
        if mapping.get("axes") is not None and mapping.get("source_up") is not None:
            # axes given with the source's up (a template's mapping turned
            # to a fit's axes, template_axes): the target's up is its image
            up_s = _axis_vector(mapping["source_up"], "source_up", where)
            up_t = C @ up_s
        else:
            up_s = C.T @ _axis_vector(mapping.get("target_up", "+z"), "target_up", where)
            up_t = _axis_vector(mapping.get("target_up", "+z"), "target_up", where)
        hs = hip_height_source(bvh, G, ref, root, up_s)
        ht = hip_height_target(skeleton, up_t)
        if hs <= 1e-9 or ht <= 1e-9:
            raise ValueError(f"{where}: cannot derive 'scale: auto' (hip heights: source {hs:.4g} m, "
                             f"target {ht:.4g} m); give a number")
        scale = ht / hs
    disp = G[:, root, :3, 3] - G[ref, root, :3, 3]
    q[:, :3] = float(scale) * disp @ C.T
    return skeleton.channel_names, q, nominal_fps(bvh.frame_time)


def continuous_euler(ang: np.ndarray, ref: int = 0) -> np.ndarray:
    """Make ``R = Rz @ Ry @ Rx`` Euler angles continuous in time.

    Every rotation has two Euler triples, ``(rx, ry, rz)`` and
    ``(rx + pi, pi - ry, rz + pi)``; :func:`matrix_to_euler_xyz` returns the
    one with ``|ry| <= pi/2``, which flips when a joint bends past 90 degrees
    about its y axis (a running knee). Starting from frame ``ref`` (kept at
    its principal value), each frame takes the triple nearest the previous
    frame, shifted by multiples of 2 pi (so a root turning around does not
    jump either).

    Parameters
    ----------
    ang : (T, ..., 3) float
        Principal angles (rx, ry, rz), radians.
    ref : int
        Frame left unchanged.

    Returns
    -------
    (T, ..., 3) float
        Same rotations, continuous from frame to frame.
    """
    two_pi = 2.0 * np.pi

    def wrap(x):
        return (x + np.pi) % two_pi - np.pi

    alt = ang + np.array([np.pi, 0.0, np.pi])
    alt[..., 1] = np.pi - ang[..., 1]
    out = ang.copy()
    # A loop over frames only (joints vectorised): the choice depends on the
    # previous frame.
    for order in (range(ref + 1, ang.shape[0]), range(ref - 1, -1, -1)):
        prev = ang[ref]
        for t in order:
            da, db = wrap(ang[t] - prev), wrap(alt[t] - prev)
            use_b = np.abs(db).sum(-1) < np.abs(da).sum(-1) - 1e-9
            prev = prev + np.where(use_b[..., None], db, da)
            out[t] = prev
    return out


def bone_direction(skel: Skeleton, j: int) -> np.ndarray | None:
    """The rest world direction (unit) of joint ``j``'s bone: to its only
    child, or to its tip if it is a leaf; None for a joint with several
    children (a pelvis, a chest) or a bone of no length."""
    kids = skel.children(j)
    if len(kids) == 1:
        d = skel.rest_positions[kids[0]] - skel.rest_positions[j]
    elif not kids:
        d = skel.tips[j] - skel.rest_positions[j]
    else:
        return None
    n = float(np.linalg.norm(d))
    return d / n if n > 1e-12 else None


def turn_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation (3, 3) taking unit vector ``a`` onto unit ``b``."""
    v, c = np.cross(a, b), float(np.dot(a, b))
    if c < -1.0 + 1e-12:          # opposite: a half turn about any normal of a
        n = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        n /= np.linalg.norm(n)
        return 2.0 * np.outer(n, n) - np.eye(3)
    K = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + K + K @ K / (1.0 + c)


def conform_clip(skel: Skeleton, frames: np.ndarray) -> np.ndarray:
    """A clip written for a template's rest pose, turned for a skeleton fitted
    to the template in another (``skel.reference``; unchanged when None).

    Each bone ``j`` with a reference direction gets the world turn ``A_j``
    that takes its rest direction onto the reference; the turned clip gives
    every joint the world rotation ``D_j(t) @ A_j``, where ``D_j(t)`` is the
    world turn the clip gives it from rest (``A_j`` the identity for the
    other joints), so each such bone points at every frame where the
    template's would. As for a BVH (module docstring)::

        R(q'_j)(t) = W'_p(t)^T @ D_j(t) @ A_j @ Wrest_j @ Rrest_j^T

    with ``W'_p(t) = D_p(t) @ A_p @ Wrest_p``. Frame by frame, made
    continuous in time (:func:`continuous_euler`); the root's translation is
    kept. An arm lowered 25 degrees in the mesh's rest pose then hangs where
    the template's clip lowers the template's T-pose arm, not 25 degrees
    further into the torso.

    Parameters
    ----------
    skel : Skeleton
    frames : (T, C) float
        Channel vectors over ``skel.channel_names``.

    Returns
    -------
    (T, C) float
        A new array (``frames`` itself when ``skel`` has no reference).
    """
    A = _reference_turns(skel)
    if A is None:
        return frames
    frames = np.asarray(frames, dtype=np.float64)
    J = skel.n_joints
    Wrest = skel.bind[:, :3, :3]
    T = len(frames)
    ang = np.empty((T, J, 3))
    for t in range(T):
        D = skel.world_matrices(frames[t])[:, :3, :3] @ np.swapaxes(Wrest, -1, -2)
        ang[t] = _channels_for(skel, D @ A @ Wrest)     # the world rotations wanted
    out = frames.copy()
    out[:, 3:] = continuous_euler(ang, 0).reshape(T, 3 * J)
    return out


def reference_pose(skel: Skeleton) -> np.ndarray | None:
    """The pose (channels) that puts a skeleton fitted to a template into
    the template's rest pose (each ``skel.reference`` bone along its
    reference; :func:`conform_clip` at ``q = 0``), or None when it has no
    reference. A BVH whose reference frame is the template's rest pose (a
    CMU T-pose onto the humanoid template) takes it as its rest offsets."""
    A = _reference_turns(skel)
    if A is None:
        return None
    q = np.zeros(skel.n_channels)
    q[3:] = _channels_for(skel, A @ skel.bind[:, :3, :3]).ravel()
    return q


def _reference_turns(skel: Skeleton) -> np.ndarray | None:
    """(J, 3, 3) world turns from each bone's rest direction onto its
    reference (the identity for bones without one); None without any."""
    ref = skel.reference
    if ref is None or not np.isfinite(ref).any():
        return None
    A = np.tile(np.eye(3), (skel.n_joints, 1, 1))
    for j in range(skel.n_joints):
        d = bone_direction(skel, j)
        if d is not None and np.isfinite(ref[j]).all():
            A[j] = turn_between(d, ref[j] / np.linalg.norm(ref[j]))
    return A


def _channels_for(skel: Skeleton, W: np.ndarray) -> np.ndarray:
    """(J, 3) principal channels giving the joints world rotations ``W``."""
    ang = np.empty((skel.n_joints, 3))
    for j in range(skel.n_joints):
        p = skel.parents[j]
        Wp = np.eye(3) if p < 0 else W[p]
        ang[j] = matrix_to_euler_xyz(Wp.T @ W[j] @ skel.rest_rotations[j].T)
    return ang
