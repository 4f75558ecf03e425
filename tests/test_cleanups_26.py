"""The clean-ups folded into issue 26: one helper turns pydantic's ValidationError into a
ConfigError naming the field (:mod:`repro.config_errors`); Neural Marionette's protocols share
one params base, one data path and one sample-file reader/writer
(:mod:`repro.eval.protocols.marionette_common`).  Behaviour is unchanged: the messages, the
protocols' keyed fields and the sample files' bytes are what they were."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
import torch
from pydantic import BaseModel, ConfigDict, Field

from repro.config_errors import config_error, first_problem, resolve_config
from repro.data.action_items import GeneratedItems, ItemsConfig
from repro.errors import ConfigError, DataError
from repro.eval.protocols import get_protocol
from repro.eval.protocols.marionette_common import (
    ActionItemParams,
    MarionetteParams,
    MarionetteProtocol,
    read_samples,
    write_samples,
)
from repro.eval.protocols.multi_action import MultiAction, MultiActionParams, MultiActionSamples
from repro.eval.protocols.single_action import (
    SingleAction,
    SingleActionParams,
    SingleActionSamples,
)
from repro.motion.motion import Motion
from repro.motion.skeleton import Skeleton


class Toy(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    n: int = Field(3, ge=1)
    mode: str = "a"


class Other(BaseModel):
    n: int = 7


# --- repro.config_errors ---------------------------------------------------------------------

def test_resolve_config_reads_none_instances_models_and_mappings():
    assert resolve_config(Toy, None, "toy: field") == Toy()
    t = Toy(n=2)
    assert resolve_config(Toy, t, "toy: field") is t
    assert resolve_config(Toy, Other(), "toy: field") == Toy(n=7)
    assert resolve_config(Toy, {"mode": "b"}, "toy: field") == Toy(mode="b")


def test_resolve_config_names_the_first_bad_field_in_the_callers_words():
    with pytest.raises(ConfigError) as e:
        resolve_config(Toy, {"n": 0}, "toy: field")
    assert str(e.value) == "toy: field 'n': Input should be greater than or equal to 1"
    with pytest.raises(ConfigError) as e:
        resolve_config(Toy, {"nn": 1}, "where:", quote=False)
    assert str(e.value) == "where: nn: Extra inputs are not permitted"
    with pytest.raises(ConfigError) as e:  # the cause is not chained into the traceback
        resolve_config(Toy, {"n": "x"}, "toy: field")
    assert e.value.__cause__ is None and e.value.__suppress_context__


def test_type_errors_are_bad_input_only_where_the_caller_says_so():
    with pytest.raises(TypeError):
        resolve_config(Toy, [1, 2], "toy: field")
    with pytest.raises(ConfigError, match=r"^toy config: "):
        resolve_config(Toy, [1, 2], "toy: field", type_lead="toy config")


def test_a_problem_without_a_location_gets_the_unnamed_word():
    from pydantic import model_validator

    class Whole(BaseModel):
        a: int = 1

        @model_validator(mode="after")
        def _check(self):
            if self.a > 5:
                raise ValueError("a too large")
            return self

    try:
        Whole(a=9)
    except Exception as e:  # noqa: BLE001 (the ValidationError itself is under test)
        err = e
    assert first_problem(err) == ("?", "Value error, a too large")
    assert str(config_error(err, "w:", unnamed="parameters", quote=False)) == \
        "w: parameters: Value error, a too large"


def test_the_three_callers_keep_their_wording():
    with pytest.raises(ConfigError) as e:
        ItemsConfig.resolve({"n_init": 0})
    assert str(e.value) == "items config: field 'n_init': Value error, must be >= 1"
    with pytest.raises(ConfigError) as e:
        get_protocol("multi_action", {"initial_frames": 0})
    assert str(e.value) == ("protocol 'multi_action': parameter 'initial_frames': Input should "
                            "be greater than or equal to 1")
    from repro.models.base import generator_class

    with pytest.raises(ConfigError) as e:
        generator_class("marionet").Config.resolve({"zzz": 1}, where="method 'marionet'")
    assert str(e.value) == "method 'marionet': MarioNetConfig field 'zzz': Extra inputs are not permitted"


# --- one params base, one data path ----------------------------------------------------------

SHARED = ("initial_frames", "fps", "test_fraction", "test_cap_per_class", "split", "split_seed",
          "context", "compose", "max_frames", "replicates", "eval_clip", "fid_method",
          "memorisation", "prdc_k")


def test_both_protocols_take_the_shared_fields_from_one_base():
    assert set(SHARED) == set(MarionetteParams.model_fields)
    assert set(ActionItemParams.model_fields) < set(MarionetteParams.model_fields)
    for cls in (SingleActionParams, MultiActionParams):
        assert issubclass(cls, MarionetteParams)
        own = set(vars(cls).get("__annotations__", {}))
        assert not own & set(SHARED), (cls.__name__, own & set(SHARED))
    s, m = SingleActionParams(), MultiActionParams()
    assert {k: getattr(s, k) for k in SHARED} == {k: getattr(m, k) for k in SHARED}
    # the keyed contents: every field but replicates, as before
    assert "replicates" not in s.describe() and set(s.describe()) == \
        set(SingleActionParams.model_fields) - {"replicates"}
    assert s.describe()["eval_clip"] == "centre" and m.describe()["prdc_k"] == 5


def test_both_protocols_share_one_data_path():
    for cls in (SingleAction, MultiAction):
        assert issubclass(cls, MarionetteProtocol)
        for name in ("item_source", "split_clipset", "train_items", "_encode"):
            assert name not in vars(cls), (cls.__name__, name)
    s = get_protocol("single_action", {"max_frames": 90, "split_seed": 3})
    m = get_protocol("ss_ar", {"max_frames": 90, "split_seed": 3})
    assert s.item_source() == m.item_source() and s.item_source().max_frames == 90
    assert s.items_config() == m.items_config()


def test_evaluation_clips_is_still_importable_from_single_action():
    from repro.eval.protocols import marionette_common, single_action

    assert single_action.evaluation_clips is marionette_common.evaluation_clips


# --- one sample-file reader/writer -----------------------------------------------------------

def _skeleton() -> Skeleton:
    from repro.data.registry import load_clipset

    return load_clipset("bandai2-mini").skeleton


def _items(sk, scale=1.0):
    g = torch.Generator().manual_seed(3)
    N, T = 6, 9
    m = Motion(scale * torch.randn(N, T, 3, generator=g),
               torch.randn(N, T, sk.n_joints, 6, generator=g), sk, 30.0)
    return m, torch.tensor([9, 5, 7, 9, 3, 8]), torch.tensor([0, 1, 2, 0, 1, 2])


def _explicit_npz(meta: dict, arrays: dict) -> bytes:
    """The layout the protocols wrote before the shared writer, spelled out."""
    buf = io.BytesIO()
    np.savez_compressed(buf, meta=np.array(json.dumps(meta, sort_keys=True)), **arrays)
    return buf.getvalue()


def _arrays(g, prefix=""):
    return {prefix + "root": g.motion.root.numpy(), prefix + "rot6d": g.motion.rot6d.numpy(),
            prefix + "lengths": g.lengths.numpy().astype(np.int64),
            prefix + "labels": g.labels.numpy().astype(np.int64)}


def test_single_action_files_are_the_bytes_they_were(tmp_path):
    sk = _skeleton()
    m, lens, labels = _items(sk)
    ref = GeneratedItems(_items(sk, 2.0)[0], lens, labels)
    gen = SingleActionSamples(m, lens, labels, reference=ref, jpe_mode="mean")
    proto = get_protocol("single_action")
    path = proto.save_generated(gen, tmp_path / "s.npz")
    meta = {"format": 1, "protocol": "single_action", "skeleton": sk.to_dict(), "fps": 30.0,
            "jpe_mode": "mean", "has_reference": True}
    assert path.read_bytes() == _explicit_npz(meta, {**_arrays(gen), **_arrays(ref, "ref_")})
    back = proto.load_generated(path)
    assert torch.equal(back.reference.motion.root, ref.motion.root) and back.jpe_mode == "mean"
    plain = proto.load_generated(proto.save_generated(GeneratedItems(m, lens, labels),
                                                      tmp_path / "p.npz"))
    assert plain.reference is None and plain.jpe_mode == "sampled"


def test_multi_action_files_are_the_bytes_they_were(tmp_path):
    sk = _skeleton()
    m, lens, labels = _items(sk)
    rev = torch.tensor([1, 0, 0, 1, 0, 1], dtype=torch.bool)
    gen = MultiActionSamples(m, lens, labels, n_sequences=2, n_actions=3, revised=rev,
                             test_set_key="k")
    proto = get_protocol("multi_action")
    path = proto.save_generated(gen, tmp_path / "m.npz")
    meta = {"format": 1, "protocol": "multi_action", "skeleton": sk.to_dict(), "fps": 30.0,
            "n_sequences": 2, "n_actions": 3, "test_set": "k"}
    assert path.read_bytes() == _explicit_npz(meta, {**_arrays(gen), "revised": rev.numpy()})
    back = proto.load_generated(path)
    assert torch.equal(back.revised, rev) and (back.n_sequences, back.n_actions) == (2, 3)
    # a file of the other protocol, or one whose shape does not fit, is refused naming it
    with pytest.raises(DataError, match=r"m\.npz.*expected 1 / 'single_action'"):
        get_protocol("single_action").load_generated(path)
    bad = write_samples(tmp_path / "bad.npz", "multi_action", 1, gen,
                        meta={"n_sequences": 4, "n_actions": 3, "test_set": "k"},
                        arrays={"revised": rev.numpy()})
    with pytest.raises(DataError, match=r"bad\.npz: malformed samples: shapes do not fit"):
        proto.load_generated(bad)


def test_read_samples_gives_every_motion_set_back(tmp_path):
    sk = _skeleton()
    m, lens, labels = _items(sk)
    a, b = GeneratedItems(m, lens, labels), GeneratedItems(_items(sk, 3.0)[0], lens, labels)
    path = write_samples(tmp_path / "x.npz", "proto_x", 4, a, meta={"note": "n"},
                         sets={"b_": b}, arrays={"extra": np.arange(3)})
    f = read_samples(path, "proto_x", 4)
    assert f.meta["note"] == "n" and f.meta["fps"] == 30.0 and f.skeleton == sk
    assert torch.equal(f.motion_set().motion.root, a.motion.root)
    assert torch.equal(f.motion_set("b_").motion.root, b.motion.root)
    assert f.arrays["extra"].tolist() == [0, 1, 2]
    with pytest.raises(DataError, match="expected 5 / 'proto_x'"):
        read_samples(path, "proto_x", 5)
