"""Write a motion-capture folder the harness has never seen, and the data-set spec that declares it.

``python docs/examples/lab_example.py OUT`` takes the real clips of the bundled ``bandai2-mini``
(280 clips of Bandai-Namco-Research-Motiondataset-2, CC BY-NC 4.0) and writes them the way
another lab might keep them: another skeleton (19 joints: the toes dropped, every joint renamed
Blender-style, ``femur.L`` ...), z up, millimetres, files named ``take_0001.bvh`` ..., and the
action and style of each take in ``labels.csv``.  Nothing in the harness knows this layout:
``OUT/lab.toml`` describes it (README, "Your own motion capture"; docs/datasets.md), and

    repro data prepare OUT/lab.toml
    repro run marionette/table1 --scale quick --dataset OUT/lab.toml

prepare it and run a table on it by configuration alone.  The motion is the stand-in's, so a
table on it is a stand-in result as well (and the clips keep bandai2's license).
"""

from __future__ import annotations

import sys
from pathlib import Path

import repro  # noqa: F401,E402  (pins the kernel paths before torch / numpy load: repro/kernels.py)
import numpy as np

#: bandai2's joints -> this lab's names (the toes are not kept)
RENAME = {"Hips": "pelvis", "Spine": "spine.lower", "Chest": "spine.upper", "Neck": "neck",
          "Head": "head", "Shoulder_L": "clavicle.L", "UpperArm_L": "humerus.L",
          "LowerArm_L": "radius.L", "Hand_L": "hand.L", "Shoulder_R": "clavicle.R",
          "UpperArm_R": "humerus.R", "LowerArm_R": "radius.R", "Hand_R": "hand.R",
          "UpperLeg_L": "femur.L", "LowerLeg_L": "tibia.L", "Foot_L": "foot.L",
          "UpperLeg_R": "femur.R", "LowerLeg_R": "tibia.R", "Foot_R": "foot.R"}
#: y up -> z up: (x, y, z) -> (x, -z, y); the spec's up_axis = "z" turns it back
TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

SPEC = '''# A lab's motion capture, declared (written by docs/examples/lab_example.py).
schema = 1
name = "lab-example"
description = "bandai2-mini's clips in another skeleton, axes, units and naming scheme"
license = "CC BY-NC 4.0"
credit = "Bandai Namco Research Inc. (motion); re-expressed by docs/examples/lab_example.py"

[source]
path = "takes"
include = "take_*.bvh"

[labels]
from = "csv"
file = "labels.csv"

[skeleton]
up_axis = "z"
units = "mm"
hips = ["femur.L", "femur.R"]       # names the harness does not guess

[frames]
fps = 30.0

[split]
test_fraction = 0.2
seed = 0

[expect]
clips = {clips}
joints = 19
'''


def write_lab_example(out: Path) -> Path:
    """Write ``out/takes/*.bvh``, ``out/labels.csv`` and ``out/lab.toml``; returns the spec."""
    from repro.data.bvh_write import write_bvh
    from repro.data.registry import load_clipset
    from repro.motion.rotations import quat_to_matrix

    clips = load_clipset("bandai2-mini")
    keep = list(RENAME)
    idx = [clips.skeleton.names.index(n) for n in keep]
    sub = clips.skeleton.subset(keep)  # only leaves are dropped: the rest of the tree is intact
    from repro.motion.skeleton import Skeleton

    skel_mm = Skeleton(tuple(RENAME[n] for n in keep), sub.parents, sub.offsets * 1000.0)
    (out / "takes").mkdir(parents=True, exist_ok=True)
    rows = ["clip,action,style"]
    for i in range(len(clips)):
        s, n = int(clips.starts[i]), int(clips.lengths[i])
        R = quat_to_matrix(np.asarray(clips.rotations[s:s + n], np.float64))[:, idx]
        R[:, 0] = TO_Z_UP @ R[:, 0]  # the body turned z-up at the root
        root = np.asarray(clips.root[s:s + n], np.float64) @ TO_Z_UP.T * 1000.0
        name = f"take_{i + 1:04d}"
        write_bvh(out / "takes" / f"{name}.bvh", skel_mm, root, R, clips.fps, units="m")
        rows.append(f"{name},{clips.label_names[clips.labels[i]]},"
                    f"{clips.style_names[clips.styles[i]]}")
    (out / "labels.csv").write_text("\n".join(rows) + "\n")
    spec = out / "lab.toml"
    spec.write_text(SPEC.replace("{clips}", str(len(clips))))
    return spec


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python docs/examples/lab_example.py OUT_FOLDER")
    print(write_lab_example(Path(sys.argv[1])))
