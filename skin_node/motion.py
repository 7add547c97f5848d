"""Motion for a character, by name: built-in clips, a glTF file's own animations, BVH.

One place that ``mocap_player``, the exporter and ``skin_bench`` ask for "the
clip NAME of this character":

* a **built-in clip** (:data:`skin_node.CLIP_NAMES`), when the skeleton has its
  channels;
* an **animation of a glTF character** (``.glb`` / ``.gltf``), by its name or as
  ``gltf:NAME`` (``gltf:0`` for the first by index; unnamed ones are called
  ``animation<k>``), sampled at any rate and converted to the skeleton's
  channels exactly (:func:`skin_node.io.gltf.gltf_clip`). A file's animation
  wins over a built-in clip of the same name; with no clip asked for, a glTF
  character plays its first animation;
* a **BVH file**, retargeted through a mapping (default
  ``config/cmu_to_<character file name>.yaml``; for a character file fitted
  to a template with none of its own, the template's,
  ``config/cmu_to_<template>.yaml``, turned to the fit's axes and rest pose).

Only the skeleton is read: no tet mesh or weights are built.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .builtin.channels import FPS
from .builtin.characters import BUILTIN_CHARACTERS
from .builtin.clips import CLIP_NAMES, Clip, default_clip_name, make_clip
from .character import load_character
from .io.bvh import load_bvh
from .io.character_file import file_clip_name, file_template, load_character_file
from .io.gltf import gltf_animation_names, load_gltf_scene
from .retarget import load_mapping, retarget_bvh, template_axes
from .skeleton import Skeleton

#: Prefix that names a glTF file's animation explicitly.
GLTF_PREFIX = "gltf:"


def config_path(name: str) -> Path:
    """A file of the package's config/ folder, installed or in the source tree."""
    try:
        # deferred: ament_index_python comes with a ROS install, which is optional
        from ament_index_python.packages import get_package_share_directory
        path = Path(get_package_share_directory("skin_node")) / "config" / name
        if path.exists():
            return path
    except (ImportError, LookupError, OSError):  # not installed, or no ament index set
        pass
    return Path(__file__).resolve().parents[1] / "config" / name


def is_gltf(character: str) -> bool:
    return Path(str(character)).suffix.lower() in (".glb", ".gltf")


def character_skeleton(character: str) -> Skeleton:
    """The skeleton of a built-in character or a character file, without rigging it."""
    if character in BUILTIN_CHARACTERS:
        # The skeleton does not depend on the density: the coarsest mesh is cheapest.
        return BUILTIN_CHARACTERS[character](surface_vertices=2000)[2]
    if is_gltf(character):      # every skin's joints, leaf tips from the body, as load_character
        return load_gltf_scene(character).split_body().skeleton
    if Path(str(character)).suffix.lower() in (".yaml", ".yml"):
        return load_character_file(Path(character))[2]
    return load_character(character).skeleton


def file_animations(character: str) -> list[str]:
    """Names of a glTF character's animations (empty for anything else)."""
    if not is_gltf(character):
        return []
    return gltf_animation_names(character)


def default_clip(character: str) -> str:
    """The built-in clip ``character`` plays when none is named: a built-in
    character's own, a character file's template's
    (:func:`~skin_node.io.character_file.file_clip_name`), else the walk."""
    if Path(character).suffix.lower() in (".yaml", ".yml"):
        return file_clip_name(Path(character)) or default_clip_name(character)
    return default_clip_name(character)


def clip_names(character: str, skeleton: Skeleton | None = None) -> list[str]:
    """Every clip ``character`` can play: its file's animations, then the built-in
    clips whose channels its skeleton has."""
    skeleton = skeleton or character_skeleton(character)
    own = file_animations(character)
    builtin = []
    for name in CLIP_NAMES:
        if name in own:
            continue
        try:
            make_clip(name, skeleton)
        except (ValueError, KeyError):   # a channel or a named joint it lacks
            continue
        builtin.append(name)
    return own + builtin


def file_clip(character: str, name: str, fps: float | None = None):
    """The glTF animation ``name`` (or ``gltf:NAME`` / ``gltf:<index>``) of a
    glTF character as a :class:`~skin_node.io.gltf.GltfClip`, or None when
    ``name`` is not one of its animations (or the character is no glTF file).

    Raises
    ------
    ValueError
        For ``gltf:NAME`` that the file does not have, or a non-glTF character.
    """
    explicit = str(name).startswith(GLTF_PREFIX)
    key = str(name)[len(GLTF_PREFIX):] if explicit else str(name)
    if not is_gltf(character):
        if explicit:
            raise ValueError(f"{name}: {character} is not a glTF file; only glTF "
                             "characters have animations of their own")
        return None
    own = file_animations(character)
    if not explicit and key not in own:
        return None
    return load_gltf_scene(character).clip(key, fps=float(fps or FPS))


def load_motion(character: str, clip: str = "", bvh: str = "", mapping: str = "",
                fps: float | None = None, skeleton: Skeleton | None = None) -> Clip:
    """The motion ``character`` plays: a BVH file, a glTF animation or a built-in clip.

    Parameters
    ----------
    character : str
        ``arm``, ``humanoid`` or a character file.
    clip : str
        A clip name (see the module docstring); empty for the default (a glTF
        character's first animation, else the character's built-in clip).
    bvh, mapping : str
        A BVH file to retarget instead, and its mapping YAML.
    fps : float, optional
        Sampling rate of a glTF animation (default 120, the built-in clips' rate).
    skeleton : Skeleton, optional
        The character's skeleton, if already loaded.

    Returns
    -------
    Clip
        ``frames`` (T, C) over ``channel_names`` (the skeleton's channels).

    Raises
    ------
    ValueError
        For an unknown clip (naming the clips that do apply) or a bad file.
    """
    skeleton = skeleton or character_skeleton(character)
    if bvh:
        source = load_bvh(bvh)
        # A character file picks its map by name: .../CesiumMan.glb -> cmu_to_cesiumman.yaml
        default = config_path(f"cmu_to_{Path(character).stem.lower()}.yaml")
        tmpl = file_template(Path(character)) if not mapping and not default.exists() else None
        fitted = tmpl is not None and config_path(f"cmu_to_{tmpl.name}.yaml").exists()
        if fitted:
            # fitted to a template: the template's mapping, in the fit's axes
            # (its rest pose: retarget_bvh takes the fit's reference pose)
            default = config_path(f"cmu_to_{tmpl.name}.yaml")
        if not mapping and not default.exists():
            shipped = sorted(p.name for p in default.parent.glob("cmu_to_*.yaml"))
            raise ValueError(f"{character}: no mapping from {Path(bvh).name}'s joints to this "
                             f"character's: {default.name} is not in {default.parent}; write "
                             f"one (shipped: {', '.join(shipped)}) and give it as the mapping")
        if mapping and not Path(mapping).exists():
            raise ValueError(f"{mapping}: no such mapping file")
        spec = load_mapping(mapping or default, skeleton, source)
        if fitted:
            spec["axes"] = template_axes(spec, skeleton)
        names, frames, rate = retarget_bvh(source, skeleton, spec)
        return Clip(Path(bvh).stem, list(names), np.asarray(frames), float(rate))
    if not clip and file_animations(character):
        clip = f"{GLTF_PREFIX}0"
    own = file_clip(character, clip, fps) if clip else None
    if own is not None:
        return own
    name = clip or default_clip(character)
    try:
        return make_clip(name, skeleton)
    except (ValueError, KeyError) as e:
        known = clip_names(character, skeleton)
        raise ValueError(f"{character}: clip '{name}': {e}; clips for this character: "
                         f"{known or 'none'} (or --bvh FILE)") from None
