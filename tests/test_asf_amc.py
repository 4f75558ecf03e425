"""ASF/AMC reader: forward kinematics against an independent implementation, parsing details,
and malformed input (always a DataError naming the file and the line)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from repro.data.asf_amc import (
    AmcMotion,
    Asf,
    parse_amc,
    parse_asf,
    read_amc,
    read_asf,
    to_skeleton_motion,
)
from repro.errors import DataError
from repro.motion.skeleton import forward_kinematics

# name, parent, direction (not unit on purpose for some), length, axis angles about x y z,
# axis order, dofs.  Axis orders and dof subsets/orders vary; "neck" has no dofs.
BONES = [
    ("lhip", "root", (0.6, -0.8, 0.0), 2.5, (0.0, 0.0, 20.0), "XYZ", "rx ry rz"),
    ("lfemur", "lhip", (0.34, -0.94, 0.05), 7.0, (10.0, -5.0, 30.0), "ZYX", "rx ry rz"),
    ("ltibia", "lfemur", (0.0, -1.0, 0.0), 7.2, (0.0, 0.0, 20.0), "XYZ", "rx"),
    ("rhip", "root", (-0.6, -0.8, 0.0), 2.5, (-15.0, 40.0, -20.0), "YZX", "rz rx"),
    ("rfemur", "rhip", (-0.3, -0.95, 0.1), 7.0, (5.0, 25.0, -35.0), "ZXY", "ry rz rx"),
    ("spine", "root", (0.0, 1.0, 0.1), 3.0, (12.0, 0.0, -7.0), "XZY", "ry"),
    ("neck", "spine", (0.0, 1.0, 0.0), 1.0, (0.0, 0.0, 0.0), "XYZ", ""),
    ("head", "neck", (0.0, 1.0, 0.2), 2.0, (30.0, 60.0, 90.0), "YXZ", "rx ry rz"),
    ("lclav", "spine", (1.0, 0.2, 0.0), 3.0, (0.0, 0.0, -20.0), "XYZ", "rz ry"),
]
N_FRAMES = 20


def _unit(d):
    d = np.asarray(d, float)
    return d / np.linalg.norm(d)


def write_asf(*, root_order="TX TY TZ RX RY RZ", root_axis="XYZ", position=(0, 0, 0),
              orientation=(0, 0, 0), radians=False, length_unit=1.0, nl="\n") -> str:
    conv = math.radians if radians else (lambda v: v)
    out = [":version 1.10", ":name testbody", "# a comment line", ":units",
           "  mass 1.0", f"  length {length_unit!r}", f"  angle {'rad' if radians else 'deg'}",
           ":documentation", "  Written by tests/test_asf_amc.py # not a comment here",
           "  Second line.", ":root", f"   order {root_order}", f"   axis {root_axis}",
           "   position " + " ".join(repr(float(v)) for v in position),
           "   orientation " + " ".join(repr(conv(float(v))) for v in orientation),
           ":bonedata"]
    for i, (name, _p, d, length, axis, order, dof) in enumerate(BONES, start=1):
        out += ["  begin", f"     id {i}", f"     name {name}",
                "     direction " + " ".join(repr(float(v)) for v in _unit(d)),
                f"     length {length!r}",
                "     axis " + " ".join(repr(float(conv(v))) for v in axis) + f" {order}"]
        if dof:
            out.append(f"    dof {dof}")
            lims = [f"({-170.0 + k} {170.0 - k})" for k in range(len(dof.split()))]
            out.append("    limits " + lims[0])
            out += ["           " + s for s in lims[1:]]
        out.append("  end")
    out += [":hierarchy", "  begin"]
    parents = dict.fromkeys(p for _n, p, *_ in BONES)
    for p in parents:
        out.append(f"    {p} " + " ".join(n for n, q, *_ in BONES if q == p))
    out += ["  end", ""]
    return nl.join(out)


def make_motion(root_order: str, seed: int = 0) -> dict[str, np.ndarray]:
    """Random motion, degrees and ASF length units: name -> (T, n_dof) in dof order."""
    rng = np.random.default_rng(seed)
    vals = {}
    cols = []
    for tok in root_order.split():
        cols.append(rng.uniform(-20, 20, N_FRAMES) if tok[0] in "tT"
                    else rng.uniform(-90, 90, N_FRAMES))
    vals["root"] = np.stack(cols, axis=1)
    for name, _p, _d, _l, _a, _o, dof in BONES:
        if dof:
            vals[name] = rng.uniform(-80, 80, (N_FRAMES, len(dof.split())))
    return vals


def write_amc(vals, root_order, *, radians=False, keyword=True, nl="\n", start=1) -> str:
    out = ["# AMC written by the test", ":FULLY-SPECIFIED"]
    if keyword:
        out.append(":RADIANS" if radians else ":DEGREES")
    rot_cols = {"root": [t[0] in "rR" for t in root_order.split()]}
    for t in range(N_FRAMES):
        out.append(str(start + t))
        for name, v in vals.items():
            row = [math.radians(x) if radians and (name != "root" or rot_cols["root"][k]) else x
                   for k, x in enumerate(v[t])]
            out.append(name + " " + " ".join(repr(float(x)) for x in row))
    out.append("")
    return nl.join(out)


# ------------------------------------------------------------- independent implementation
def reference_positions(vals, *, root_order, root_axis, position, orientation):
    """Bone start and end positions (T, 3) per bone, ASF units, by walking the tree of BONES
    recursively with 4x4 transforms of the bones' *axis* frames (scipy rotations).

    Frame of bone b: F_b = F_p · [C_p⁻¹ C_b M_b | C_p⁻¹ d_p l_p]; the bone's end is
    F_b · (C_b⁻¹ d_b l_b).  Root frame: [O M_root | P + O T]."""

    def euler(angles_xyz, order):  # the triple is (x, y, z); order = application order
        ang = [angles_xyz["XYZ".index(c)] for c in order]
        return Rotation.from_euler(order.lower(), ang, degrees=True).as_matrix()

    def dof_rot(names, values):
        rots = [(n[1], v) for n, v in zip(names, values) if n[0] == "r"]
        if not rots:
            return np.eye(3)
        return Rotation.from_euler("".join(a for a, _ in rots), [v for _, v in rots],
                                   degrees=True).as_matrix()

    def homog(R, t):
        H = np.eye(4)
        H[:3, :3], H[:3, 3] = R, t
        return H

    info = {b[0]: b for b in BONES}
    kids: dict[str, list[str]] = {}
    for name, parent, *_ in BONES:
        kids.setdefault(parent, []).append(name)
    starts = {n: np.zeros((N_FRAMES, 3)) for n in ["root"] + list(info)}
    ends = {n: np.zeros((N_FRAMES, 3)) for n in info}

    def walk(name, F_p, C_p, vec_p, t):
        _n, _p, d, length, axis, order, dof = info[name]
        C = euler(axis, order)
        M = dof_rot(dof.split(), vals[name][t]) if dof else np.eye(3)
        F = F_p @ homog(C_p.T @ C @ M, C_p.T @ vec_p)
        vec = _unit(d) * length
        starts[name][t] = F[:3, 3]
        ends[name][t] = (F @ np.append(C.T @ vec, 1.0))[:3]
        for k in kids.get(name, []):
            walk(k, F, C, vec, t)

    toks = [s.lower() for s in root_order.split()]
    O = euler(orientation, root_axis)
    for t in range(N_FRAMES):
        T = np.zeros(3)
        for k, s in enumerate(toks):
            if s[0] == "t":
                T["xyz".index(s[1])] = vals["root"][t, k]
        F_root = homog(O @ dof_rot(toks, vals["root"][t]), np.asarray(position, float) + O @ T)
        starts["root"][t] = F_root[:3, 3]
        for k in kids["root"]:
            walk(k, F_root, np.eye(3), np.zeros(3), t)
    return starts, ends


_KEYS = ("root_order", "root_axis", "position", "orientation", "radians", "amc_radians",
         "keyword", "nl")
VARIANTS = {name: dict(zip(_KEYS, v, strict=True)) for name, v in {
    "standard": ("TX TY TZ RX RY RZ", "XYZ", (0, 0, 0), (0, 0, 0), False, False, True, "\n"),
    # interleaved root order, pre-set position/orientation, ASF and AMC in radians, CR LF
    "interleaved-rad": ("RY TX RZ TY RX TZ", "ZXY", (1.5, -2.0, 3.0), (10.0, -25.0, 40.0), True,
                        True, True, "\r\n"),
    # rotations before translations; the AMC names no angle unit (the ASF's: degrees); CR only
    "rot-first": ("rz ry rx tx ty tz", "YZX", (0, 0, 0), (0, 90, 0), False, False, False, "\r"),
}.items()}


@pytest.mark.parametrize("variant", list(VARIANTS))
@pytest.mark.parametrize("leaf_ends", [False, True])
def test_fk_matches_independent_implementation(variant, leaf_ends):
    v = VARIANTS[variant]
    asf_text = write_asf(root_order=v["root_order"], root_axis=v["root_axis"],
                         position=v["position"], orientation=v["orientation"],
                         radians=v["radians"], length_unit=0.45, nl=v["nl"])
    vals = make_motion(v["root_order"], seed=len(variant))
    amc_text = write_amc(vals, v["root_order"], radians=v["amc_radians"], keyword=v["keyword"],
                         nl=v["nl"])
    asf = parse_asf(asf_text.encode(), "t.asf")
    amc = parse_amc(amc_text.encode(), "t.amc", asf)
    assert amc.angle_unit == ("rad" if v["amc_radians"] else "deg")
    skel, root, R, fps = to_skeleton_motion(asf, amc, length_scale=1.0, leaf_ends=leaf_ends)
    assert fps == 120.0 and R.shape == (N_FRAMES, skel.n_joints, 3, 3)
    pos = forward_kinematics(skel, R, root)
    starts, ends = reference_positions(vals, root_order=v["root_order"],
                                       root_axis=v["root_axis"], position=v["position"],
                                       orientation=v["orientation"])
    want = np.stack([starts[n] if n in starts else ends[n[:-4]] for n in skel.names], axis=1)
    leaves = {n for n, *_ in BONES} - {p for _n, p, *_ in BONES}
    assert skel.n_joints == 1 + len(BONES) + (len(leaves) if leaf_ends else 0)
    err = np.abs(pos - want).max()
    print(f"{variant} leaf_ends={leaf_ends}: max |FK - reference| = {err:.3e} ASF units")
    assert err < 1e-4
    # the default length scale undoes ':units length 0.45'
    _, root2, _, _ = to_skeleton_motion(asf, amc)
    np.testing.assert_allclose(root2, root / 0.45)


def test_rest_pose_is_identity_and_offsets_follow_parent_bone():
    vals = {k: np.zeros_like(v) for k, v in make_motion("TX TY TZ RX RY RZ").items()}
    asf = parse_asf(write_asf(), "t.asf")
    amc = parse_amc(write_amc(vals, "TX TY TZ RX RY RZ"), "t.amc", asf)
    skel, _, R, _ = to_skeleton_motion(asf, amc, length_scale=2.0)
    np.testing.assert_allclose(R, np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(skel.offsets[skel.index("lhip")], 0.0)
    np.testing.assert_allclose(skel.offsets[skel.index("lfemur")], _unit((0.6, -0.8, 0)) * 5.0)
    assert skel.names[0] == "root" and skel.parents[skel.index("head")] == skel.index("neck")


# --------------------------------------------------------------------------- parsing details
MESSY_ASF = """# leading comment\r
:version 1.10\r
:name   messy   body\r
:units\r
\tmass 1.0\r
  length   1.0   # trailing comment\r
  angle rad\r
:documentation\r
  Free text: # kept, (parens) too\r
:root\r
  axis xyz\r
  order tx ty tz rz ry rx\r
  position 0 0 0\r
  orientation 0 0 0\r
:bonedata\r
  begin\r
    id 1\r
    name  thigh\r
    direction 0, 3, 4\r
    length 2.0\r
    axis 0.1 0.2 0.3 zyx\r
    dof rx   ry rz\r
    limits (-3.0 1.0)\r
           (-1.0 1.0)  # second pair\r
\r
           (-inf inf)\r
  end\r
  begin\r
    name shin\r
    direction 0 -1 0\r
    length 1.5\r
  end\r
:skin whatever.skin\r
  ignored lines\r
:hierarchy\r
  begin\r
     root   thigh\r
     thigh shin\r
  end\r
"""


def test_parsing_details():
    asf = parse_asf(MESSY_ASF.encode(), "messy.asf")
    assert asf.version == "1.10" and asf.name == "messy body" and asf.angle_unit == "rad"
    assert "Free text: # kept" in asf.documentation
    assert asf.root_order == ("tx", "ty", "tz", "rz", "ry", "rx") and asf.root_axis == "XYZ"
    thigh = asf.bones["thigh"]
    assert thigh.id == 1 and thigh.axis == (0.1, 0.2, 0.3) and thigh.axis_order == "ZYX"
    assert thigh.dof == ("rx", "ry", "rz")
    assert thigh.limits == ((-3.0, 1.0), (-1.0, 1.0), (-math.inf, math.inf))
    np.testing.assert_allclose(thigh.direction, (0, 0.6, 0.8))
    assert asf.bones["shin"].dof == () and asf.order == ("root", "thigh", "shin")
    assert asf.parent == {"thigh": "root", "shin": "thigh"}
    amc_text = ":fully-specified\n:radians\n  7 \nroot 1 2 3 0.1 0.2 0.3\nthigh\t0.5 0 0 # c\n" \
               "8\nthigh 0 0 0\nroot 1 2 3 0 0 0\nshin\n"
    amc = parse_amc(amc_text, "m.amc", asf)
    assert amc.fully_specified and amc.angle_unit == "rad" and amc.n_frames == 2
    assert amc.frame_numbers.tolist() == [7, 8] and set(amc.values) == {"root", "thigh"}
    np.testing.assert_allclose(amc.values["root"][0], [1, 2, 3, 0.1, 0.2, 0.3])
    _, _, R, _ = to_skeleton_motion(asf, amc, length_scale=1.0)
    want = Rotation.from_euler("zyx", [0.1, 0.2, 0.3]).as_matrix()  # order tx ty tz rz ry rx
    np.testing.assert_allclose(R[0, 0], want, atol=1e-12)


def test_read_from_disk(tmp_path):
    (tmp_path / "a.asf").write_text(write_asf())
    vals = make_motion("TX TY TZ RX RY RZ")
    (tmp_path / "a.amc").write_text(write_amc(vals, "TX TY TZ RX RY RZ"))
    asf = read_asf(tmp_path / "a.asf")
    assert isinstance(asf, Asf) and isinstance(read_amc(tmp_path / "a.amc", asf), AmcMotion)
    with pytest.raises(DataError, match="file not found"):
        read_asf(tmp_path / "nope.asf")


# -------------------------------------------------------------------------- malformed input
def _line_of(text: str, needle: str, nth: int = 0) -> int:
    hits = [i for i, ln in enumerate(text.split("\n"), start=1) if needle in ln]
    return hits[nth]


ASF = write_asf()
VALS = make_motion("TX TY TZ RX RY RZ")
AMC = write_amc(VALS, "TX TY TZ RX RY RZ")
N_ASF_LINES = len(ASF.rstrip("\n").split("\n"))


def _cut_hierarchy(t):
    return t[:t.index(":hierarchy")]


ASF_CASES = {
    "missing hierarchy": (_cut_hierarchy, lambda t: len(t.rstrip("\n").split("\n")),
                          "no :hierarchy"),
    "undefined bone": (lambda t: t.replace("    root lhip rhip spine", "    root lhip rhip spine ghost"),
                       lambda t: _line_of(t, "root lhip rhip spine"), "'ghost'"),
    "undefined parent": (lambda t: t.replace("    spine neck lclav", "    spne neck lclav"),
                         lambda t: _line_of(t, "spne neck"), "'spne'"),
    "cycle": (lambda t: t.replace("    lhip lfemur", "    ltibia lfemur"),
              lambda t: _line_of(t, "    lfemur ltibia"), "cycle"),
    "two parents": (lambda t: t.replace("    neck head", "    neck head\n    lclav head"),
                    lambda t: _line_of(t, "lclav head"), "second parent"),
    "non-numeric length": (lambda t: t.replace("length 7.2", "length 7.2x"),
                           lambda t: _line_of(t, "length 7.2x"), "'7.2x' is not a number"),
    "comma in a number": (lambda t: t.replace("length 7.2", "length 7,2"),
                          lambda t: _line_of(t, "length 7,2"), "expected 1 numbers, found 2"),
    "non-numeric direction": (lambda t: t.replace("direction 0.0 -1.0 0.0", "direction 0 -1 zero"),
                              lambda t: _line_of(t, "direction 0 -1 zero"), "'zero'"),
    "limits count": (lambda t: t.replace("    limits (-170.0 170.0)\n  end",
                                         "    limits (-170.0 170.0) (1 2)\n  end"),
                     lambda t: _line_of(t, "limits (-170.0 170.0) (1 2)"), "expected 2 numbers"),
    "bad axis order": (lambda t: t.replace("30.0 ZYX", "30.0 ZYY"),
                       lambda t: _line_of(t, "30.0 ZYY"), "rotation order such as XYZ"),
    "unknown dof": (lambda t: t.replace("dof ry rz rx", "dof ry rw rx"),
                    lambda t: _line_of(t, "dof ry rw rx"), "unknown channel 'rw'"),
    "repeated dof": (lambda t: t.replace("dof ry rz rx", "dof ry rz ry"),
                     lambda t: _line_of(t, "dof ry rz ry"), "repeated"),
    "angle unit": (lambda t: t.replace("angle deg", "angle grad"),
                   lambda t: _line_of(t, "angle grad"), "angle deg|rad"),
    "duplicate bone": (lambda t: t.replace("name rfemur", "name lfemur"),
                       lambda t: _line_of(t, "name lfemur", 1) - 2, "used twice"),
    "bone without end": (lambda t: t.replace("  end\n:hierarchy", ":hierarchy"),
                         lambda t: _line_of(t, ":hierarchy"), "no 'end'"),
    "unknown field": (lambda t: t.replace("length 7.2", "lenght 7.2"),
                      lambda t: _line_of(t, "lenght 7.2"), "unknown bone field 'lenght'"),
    "missing root": (lambda t: t.replace(":root", ":rooot"), lambda t: N_ASF_LINES,
                     "no :root"),
    "text outside a section": (lambda t: "hello\n" + t, lambda t: 1, "outside any section"),
    "unattached bone": (lambda t: t.replace("    neck head\n", ""),
                        lambda t: _line_of(t, "name head") - 2, "not attached"),
    "hierarchy without end": (lambda t: t.rstrip().rsplit("\n", 1)[0] + "\n",
                              lambda t: len(t.rstrip("\n").split("\n")), "no 'end'"),
    "huge number": (lambda t: t.replace("length 7.2", "length " + "9" * 5000),
                    lambda t: _line_of(t, "length 999"), "not a finite number"),
}


@pytest.mark.parametrize("case", list(ASF_CASES))
def test_malformed_asf(case):
    mutate, line, words = ASF_CASES[case]
    text = mutate(ASF)
    assert text != ASF
    with pytest.raises(DataError) as ei:
        parse_asf(text.encode(), "bad.asf")
    e = ei.value
    assert e.file == "bad.asf" and e.line == line(text), (str(e), line(text))
    assert words in str(e) and str(e).startswith(f"bad.asf:{e.line}: ")
    assert len(str(e)) < 250


def _line_eq(text: str, exact: str, nth: int = 0) -> int:
    return [i for i, ln in enumerate(text.split("\n"), start=1) if ln == exact][nth]


def _edit_first(text: str, prefix: str, fn) -> str:
    lines = text.split("\n")
    k = next(i for i, ln in enumerate(lines) if ln.startswith(prefix))
    lines[k:k + 1] = fn(lines[k])
    return "\n".join(lines)


def _first_value_to(word):
    return lambda t: _edit_first(t, "rhip ", lambda ln: [" ".join(["rhip", word] + ln.split()[2:])])


AMC_CASES = {
    "wrong value count": (lambda t: _edit_first(t, "ltibia ", lambda ln: [ln + " 1.0"]),
                          lambda t: _line_of(t, " 1.0"), "needs 1 values, found 2"),
    "non-numeric value": (_first_value_to("abc"), lambda t: _line_of(t, "rhip abc"),
                          "'abc' is not a number"),
    "nan value": (_first_value_to("nan"), lambda t: _line_of(t, "rhip nan"),
                  "not a finite number"),
    "frame out of order": (lambda t: t.replace("\n3\n", "\n4\n", 1),
                           lambda t: _line_eq(t, "4"), "does not follow frame 2"),
    "frame repeated": (lambda t: t.replace("\n3\n", "\n2\n", 1),
                       lambda t: _line_eq(t, "2", 1), "does not follow frame 2"),
    "non-integer frame": (lambda t: t.replace("\n3\n", "\n3.5\n", 1),
                          lambda t: _line_eq(t, "3.5"), "neither a frame number"),
    "unknown bone": (lambda t: t.replace("\nspine ", "\nspin ", 1), lambda t: _line_of(t, "spin "),
                     "unknown bone 'spin'"),
    "bone twice": (lambda t: _edit_first(t, "spine ", lambda ln: ["lhip 0 0 0", ln]),
                   lambda t: _line_of(t, "lhip 0 0 0"), "given twice"),
    "bone missing": (lambda t: _edit_first(t, "head ", lambda ln: []),
                     lambda t: _line_eq(t, "1"), "no values for bone 'head'"),
    "bone missing in the last frame": (lambda t: t.rstrip("\n").rsplit("\n", 1)[0] + "\n",
                                       lambda t: _line_eq(t, str(N_FRAMES)),
                                       "no values for bone 'lclav'"),
    "values before frames": (lambda t: t.replace(":DEGREES", ":DEGREES\nroot 1 2 3 4 5 6"),
                             lambda t: _line_of(t, "root 1 2 3 4 5 6"), "before the first frame"),
    "keyword after frames": (lambda t: t + ":RADIANS\n", lambda t: _line_of(t, ":RADIANS"),
                             "after the first frame"),
    "both angle units": (lambda t: t.replace(":DEGREES", ":DEGREES\n:RADIANS"),
                         lambda t: _line_of(t, ":RADIANS"), "both"),
    "no frames": (lambda t: ":DEGREES\n", lambda t: 1, "no frames"),
}


@pytest.mark.parametrize("case", list(AMC_CASES))
def test_malformed_amc(case):
    mutate, line, words = AMC_CASES[case]
    text = mutate(AMC)
    assert text != AMC
    asf = parse_asf(ASF, "good.asf")
    with pytest.raises(DataError) as ei:
        parse_amc(text.encode(), "bad.amc", asf)
    e = ei.value
    assert e.file == "bad.amc" and e.line == line(text), (str(e), line(text))
    assert words in str(e)


def test_translation_dof_on_a_bone_is_refused_naming_the_asf_line():
    text = ASF.replace("dof ry rz rx", "dof ry rz rx tx")
    text = text.replace("    limits (-170.0 170.0)\n           (-169.0 169.0)\n           "
                        "(-168.0 168.0)\n  end", "  end")
    asf = parse_asf(text, "tdof.asf")
    vals = dict(VALS)
    vals["rfemur"] = np.hstack([VALS["rfemur"], np.zeros((N_FRAMES, 1))])
    amc = parse_amc(write_amc(vals, "TX TY TZ RX RY RZ"), "t.amc", asf)
    assert amc.values["rfemur"].shape == (N_FRAMES, 4)
    with pytest.raises(DataError) as ei:
        to_skeleton_motion(asf, amc)
    assert ei.value.file == "tdof.asf" and ei.value.line == _line_of(text, "dof ry rz rx tx")
    assert "not supported" in str(ei.value)


def test_mutations_raise_only_data_error():
    """Seeded random edits of valid files: parsing either succeeds or raises DataError."""
    rng = np.random.default_rng(16)
    asf_ok = parse_asf(ASF, "good.asf")
    pieces = [" ", "\n", "#", "(", ")", ",", ":", "-", "1e999", "nan", "root", "begin", "end",
              "x", "0", "\r", "\x00", "é", ":hierarchy", "9" * 400]
    for i in range(300):
        base = ASF if i % 2 == 0 else AMC
        b = list(base)
        for _ in range(int(rng.integers(1, 4))):
            k = int(rng.integers(0, len(b)))
            op = rng.integers(0, 3)
            if op == 0:
                del b[k:k + int(rng.integers(1, 30))]
            elif op == 1:
                b.insert(k, pieces[int(rng.integers(0, len(pieces)))])
            else:
                b = b[:k]
        text = "".join(b)
        try:
            if base is ASF:
                a = parse_asf(text.encode("utf-8", "surrogatepass"), "fuzz.asf")
                m = parse_amc(AMC, "good.amc", a)
                to_skeleton_motion(a, m)
            else:
                parse_amc(text.encode("utf-8", "surrogatepass"), "fuzz.amc", asf_ok)
        except DataError as e:
            assert e.file in ("fuzz.asf", "fuzz.amc", "good.amc", "good.asf") and e.line
