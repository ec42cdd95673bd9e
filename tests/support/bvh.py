"""BVH fixtures made from a parsed clip: renamed joints, six channels on every joint, a floor root
below the pelvis, arms posed differently at rest: what other tools' exporters write; and an
independent reader of a file's joint positions (:func:`read_bvh_positions`)."""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy.spatial.transform import Rotation

from limbstream.sources.bvh import BvhClip, local_rotations

_AXES = {"Xrotation": "X", "Yrotation": "Y", "Zrotation": "Z"}
POSITIONS = ("Xposition", "Yposition", "Zposition")


def write_bvh(clip: BvhClip, rename: Mapping[str, str] | None = None, six: bool = False,
              floor_root: str | None = None, offsets: np.ndarray | None = None,
              locals_: dict[int, Rotation] | None = None) -> str:
    """BVH text of ``clip`` with joints renamed (``rename``: old -> new), position channels on
    every joint (``six``: they hold the joint's OFFSET, the root's its own path), a static root
    named ``floor_root`` at the origin holding the clip's root, other ``offsets`` (J, 3) and
    other local rotations for some joints (``locals_``: joint index -> (F,) rotations)."""
    rename = dict(rename or {})
    offsets = clip.offsets if offsets is None else offsets
    rotations = [_rotation_channels(clip, j) for j in range(len(clip.joints))]
    ends = getattr(clip, "end_offsets", None)
    columns: list[np.ndarray] = []
    lines = ["HIERARCHY"]
    if floor_root is not None:
        lines += [f"ROOT {floor_root}", "{", "  OFFSET 0 0 0",
                  "  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"]
        columns.append(np.zeros((clip.n_frames, 6)))

    def joint(j: int, depth: int) -> None:
        pad = "  " * depth
        kind = "ROOT" if depth == 0 else "JOINT"
        lines.extend([f"{pad}{kind} {rename.get(clip.joints[j], clip.joints[j])}", f"{pad}{{",
                      f"{pad}  OFFSET {' '.join(f'{v:.6f}' for v in offsets[j])}"])
        names, values = rotations[j]
        if locals_ and j in locals_:
            values = locals_[j].as_euler("".join(_AXES[n] for n in names), degrees=True)
        own = clip.channels[j]
        if any(p in own for p in POSITIONS):
            start = clip.channel_start(j)
            names, values = POSITIONS + names, np.hstack([clip.motion[:, [start + own.index(p) for p in POSITIONS]],
                                                          values])
        elif six:
            names, values = POSITIONS + names, np.hstack([np.tile(offsets[j], (clip.n_frames, 1)), values])
        lines.append(f"{pad}  CHANNELS {len(names)} {' '.join(names)}")
        columns.append(values)
        for child in np.flatnonzero(clip.parents == j):
            joint(int(child), depth + 1)
        end = np.full(3, np.nan) if ends is None else ends[j]
        if np.all(np.isfinite(end)):
            lines.extend([f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET {' '.join(f'{v:.6f}' for v in end)}",
                          f"{pad}  }}"])
        lines.append(f"{pad}}}")

    joint(0, 1 if floor_root is not None else 0)
    if floor_root is not None:
        lines.append("}")
    motion = np.hstack(columns)
    lines += ["MOTION", f"Frames: {clip.n_frames}", f"Frame Time: {clip.frame_time:.8f}"]
    lines += [" ".join(f"{v:.6f}" for v in row) for row in motion]
    return "\n".join(lines) + "\n"


def _rotation_channels(clip: BvhClip, j: int) -> tuple[tuple[str, ...], np.ndarray]:
    """(names, (F, 3) degrees) of joint j's rotation channels (ZXY zeros where it has none)."""
    names = tuple(n for n in clip.channels[j] if n in _AXES) or ("Zrotation", "Xrotation", "Yrotation")
    return names, local_rotations(clip, j).as_euler("".join(_AXES[n] for n in names), degrees=True)


def read_bvh_positions(path) -> dict[str, np.ndarray]:
    """An independent BVH reader (from the format's definition, scipy for the Euler angles):
    every joint's world position per frame, {name: (F, 3)}."""
    tokens = path.read_text().split()
    joints, parents, offsets, channels, stack_ = [], [], [], [], []
    i = 0
    while tokens[i] != "MOTION":
        word = tokens[i]
        if word in ("ROOT", "JOINT"):
            joints.append(tokens[i + 1])
            parents.append(stack_[-1] if stack_ else -1)
            i += 2
        elif word == "End":
            joints.append(None)
            parents.append(stack_[-1])
            i += 2
        elif word == "{":
            stack_.append(len(joints) - 1)
            i += 1
        elif word == "}":
            stack_.pop()
            i += 1
        elif word == "OFFSET":
            offsets.append([float(v) for v in tokens[i + 1:i + 4]])
            i += 4
        elif word == "CHANNELS":
            n = int(tokens[i + 1])
            channels.append(tokens[i + 2:i + 2 + n])
            i += 2 + n
        else:
            i += 1
    n_frames = int(tokens[tokens.index("Frames:") + 1])
    start = tokens.index("Time:") + 2
    values = np.array(tokens[start:], float).reshape(n_frames, -1)
    world_r, world_p, out, col, ch = {}, {}, {}, 0, iter(channels)
    for j, name in enumerate(joints):
        parent = parents[j]
        chans = [] if name is None else next(ch)
        v = values[:, col:col + len(chans)]
        col += len(chans)
        local_p = np.broadcast_to(np.array(offsets[j]), (n_frames, 3)).copy()
        rot_names = [c for c in chans if c.endswith("rotation")]
        for k, c in enumerate(chans):
            if c.endswith("position"):
                local_p[:, "XYZ".index(c[0])] = v[:, k]
        rot = Rotation.from_euler("".join(c[0] for c in rot_names),
                                  v[:, [chans.index(c) for c in rot_names]], degrees=True) if rot_names \
            else Rotation.identity(n_frames)
        if parent < 0:
            world_p[j], world_r[j] = local_p, rot
        else:
            world_p[j] = world_p[parent] + world_r[parent].apply(local_p)
            world_r[j] = world_r[parent] * rot
        if name is not None:
            out[name] = world_p[j]
    return out
