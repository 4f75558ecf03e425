"""One family of item sources (issue 30): Neural Marionette's actions, MultiAct's pairs and
ODMO's windows specialise one base in the data layer, and every table protocol's parameters one
base that maps its item fields onto it."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

import repro
from repro.data.action_items import ActionItems
from repro.data.clip_draws import balanced_clips
from repro.data.contexts import ActionSource
from repro.data.item_families import FAMILIES, source_from_description
from repro.data.item_sources import ItemSet, ItemSource
from repro.data.odmo_items import WindowItems, WindowSource
from repro.data.pairs import PairItems
from repro.data.pairs_build import PairSource
from repro.errors import ConfigError, DataError
from repro.eval.protocols import get_protocol
from repro.eval.protocols.base import ItemParams, ItemProtocol

SOURCES = [ActionSource(), ActionSource(context="same_clip", max_frames=90),
           PairSource(train_per_label=7), WindowSource(window=30)]
PROTOCOLS = {"single_action": ActionSource, "multi_action": ActionSource, "ss_ar": ActionSource,
             "multiact_conditioned": PairSource, "transition": PairSource,
             "long_term": PairSource, "odmo_generation": WindowSource,
             "latent_modes": WindowSource, "trajectory_customisation": WindowSource}


@pytest.mark.parametrize("src", SOURCES, ids=lambda s: f"{type(s).__name__}")
def test_every_family_is_one_item_source(src):
    assert isinstance(src, ItemSource)
    d = src.describe()
    assert d[type(src).VERSION_FIELD] == type(src).VERSION
    back = source_from_description(d)
    assert type(back) is type(src) and back.describe() == d and back.key() == src.key()
    with pytest.raises(DataError, match="this code builds"):
        type(src).from_description({**d, type(src).VERSION_FIELD: type(src).VERSION + 1})
    # without its version field: the current version where descriptions predate the field
    # (single actions, pairs); refused for ODMO's windows, which always wrote it
    bare = {k: v for k, v in d.items() if k != type(src).VERSION_FIELD}
    if type(src).VERSION_MAY_BE_ABSENT:
        assert type(src).from_description(bare).key() == src.key()
    else:
        with pytest.raises(DataError, match="described by version None"):
            type(src).from_description(bare)


def test_descriptions_keep_their_fields_and_version_names():
    # the training keys of issue 26/27 hash these descriptions: the fields and the version
    # names are the ones each family always wrote
    assert set(ActionSource().describe()) == {
        "context", "fps", "split", "split_seed", "test_fraction", "test_cap_per_class",
        "n_init", "max_frames", "compose", "context_version"}
    assert "compose" not in ActionSource(context="same_clip").describe()
    assert PairSource().describe()["pairs_version"] == 1
    assert PairSource().describe()["compose"]["blend_frames"] == 30  # resolved composition
    assert WindowSource().describe()["version"] == 2
    assert {ActionSource.VERSION_FIELD, PairSource.VERSION_FIELD,
            WindowSource.VERSION_FIELD} == {"context_version", "pairs_version", "version"}


def test_an_unknown_builder_is_one_data_error():
    with pytest.raises(DataError, match="unknown builder 'nope'"):
        source_from_description({"builder": "nope"})
    assert FAMILIES[None] is ActionSource


@pytest.mark.parametrize("cls", [ActionSource, PairSource, WindowSource])
def test_make_names_where_and_the_field(cls):
    with pytest.raises(ConfigError, match=r"^protocol 'x': (\w+\.)*\w+: "):
        cls.make("protocol 'x'", not_a_field=1)


@pytest.mark.parametrize("pid", sorted(PROTOCOLS))
def test_every_protocol_takes_its_items_from_the_one_base(pid):
    proto = get_protocol(pid, {})
    assert isinstance(proto, ItemProtocol) and isinstance(proto.params, ItemParams)
    src = proto.item_source()
    assert type(src) is PROTOCOLS[pid] and src is not None
    # no family repeats the data path: it is ItemProtocol's
    for cls in type(proto).__mro__:
        if cls is ItemProtocol:
            break
        for name in ("item_source", "split_clipset", "train_items"):
            assert name not in vars(cls), (cls.__name__, name)
    # item fields reach the source (a renamed one included), and a bad one names the protocol
    field, src_field, value = {ActionSource: ("initial_frames", "n_init", 4),
                               PairSource: ("pair_seed", "seed", 3),
                               WindowSource: ("window", "window", 40)}[PROTOCOLS[pid]]
    assert getattr(get_protocol(pid, {field: value}).item_source(), src_field) == value


def test_pass_through_item_fields_are_validated_by_the_source():
    p = get_protocol("multiact_conditioned", {"pairs": {"max_prev_frames": 30}})
    assert p.item_source().max_prev_frames == 30
    with pytest.raises(ConfigError, match="protocol 'odmo_generation': seedd"):
        get_protocol("odmo_generation", {"windows": {"seedd": 1}}).item_source()


@pytest.fixture(scope="module")
def clips():
    from repro.data.registry import load_clipset

    return load_clipset("bandai2-mini")


def test_training_items_by_item_kind(clips):
    pairs = PairSource()
    assert isinstance(pairs.training_items(clips, "pairs"), PairItems)
    acts = pairs.training_items(clips, "actions")
    assert isinstance(acts, ActionItems)
    assert acts.key() == pairs.train_items(clips).as_action_items().key()
    win = WindowSource()
    assert isinstance(win.training_items(clips, "windows"), WindowItems)
    assert isinstance(win.training_items(clips, "actions"), ActionItems)
    with pytest.raises(ConfigError, match="trains on pairs cannot train on the windows"):
        win.training_items(clips, "pairs")


def test_item_containers_answer_alike(clips):
    pool = WindowSource().train_items(clips)
    pairs = PairSource().train_items(clips)
    for items in (pool, pairs, pairs.as_action_items(), pool.as_action_items()):
        assert isinstance(items, ItemSet)
        assert items.skeleton == clips.skeleton
        assert items.n_classes == clips.n_classes == len(items.label_names)
    assert pool.fps == float(clips.fps) and pairs.fps == 20.0


def test_class_balanced_recipes_draw_the_same_distribution(clips):
    pool = clips.indices()
    labels = clips.labels
    for recipe in ("weights", "class_first"):
        got = balanced_clips(clips, pool, 20000, np.random.default_rng(0), recipe=recipe)
        assert np.isin(got, pool).all()
        share = np.bincount(labels[got], minlength=clips.n_classes) / got.size
        present = np.unique(labels[pool])
        assert np.allclose(share[present], 1 / present.size, atol=0.02), recipe
    with pytest.raises(ValueError, match="recipe"):
        balanced_clips(clips, pool, 3, np.random.default_rng(0), recipe="other")


def _imports(path: Path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return out


def test_items_are_built_in_the_data_layer():
    root = Path(repro.__file__).parent
    assert not (root / "models" / "items.py").exists()
    for name in ("item_sources", "item_families", "action_items", "contexts", "pairs",
                 "pairs_build", "odmo_items", "clip_draws"):
        bad = {m for m in _imports(root / "data" / f"{name}.py")
               if m.startswith(("repro.models", "repro.eval", "repro.engine", "repro.train"))}
        assert not bad, (name, bad)
