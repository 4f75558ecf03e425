"""Readers for the papers' own datasets in their upstream formats, and their registry entries.

Datasets (each in ``$REPRO_PAPER_DATA/<name>/``, default ``REPRO_HOME/paper-data/<name>/``;
layouts in ``docs/datasets.md`` and each module's docstring):

- ``humanact12`` (ODMO Table 1): ACTOR's ``humanact12poses.pkl`` -> :mod:`.humanact12`;
- ``uestc`` (ODMO Table 1): ODMO's ``odmo_3d/*.npy`` + split CSVs, or ACTOR's VIBE cache
  -> :mod:`.uestc`;
- ``cmu-mocap`` (ODMO Table 2): Action2Motion's ``mocap_3djoints/*.npy`` + clip list
  -> :mod:`.cmu_mocap`;
- ``babel`` (MultiAct): BABEL v1.0 ``train.json``/``val.json`` + AMASS ``*_poses.npz`` + the
  SMPL-H body model -> :mod:`.babel`, :mod:`.amass`, :mod:`.smpl`;
- ``babel-mag`` (Neural Marionette): not public; its status says so.

``ENTRIES`` is read by :mod:`repro.data.registry` (:func:`repro.data.builtin_sets.
upstream_entries`); the entries are :mod:`repro.data.dataset_entry`'s.  Status checks are cheap
(file presence; fingerprints are content hashes cached by file stat, see :mod:`.fingerprint`).
Validation (``repro doctor``, issue 16) runs each reader's own checks on the files present
(HumanAct12: the restricted unpickler and every clip's shape, values and label; UESTC and CMU
MoCap: every listed clip's ``.npy``; BABEL: the annotations, already read by its status check),
without building a ClipSet.
"""

from __future__ import annotations

from pathlib import Path

from repro.data.dataset_entry import DatasetEntry, DatasetStatus
from repro.errors import ReproError

from .locations import PAPER_DATA_ENV, paper_data_dir, paper_data_root

__all__ = ["ENTRIES", "PAPER_DATA_ENV", "paper_data_dir", "paper_data_root"]


def _status(name: str, check) -> DatasetStatus:
    """Run ``check(dir) -> (fingerprint | None, missing | None)``; a ReproError raised while
    checking (a malformed index file) becomes the ``missing`` text."""
    d = paper_data_dir(name)
    try:
        fp, missing = check(d)
    except ReproError as e:
        fp, missing = None, f"{name}: {e}"
    return DatasetStatus(missing is None, str(d), fp if missing is None else None, missing)


# ------------------------------------------------------------------------------ HumanAct12
def _humanact12_check(d: Path):
    from .fingerprint import tree_fingerprint
    from .humanact12 import HUMANACT12_FILE

    if not (d / HUMANACT12_FILE).is_file():
        return None, (f"HumanAct12: put {HUMANACT12_FILE} (ACTOR's HumanAct12Poses release) at "
                      f"{d / HUMANACT12_FILE}")
    return tree_fingerprint(d, [HUMANACT12_FILE]), None


def _humanact12_load():
    from .humanact12 import humanact12_clipset, read_humanact12

    return humanact12_clipset(read_humanact12(paper_data_dir("humanact12")))


# ------------------------------------------------------------------------------ UESTC
def _uestc_check(d: Path):
    from .fingerprint import tree_fingerprint
    from .uestc import ACTOR_FILES, ODMO_FILES, ODMO_JOINT_DIR, detect_layout, odmo_listed_files

    layout = detect_layout(d)
    if layout is None:
        return None, (f"UESTC: put ODMO's preprocessed UESTC ({', '.join(ODMO_FILES)} and "
                      f"{ODMO_JOINT_DIR}/<clip>.npy, from ODMO's dataset/uestc/) in {d}, or "
                      f"ACTOR's ({', '.join(ACTOR_FILES)})")
    if layout == "odmo":
        rel = odmo_listed_files(d)
        absent = [r for r in rel if not (d / r).is_file()]
        if absent:
            return None, (f"UESTC: {len(absent)} clips named in the split CSVs are missing, "
                          f"e.g. {d / absent[0]}")
        return tree_fingerprint(d, rel), None
    rel = list(ACTOR_FILES) + (["globtrans_usez.pkl"] if (d / "globtrans_usez.pkl").is_file()
                               else [])
    return tree_fingerprint(d, rel), None


def _uestc_load():
    from .uestc import read_uestc, uestc_clipset

    return uestc_clipset(read_uestc(paper_data_dir("uestc")))


# ------------------------------------------------------------------------------ CMU MoCap
def _cmu_check(d: Path):
    from .cmu_mocap import JOINT_DIR, listed_files, resolve_clip_list
    from .fingerprint import tree_fingerprint

    csv_name, _ = resolve_clip_list(d, "odmo7")
    if not (d / csv_name).is_file() or not (d / JOINT_DIR).is_dir():
        return None, (f"CMU MoCap: put Action2Motion's preprocessed CMU MoCap ({JOINT_DIR}/"
                      f"<motion>.npy and pose_clip_7class.csv (ODMO's 7 classes) or "
                      f"pose_clip.csv (A2M's 8)) in {d}")
    rel = listed_files(d, "odmo7")
    absent = [r for r in rel if not (d / r).is_file()]
    if absent:
        return None, (f"CMU MoCap: {len(absent)} clips named in {csv_name} are missing, "
                      f"e.g. {d / absent[0]}")
    return tree_fingerprint(d, rel), None


def _cmu_load():
    from .cmu_mocap import cmu_mocap_clipset, read_cmu_mocap

    return cmu_mocap_clipset(read_cmu_mocap(paper_data_dir("cmu-mocap")))


# ------------------------------------------------------------------------------ BABEL
def _babel_check(d: Path):
    from .babel import ANNOTATION_DIR, MOTION_DIR, SPLITS, read_babel
    from .smpl import locate_body_model

    problems, fp = [], None
    jsons = [d / ANNOTATION_DIR / f"{s}.json" for s in SPLITS]
    absent = [p for p in jsons if not p.is_file()]
    if absent:
        problems.append(f"put BABEL v1.0's {', '.join(p.name for p in absent)} in "
                        f"{d / ANNOTATION_DIR} (https://babel.is.tue.mpg.de) and the AMASS "
                        f"SMPL-H body data in {d / MOTION_DIR} (https://amass.is.tue.mpg.de)")
    else:
        try:
            fp = read_babel(d).fingerprint  # names the first absent AMASS file
        except ReproError as e:
            problems.append(str(e))
    try:
        locate_body_model("smplh", gender="male")  # MultiAct's joints use the male model
    except ReproError as e:
        problems.append(f"for joints, {e}")
    if problems:
        return None, "BABEL: " + "; ".join(problems)
    return fp, None


def _babel_load():
    from .babel import babel_clipset, read_babel
    from .smpl import load_body_model, locate_body_model

    model = load_body_model(locate_body_model("smplh", gender="male"))
    return babel_clipset(read_babel(paper_data_dir("babel")), model)


# ------------------------------------------------------------------------------ BABEL-MAG
def _babel_mag_check(d: Path):
    return None, ("BABEL-MAG: not public. Neural Marionette's authors did not release it (their "
                  "31-tag relabelling of 7,643 BABEL actions, with previous motion and next "
                  "tag), and no reader can exist without its format; Neural Marionette tables "
                  "run on the bandai2 stand-in")


def _validate(name: str, check, read) -> str | None:
    """``read(dir)`` (the reader, no ClipSet) when ``check`` finds the files present: its
    DataError, naming the file, is the damage; ``None`` when absent or intact."""
    d = paper_data_dir(name)
    try:
        if check(d)[1] is not None:
            return None  # not present: the status line says what is missing
    except ReproError:
        return None  # the status line quotes it
    if read is None:
        return None
    try:
        read(d)
    except ReproError as e:
        return str(e)
    return None


def _read_humanact12(d: Path):
    from .humanact12 import read_humanact12

    return read_humanact12(d)


def _read_uestc(d: Path):
    from .uestc import read_uestc

    return read_uestc(d)


def _read_cmu(d: Path):
    from .cmu_mocap import read_cmu_mocap

    return read_cmu_mocap(d)


_READERS = {"humanact12": _read_humanact12, "uestc": _read_uestc, "cmu-mocap": _read_cmu}


def _entry(name: str, description: str, check, loader) -> DatasetEntry:
    validate = (None if loader is None else
                lambda: _validate(name, check, _READERS.get(name)))  # BABEL: its check reads
    return DatasetEntry(name, description, True, lambda: _status(name, check), loader, validate)


ENTRIES: list[DatasetEntry] = [
    _entry("humanact12", "HumanAct12 (ODMO Tab. 1): 1,191 clips, 12 actions, 24 SMPL joints; "
           "ACTOR's humanact12poses.pkl", _humanact12_check, _humanact12_load),
    _entry("uestc", "UESTC (ODMO Tab. 1): 40 actions, 18 VIBE joints, train/test by subject; "
           "ODMO's odmo_3d npy + CSVs or ACTOR's VIBE cache", _uestc_check, _uestc_load),
    _entry("cmu-mocap", "CMU MoCap as Action2Motion preprocessed it (ODMO Tab. 2): 970 clips, "
           "7 actions, 20 joints", _cmu_check, _cmu_load),
    _entry("babel", "BABEL v1.0 + AMASS SMPL-H (MultiAct): segments in seconds, 52 joints via "
           "the SMPL-H body model", _babel_check, _babel_load),
    _entry("babel-mag", "BABEL-MAG (Neural Marionette): 31 tags relabelled from BABEL; not "
           "released", _babel_mag_check, None),
]
