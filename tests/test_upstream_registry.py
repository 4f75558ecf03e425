"""The paper datasets in the registry: statuses match the readers, loaders return ClipSets."""

import numpy as np
import pytest
from test_upstream_babel import write_babel
from test_upstream_uestc import write_actor, write_odmo
from upstream_synth import body_model_arrays

from repro.data.registry import get_entry, load_clipset
from repro.data.upstream import ENTRIES
from repro.data.upstream.skeletons import SMPLH_52
from repro.data.upstream.uestc import read_uestc
from repro.errors import MissingDataError


def test_entries_are_registered_as_paper_datasets():
    names = [e.name for e in ENTRIES]
    assert names == ["humanact12", "uestc", "cmu-mocap", "babel", "babel-mag"]
    for n in names:
        assert get_entry(n).is_paper_dataset


@pytest.mark.parametrize("writer, layout", [(write_odmo, "odmo"), (write_actor, "actor")])
def test_uestc_status_and_loader(paper_data, writer, layout):
    writer(paper_data / "uestc")
    st = get_entry("uestc").status()
    assert st.prepared and st.missing is None
    assert st.fingerprint == read_uestc(paper_data / "uestc").fingerprint
    cs = load_clipset("uestc")
    assert cs.name == "uestc" and cs.skeleton.n_joints == 18 and len(cs) == 3


def test_babel_needs_annotations_motions_and_the_smplh_model(paper_data, tmp_path, monkeypatch):
    write_babel(paper_data / "babel")
    st = get_entry("babel").status()
    assert not st.prepared and "SMPL-H body model (male)" in st.missing
    models = tmp_path / "models"
    (models / "smplh").mkdir(parents=True)
    np.savez(models / "smplh" / "SMPLH_MALE.npz", **body_model_arrays(SMPLH_52))
    monkeypatch.setenv("REPRO_SMPL_DIR", str(models))
    st = get_entry("babel").status()
    assert st.prepared and st.fingerprint
    cs = load_clipset("babel")
    assert cs.skeleton.n_joints == 52 and len(cs) == 6
    (paper_data / "babel" / "AMASS" / "KIT/KIT/3/walk_poses.npz").unlink()
    st = get_entry("babel").status()
    assert not st.prepared and "walk_poses.npz" in st.missing


def test_babel_mag_cannot_be_loaded(paper_data):
    with pytest.raises(MissingDataError, match="not public"):
        load_clipset("babel-mag")
