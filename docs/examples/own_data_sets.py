"""Write the two example data sets of docs/datasets.md's walk-through ("Walk-through: two data
sets of one's own") from the bundled clips.

``python docs/examples/own_data_sets.py OUT`` takes the real motion of the bundled
``bandai2-mini`` (Bandai-Namco-Research-Motiondataset-2, CC BY-NC 4.0) and writes it in the
shapes a lab's own capture comes in (issue 28):

- ``OUT/styles/``: a **BVH set with styles**, one take per (action, style) cell: the first
  clip (by name) of each of the mini's 10 actions × 7 styles, under its own file name
  (``dataset-2_<action>_<style>_<take>.bvh``, centimetres, 30 fps), with these defects of real
  exports: every file has Bandai's dummy root ``joint_Root`` above ``Hips``, and in the takes
  of the ``youthful`` session the root's motion is on it (its translation over the floor and
  the body's yaw; :func:`dummy_carries_root_motion`); the ``elderly`` session's files give
  ``LowerLeg_L`` 0.04 cm more length (:data:`OFF_JOINT`); and ``wave-right-hand`` was taken
  in only two styles (:data:`SMALL_CLASS`), 2 clips where Neural Marionette's split needs 3.
- ``OUT/subjects/``: an **ASF/AMC set with subjects**, CMU's layout: one folder per performer
  (``OUT/subjects/mocap/<nn>/<nn>.asf`` beside ``<nn>_<take>.amc``) and ``labels.csv`` (clip,
  action, subject).  The seven performers are the mini's seven styles (subject 01 = active,
  ..., 07 = youthful; :data:`SUBJECTS`) and each subject's ASF has its own bone lengths, every
  bone ``1 + 0.01 · (n − 1)`` times the stand-in's (subject 01: the stand-in's own, 07: 6 %
  longer), and its root path (hip height, travel) scaled the same way.  ``run`` was captured with subjects 01, 02 and 04 only (:data:`FEW_SUBJECTS`).  The
  ASF is the stand-in's skeleton in CMU's manner: a bone per joint, starting at it and
  reaching its (first) child, and bones without degrees of freedom where a joint's children
  start apart (``Hip_L``, ``Hip_R``, ``Waist`` from the root, ``Clavicle_L``,
  ``Clavicle_R`` from the chest; CMU's ``lhipjoint`` ...), so every stand-in joint is a bone
  start at its own place.

and the data-set specs that declare them, as they end the walk-through
(``OUT/styles/styles.toml``, ``OUT/subjects/subjects.toml``: :data:`STYLES_SPEC`,
:data:`SUBJECTS_SPEC`; the walk-through starts from :data:`STYLES_FIRST` and
:data:`SUBJECTS_FIRST` and adds what each refusal asks for).
Nothing in the harness knows these sets: the specs alone declare them.  The motion is the
stand-in's, so a table on either is a stand-in result too (and the files keep its licence).
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import repro  # noqa: F401,E402  (pins the kernel paths before torch / numpy load: repro/kernels.py)
import numpy as np

#: the action taken in two styles only (2 clips) and those styles
SMALL_CLASS = "wave-right-hand"
SMALL_STYLES = ("feminine", "masculine")
#: the session whose takes carry the root motion on the dummy root ``joint_Root``
DUMMY_MOVES_STYLE = "youthful"
#: the session whose files give one joint a little more length, and that joint and length
OFF_STYLE = "elderly"
OFF_JOINT = "LowerLeg_L"
OFF_CM = 0.04
#: the styles as performers of the ASF/AMC set, in the styles' order: 01 = active ...
SUBJECTS = {"active": "01", "elderly": "02", "exhausted": "03", "feminine": "04",
            "masculine": "05", "normal": "06", "youthful": "07"}
#: the action captured with a few subjects only, and those subjects
FEW_ACTION = "run"
FEW_SUBJECTS = ("01", "02", "04")
DUMMY_ROOT = "joint_Root"

STYLES_SPEC = '''# A BVH set with styles (written by docs/examples/own_data_sets.py; docs/datasets.md,
# "Walk-through: two data sets of one's own").
schema = 1
name = "lab-styles"
description = "one take per action x style cell of bandai2-mini's clips, as exported BVH"
license = "CC BY-NC 4.0"
credit = "Bandai Namco Research Inc. (motion); written by docs/examples/own_data_sets.py"

[source]
path = "takes"
include = "*.bvh"

[labels]
pattern = '^dataset-2_(?P<action>[a-z-]+)_(?P<style>[a-z]+)_\\d+$'
# every action but wave-right-hand (2 takes: too few for Neural Marionette's split)
classes = ["raise-up-both-hands", "raise-up-left-hand", "raise-up-right-hand", "run", "walk",
           "walk-turn-left", "walk-turn-right", "wave-both-hands", "wave-left-hand"]

[skeleton]
units = "cm"
dummy_root = "joint_Root"            # Bandai's root above the hips ...
fold_dummy_root = true               # ... which carries the motion in some takes
offset_tolerance = 0.001             # metres: the elderly session's LowerLeg_L is 0.04 cm longer

[frames]
fps = 30.0

[split]
by = "style"                         # one take per cell: whole styles go to test
'''

SUBJECTS_SPEC = '''# An ASF/AMC set with subjects (written by docs/examples/own_data_sets.py;
# docs/datasets.md, "Walk-through: two data sets of one's own").
schema = 1
name = "lab-subjects"
description = "bandai2-mini's clips as seven performers' AMC takes, one ASF per performer"
license = "CC BY-NC 4.0"
credit = "Bandai Namco Research Inc. (motion); written by docs/examples/own_data_sets.py"

[source]
path = "mocap"
format = "asf_amc"
asf = "*.asf"                        # each take is read with its own performer's ASF

[labels]
from = "csv"
file = "labels.csv"                  # clip, action, subject

[skeleton]
units = "cm"
hips = ["UpperLeg_L", "UpperLeg_R"]  # Hip_L / Hip_R both start at the root
offset_tolerance = 0.03              # metres: the performers' bones differ by up to 2.5 cm

[frames]
fps = 30.0                           # AMC files carry no frame rate

[split]
by = "subject"                       # no performer on both sides ...
stratify = "action"                  # ... and every action on both sides
'''


def first_spec(spec: str, drop: tuple[str, ...], replace: dict[str, str] | None = None) -> str:
    """The spec a user would write first (the walk-through's starting point): ``spec`` less
    its comments, the lines setting the keys in ``drop`` (and a list's continuation lines)
    and the sections left empty, with the values of ``replace`` (``{line: line}``) put back
    as they were before a refusal asked for them."""
    rows: list[str] = []
    dropping = False
    for line in spec.split("\n"):
        if line.startswith("#") or (dropping and line.startswith(" ")):
            continue
        dropping = line.split("=")[0].strip() in drop
        if not dropping:
            line = line.split("  #")[0].rstrip()
            rows.append((replace or {}).get(line, line))
    out = re.sub(r"\n\[[a-z]+\]\n(?=\n|$)", "\n", "\n".join(rows))  # a section left empty
    out = re.sub(r"\n{3,}", "\n\n", out)
    return out.strip("\n") + "\n"


#: the specs a user would write first: what the files are, where, and how they are
#: labelled; each refusal on the way then asks for one more line (or another value)
STYLES_FIRST = first_spec(STYLES_SPEC, ("classes", "dummy_root", "fold_dummy_root",
                                        "offset_tolerance", "by"))
SUBJECTS_FIRST = first_spec(SUBJECTS_SPEC, ("hips", "offset_tolerance", "stratify"),
                            {'asf = "*.asf"': 'asf = "01/01.asf"'})


def _cells(clips) -> dict[tuple[str, str], int]:
    """(action, style) -> the index of the cell's first clip by name."""
    out: dict[tuple[str, str], int] = {}
    for i in sorted(range(len(clips)), key=lambda i: clips.clip_names[i]):
        key = (clips.label_names[clips.labels[i]], clips.style_names[clips.styles[i]])
        out.setdefault(key, i)
    return out


def _motion(clips, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Clip ``i``'s local rotation matrices (T, J, 3, 3) and root translation (T, 3), metres."""
    from repro.motion.rotations import quat_to_matrix

    s, n = int(clips.starts[i]), int(clips.lengths[i])
    R = np.asarray(quat_to_matrix(np.asarray(clips.rotations[s:s + n], np.float64)))
    return R, np.asarray(clips.root[s:s + n], np.float64)


def _yaw(R: np.ndarray) -> np.ndarray:
    """Per frame, the angle (radians, unwrapped) about +y of the root's local z axis."""
    z = R[:, :, 2]
    return np.unwrap(np.arctan2(z[:, 0], z[:, 2]))


def dummy_carries_root_motion(R: np.ndarray, root: np.ndarray) -> tuple:
    """Move the root motion (``R``: (T, J, 3, 3), ``root``: (T, 3) metres) onto a dummy root:
    the dummy gets the translation over the floor and the body's yaw ``ψ``, ``Hips`` what is
    left: ``t_hips = R_y(ψ)ᵀ (root − t_dummy)``, ``R_hips = R_y(ψ)ᵀ R_root`` (world positions
    unchanged: ``fold_dummy_root`` composes them back).  Returns (R', hips translation,
    dummy translation, ψ in degrees)."""
    psi = _yaw(R[:, 0])
    c, s = np.cos(psi), np.sin(psi)
    Ry = np.zeros((len(psi), 3, 3))
    Ry[:, 0, 0], Ry[:, 0, 2], Ry[:, 1, 1], Ry[:, 2, 0], Ry[:, 2, 2] = c, s, 1.0, -s, c
    t_dummy = root * np.array([1.0, 0.0, 1.0])
    hips_t = np.einsum("tji,tj->ti", Ry, root - t_dummy)
    R2 = R.copy()
    R2[:, 0] = np.einsum("tji,tjk->tik", Ry, R[:, 0])
    return R2, hips_t, t_dummy, np.degrees(psi)


def style_takes(clips) -> list[tuple[str, str, int]]:
    """The BVH set's takes: (action, style, index of the bundled clip), one per cell (the
    cell's first clip by name), :data:`SMALL_CLASS` in :data:`SMALL_STYLES` only."""
    return [(a, s, i) for (a, s), i in _cells(clips).items()
            if a != SMALL_CLASS or s in SMALL_STYLES]


def write_styles_set(out: Path, clips=None) -> Path:
    """``out/takes/*.bvh`` and ``out/styles.toml`` (module docstring); returns the spec."""
    from dataclasses import replace

    from repro.data.bvh_write import bvh_of, save_bvh
    from repro.motion.skeleton import Skeleton

    if clips is None:
        from repro.data.registry import load_clipset

        clips = load_clipset("bandai2-mini")
    sk = clips.skeleton
    off = sk.offsets.copy()
    j = sk.index(OFF_JOINT)
    off[j] = off[j] * (1 + OFF_CM / 100 / np.linalg.norm(off[j]))  # along the bone
    longer = Skeleton(sk.names, sk.parents, off)
    takes = out / "takes"
    takes.mkdir(parents=True, exist_ok=True)
    for _action, style, i in style_takes(clips):
        R, root = _motion(clips, i)
        skel = longer if style == OFF_STYLE else sk
        if style == DUMMY_MOVES_STYLE:
            R, hips_t, t_dummy, psi = dummy_carries_root_motion(R, root)
            bvh = bvh_of(skel, hips_t, R, clips.fps, dummy_root=DUMMY_ROOT)
            motion = bvh.motion.copy()
            motion[:, 0:3] = np.round(t_dummy * 100.0, 6)    # Xposition Yposition Zposition
            motion[:, 5] = np.round(psi, 6)                  # Zrotation Xrotation Yrotation
            bvh = replace(bvh, motion=motion)
        else:
            bvh = bvh_of(skel, root, R, clips.fps, dummy_root=DUMMY_ROOT)
        save_bvh(bvh, takes / f"{clips.clip_names[i]}.bvh")
    spec = out / "styles.toml"
    spec.write_text(STYLES_SPEC)
    return spec


# ----------------------------------------------------------------------------- ASF / AMC
#: joints whose children start apart: (child -> the bone without dofs that reaches it)
CONNECTORS = {"Spine": "Waist", "UpperLeg_L": "Hip_L", "UpperLeg_R": "Hip_R",
              "Shoulder_L": "Clavicle_L", "Shoulder_R": "Clavicle_R"}


def _bones(sk, scale: float) -> list[tuple[str, str, np.ndarray, bool]]:
    """The ASF bones of the stand-in's skeleton ``sk`` (lengths × ``scale``, centimetres):
    (name, parent bone, vector, has dofs), parents first.  Joint ``j`` is the bone ``j``,
    starting at the joint and reaching its first child (half its own offset for a leaf); a
    child that does not start there hangs from a connector bone (:data:`CONNECTORS`) from
    the end of its parent's bone."""
    off = np.asarray(sk.offsets, np.float64) * 100.0 * scale
    kids = {j: sk.children(j) for j in range(sk.n_joints)}
    reach = {j: (off[kids[j][0]] if kids[j] else 0.5 * off[j]) for j in range(sk.n_joints)}
    reach[0] = np.zeros(3)  # the root has no bone: its children start at it
    bones = []
    for j in range(1, sk.n_joints):
        p = sk.parents[j]
        name, parent = sk.names[j], "root" if p == 0 else sk.names[p]
        if name in CONNECTORS:  # from the end of the parent's bone to this joint
            bones.append((CONNECTORS[name], parent, off[j] - reach[p], False))
            parent = CONNECTORS[name]
        bones.append((name, parent, reach[j], True))
    return bones


def asf_text(sk, scale: float, subject: str) -> str:
    """The ASF of one subject: lengths in centimetres (``:units length 1``), degrees, rest
    frames aligned with the world (``axis 0 0 0``), ``dof rx ry rz`` on every joint's bone."""
    def num(v):
        return " ".join(f"{float(x):.6f}" for x in v)

    out = [":version 1.10", f":name subject{subject}", ":units", "  mass 1.0", "  length 1.0",
           "  angle deg", ":documentation",
           "  bandai2-mini's skeleton, written by docs/examples/own_data_sets.py",
           ":root", "   order TX TY TZ RX RY RZ", "   axis XYZ", "   position 0 0 0",
           "   orientation 0 0 0", ":bonedata"]
    bones = _bones(sk, scale)
    for k, (name, _p, vec, dof) in enumerate(bones, start=1):
        length = float(np.linalg.norm(vec))
        direction = vec / length
        out += ["  begin", f"     id {k}", f"     name {name}", f"     direction {num(direction)}",
                f"     length {length:.6f}", "     axis 0 0 0 XYZ"]
        if dof:
            out.append("    dof rx ry rz")
        out.append("  end")
    out += [":hierarchy", "  begin"]
    for parent in dict.fromkeys(p for _n, p, _v, _d in bones):
        out.append(f"    {parent} " + " ".join(n for n, p, _v, _d in bones if p == parent))
    out += ["  end", ""]
    return "\n".join(out)


def amc_text(sk, R: np.ndarray, root: np.ndarray) -> str:
    """The AMC of one clip: the root's translation (cm) and rotation, each joint's local
    rotation as ``rx ry rz`` about fixed axes (``R = Rz · Ry · Rx``), degrees."""
    from scipy.spatial.transform import Rotation

    T, J = R.shape[:2]
    ang = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_euler("xyz", degrees=True).reshape(T, J, 3)
    out = ["# written by docs/examples/own_data_sets.py", ":FULLY-SPECIFIED", ":DEGREES"]
    for t in range(T):
        out.append(str(t + 1))
        out.append("root " + " ".join(f"{v:.6f}" for v in (*(root[t] * 100.0), *ang[t, 0])))
        for j in range(1, J):
            out.append(f"{sk.names[j]} " + " ".join(f"{v:.6f}" for v in ang[t, j]))
    return "\n".join(out) + "\n"


def subject_takes(clips) -> list[tuple[str, str, str, int]]:
    """The ASF/AMC set's takes: (subject, clip, action, index of the bundled clip), in the
    order they are numbered (per subject, by action)."""
    out, n = [], {}
    for (action, style), i in _cells(clips).items():
        subject = SUBJECTS[style]
        if action == FEW_ACTION and subject not in FEW_SUBJECTS:
            continue
        n[subject] = n.get(subject, 0) + 1
        out.append((subject, f"{subject}_{n[subject]:02d}", action, i))
    return out


def subject_scale(subject: str) -> float:
    """Subject ``nn``'s bones: ``1 + 0.01 · (nn − 1)`` times the stand-in's."""
    return 1 + 0.01 * (int(subject) - 1)


def write_subjects_set(out: Path, clips=None) -> Path:
    """``out/mocap/<nn>/<nn>.asf`` and ``<nn>_<take>.amc``, ``out/labels.csv`` and
    ``out/subjects.toml`` (module docstring); returns the spec."""
    if clips is None:
        from repro.data.registry import load_clipset

        clips = load_clipset("bandai2-mini")
    sk = clips.skeleton
    src = out / "mocap"
    rows = ["clip,action,subject"]
    for subject, clip, action, i in subject_takes(clips):
        folder = src / subject
        if not folder.is_dir():
            folder.mkdir(parents=True)
            (folder / f"{subject}.asf").write_text(asf_text(sk, subject_scale(subject), subject))
        R, root = _motion(clips, i)
        # a taller subject's root is higher and travels further: the bundled path × its scale
        (folder / f"{clip}.amc").write_text(amc_text(sk, R, root * subject_scale(subject)))
        rows.append(f"{clip},{action},{subject}")
    (out / "labels.csv").write_text("\n".join(rows) + "\n")
    spec = out / "subjects.toml"
    spec.write_text(SUBJECTS_SPEC)
    return spec


def write_own_data_sets(out: Path) -> tuple[Path, Path]:
    """Both sets under ``out/styles`` and ``out/subjects``; returns their specs."""
    from repro.data.registry import load_clipset

    clips = load_clipset("bandai2-mini")
    return (write_styles_set(Path(out) / "styles", clips),
            write_subjects_set(Path(out) / "subjects", clips))


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python docs/examples/own_data_sets.py OUT_FOLDER")
    for p in write_own_data_sets(Path(sys.argv[1])):
        print(p)
