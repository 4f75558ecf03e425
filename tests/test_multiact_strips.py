"""Strips and export of MultiAct's bands (repro.report.pair_strips, repro.exporters.samples) on
synthetic pairs, fake samples shaped as the protocols save them (MultiActSamples) and a fake
band: panel counts, segment boundaries, the S_p each row shows, every row drawn for the same
item, the long-term chains and their exports."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from test_items import NAMES, OFFSETS, PARENTS

from repro.data.pairs import PairItems, gather_frames
from repro.engine.run_samples import RowSamples
from repro.errors import ConfigError, DataError
from repro.eval.protocols.long_term import LongTermItems
from repro.eval.protocols.multiact_common import MultiActSamples
from repro.eval.protocols.multiact_conditions import anchor_frames
from repro.motion.motion import Motion
from repro.motion.rotations import matrix_to_6d
from repro.motion.skeleton import Skeleton
from repro.report.pair_strips import chain_parts
from repro.report.strip_sets import table_strips

LABELS = ("walk", "wave", "turn", "jump")
SKEL = Skeleton(NAMES, PARENTS, np.array(OFFSETS))
J = len(NAMES)


def _motion(root: torch.Tensor) -> Motion:
    """A rest-pose body following ``root`` (N, T, 3)."""
    rot = matrix_to_6d(torch.eye(3, dtype=root.dtype)).expand(*root.shape[:2], J, 6).clone()
    return Motion(root, rot, SKEL, 20.0)


def _pairs(n: int = 8) -> PairItems:
    """``n`` pairs, item ``i``: root at x = i (so an item is recognisable), walking along z;
    l_p 5 + i % 3, l_t 3 + i % 2, l_c 6 + i % 4; label i % 4, previous label (i + 1) % 4."""
    l_p = torch.tensor([5 + i % 3 for i in range(n)])
    l_t = torch.tensor([3 + i % 2 for i in range(n)])
    l_c = torch.tensor([6 + i % 4 for i in range(n)])
    T = int((l_p + l_t + l_c).max())
    t = torch.arange(T, dtype=torch.float64)
    root = torch.zeros(n, T, 3, dtype=torch.float64)
    root[..., 0] = torch.arange(n, dtype=torch.float64)[:, None]
    root[..., 1] = 0.9
    root[..., 2] = 0.05 * t
    return PairItems(_motion(root), l_p, l_t, l_c, [(i + 1) % 4 for i in range(n)],
                     [i % 4 for i in range(n)], LABELS, source="test")


def _pair_samples(items: PairItems, kind: str) -> MultiActSamples:
    """``real``: a pair generator continuing the real S_p; ``actor_prev``: one continuing a
    generated S_p 10 m away (only its last frame stored, as the anchor); ``label_only``: ACTOR
    (no transition).  Generated frames sit 0.2 m above the real ones (recognisable)."""
    anchor = anchor_frames(items.motion, items.l_p)
    l_t = items.l_t.clone() if kind != "label_only" else torch.zeros_like(items.l_t)
    n = l_t + items.l_c
    m = gather_frames(items.motion, items.l_p + items.l_t - l_t, n)
    root = m.root.clone()
    root[..., 1] += 0.2
    if kind == "actor_prev":
        root[..., 0] += 10.0
        anchor = anchor.replace(root=anchor.root + torch.tensor([10.0, 0.0, 0.0],
                                                                 dtype=anchor.root.dtype))
    return MultiActSamples(m.replace(root=root), l_t, items.l_c.clone(), items.labels.clone(),
                           anchor, transitions=kind != "label_only", items_key=items.key())


def _row(row_id: str, method: str) -> RowSamples:
    return RowSamples(row_id, row_id.upper(), method, 0, 0, 0, "k" * 64)


def _band(protocol_id: str, items, samples: dict, label: str | None = None):
    rows = [_row(r, "m") for r in samples]

    def load(row):
        g = samples[row.row_id]
        if g is None:
            raise DataError("gone")
        return g

    return SimpleNamespace(index=0, protocol_id=protocol_id, label=label or protocol_id,
                           items=items, rows=rows, is_sequence=False, load=load,
                           protocol=SimpleNamespace(params=SimpleNamespace(prev_trim=2)))


def _rs(band):
    return SimpleNamespace(bands=[band], spec=SimpleNamespace(id="multiact/test"),
                           run_id="run0", run_path=None)


def _np(motion: Motion, i: int) -> np.ndarray:
    return motion.select(i).joints()[0].numpy().astype(np.float32)


@pytest.fixture(scope="module")
def items():
    return _pairs()


@pytest.fixture(scope="module")
def pair_band(items):
    return _band("transition", items, {k: _pair_samples(items, k)
                                       for k in ("real", "actor_prev", "label_only")})


# ---------------------------------------------------------------------------------------------
# single step


def test_pair_strips_panels_segments_and_same_item(items, pair_band):
    strips, notes = table_strips(_rs(pair_band), items=3, key_frames=6)
    assert notes == []
    assert len(strips) == 3
    picked = [st.meta["item"] for st in strips]
    assert len({int(items.labels[i]) for i in picked}) == 3     # different S_c labels
    for st in strips:
        i = st.meta["item"]
        lp, lt, lc = int(items.l_p[i]), int(items.l_t[i]), int(items.l_c[i])
        total = lp + lt + lc
        assert [p.label for p in st.panels] == ["Real (test pair)", "REAL", "ACTOR_PREV",
                                                "LABEL_ONLY"]
        assert st.meta["rows"] == ["real", "actor_prev", "label_only"]
        assert all(p.frame_offset == -lp for p in st.panels)
        assert all(len(p.joints) == total for p in st.panels)
        real = _np(items.motion, i)[:total]
        # top: the real [S_p, T, S_c]
        np.testing.assert_allclose(st.panels[0].joints, real, atol=1e-6)
        segs = [(s.start, s.stop, s.transition) for s in st.panels[0].segments]
        assert segs == [(0, lp, None), (lp, lp + lt, (lp, lp + lt)), (lp + lt, total, None)]
        a_p, a_c = LABELS[(i + 1) % 4], LABELS[i % 4]
        assert [s.tag for s in st.panels[0].segments] == [f"previous: {a_p}", "transition", a_c]
        assert st.title.startswith(f"transition: test pair {i}: {a_p} > {a_c}, S_p {lp} + T "
                                   f"{lt} + S_c {lc} frames")
        # the row that used the real S_p: it, then its own [T̂, Ŝ_c] of the same item
        p = st.panels[1]
        np.testing.assert_allclose(p.joints[:lp], real[:lp], atol=1e-6)
        gen = _np(pair_band.load(SimpleNamespace(row_id="real")).motion, i)
        np.testing.assert_allclose(p.joints[lp:], gen[:lt + lc], atol=1e-6)
        np.testing.assert_allclose(p.joints[lp:, 0, 1] - real[lp:, 0, 1], 0.2, atol=1e-6)
        assert [(s.start, s.stop) for s in p.segments] == [(0, lp), (lp, lp + lt),
                                                           (lp + lt, total)]
        assert st.meta["prev"]["real"] == "real"
        # a generated S_p (not stored): its last frame held over the S_p frames, said so
        p = st.panels[2]
        g = pair_band.load(SimpleNamespace(row_id="actor_prev"))
        anchor = _np(g.anchor, i)[0]
        np.testing.assert_allclose(p.joints[:lp], np.repeat(anchor[None], lp, 0), atol=1e-6)
        assert np.allclose(p.joints[lp:, 0, 0], i + 10.0)
        assert "not stored" in p.segments[0].tag and "not stored" in p.tag
        assert st.meta["prev"]["actor_prev"].startswith("generated")
        assert "generated S_p not stored" in st.title
        # label only: real S_p, then Ŝ_c at once; no transition segment drawn; held to the end
        p = st.panels[3]
        np.testing.assert_allclose(p.joints[:lp], real[:lp], atol=1e-6)
        np.testing.assert_allclose(p.joints[lp:lp + lc], _np(
            pair_band.load(SimpleNamespace(row_id="label_only")).motion, i)[:lc], atol=1e-6)
        np.testing.assert_allclose(p.joints[lp + lc:], p.joints[lp + lc - 1:lp + lc].repeat(
            lt, 0), atol=1e-6)
        drawn = [(s.start, s.stop) for s in p.segments if s.start < total]
        assert drawn == [(0, lp), (lp, lp + lc)]
        assert p.segments[2].tag == a_c          # same colour index as the other rows' action
        assert "no T" in p.tag and f"held from {lc}" in p.tag
        assert st.meta["row_frames"]["label_only"] == {"transition": 0, "action": lc}
        # key frames: evenly spaced plus the last S_p frame, the first generated frame and
        # the first real S_c frame
        assert {lp - 1, lp, lp + lt, 0, total - 1} <= set(st.frames)
        assert max(st.frames) < total


def test_pair_strips_render(items, pair_band, tmp_path):
    from repro.render.strips import render_strip

    st = table_strips(_rs(pair_band), items=1)[0][0]
    img = render_strip(st.panels, SKEL.parents, SKEL.names, frames=st.frames, top_view=True,
                       title=st.title)
    assert len(img.frames) == len(st.frames)
    assert {k[0] for k in img.boxes} == set(range(4))


def test_pair_strips_notes(items):
    other = _pair_samples(_pairs(9), "real")        # samples of other test items
    band = _band("multiact_conditioned", items, {"real": _pair_samples(items, "real"),
                                                 "other": other, "gone": None})
    strips, notes = table_strips(_rs(band), items=2)
    assert len(strips) == 2 and all(len(st.panels) == 2 for st in strips)
    assert any(n.startswith("other (") and "other test items" in n for n in notes)
    assert any(n.startswith("gone (") and n.endswith(": gone") for n in notes)


# ---------------------------------------------------------------------------------------------
# long term

S, N = 3, 4


def _plan(pairs: PairItems) -> LongTermItems:
    labels = torch.tensor([[(s + x) % 4 for x in range(N)] for s in range(S)])
    l_t = torch.tensor([[0] + [3 + (s + x) % 2 for x in range(1, N)] for s in range(S)])
    l_c = torch.tensor([[7 + (s + x) % 3 for x in range(N)] for s in range(S)])
    prev = torch.zeros(S, N, dtype=torch.long)
    return LongTermItems(pairs, labels, l_t, l_c, prev, torch.full((S,), -1), source="t")


def _chain_samples(plan: LongTermItems, transitions: bool) -> MultiActSamples:
    """Row s·N + x: root x = 100 s + x, z = the frame (the chains are recognisable)."""
    l_t = plan.l_t.reshape(-1) if transitions else torch.zeros(S * N, dtype=torch.long)
    l_c = plan.l_c.reshape(-1)
    W = int((l_t + l_c).max())
    root = torch.zeros(S * N, W, 3, dtype=torch.float64)
    s, x = torch.arange(S * N) // N, torch.arange(S * N) % N
    root[..., 0] = (100 * s + x).double()[:, None]
    root[..., 1] = 0.9
    root[..., 2] = torch.arange(W, dtype=torch.float64)
    m = _motion(root)
    return MultiActSamples(m, l_t, l_c, plan.labels.reshape(-1), m.slice_time(0, 1),
                           transitions=transitions, n_sequences=S, n_steps=N,
                           items_key=plan.key())


@pytest.fixture(scope="module")
def plan(items):
    return _plan(items)


@pytest.fixture(scope="module")
def lt_band(plan):
    return _band("long_term", plan, {"multiact": _chain_samples(plan, True),
                                     "actor": _chain_samples(plan, False)})


def test_chain_parts(plan):
    g = _chain_samples(plan, True)
    parts = chain_parts(g, 1, 3, 2)
    assert [p[0] for p in parts] == [N, N + 1, N + 2]
    assert [p[1] for p in parts] == [int(plan.l_t[1, x]) for x in range(3)]
    assert [p[2] for p in parts] == [int(plan.l_c[1, 0]) - 2, int(plan.l_c[1, 1]) - 2,
                                     int(plan.l_c[1, 2])]


def test_long_term_strips(plan, lt_band):
    strips, notes = table_strips(_rs(lt_band), items=2, max_actions=3)
    assert notes == [] and len(strips) == 2
    for s, st in enumerate(strips):
        assert "no real counterpart (generated from labels)" in st.title
        assert st.meta["sequence"] == s and st.meta["real"] is None
        tags = [LABELS[(s + x) % 4] for x in range(3)]
        assert st.meta["tags"] == tags
        assert [p.label for p in st.panels] == ["MULTIACT", "ACTOR"]   # no real panel
        total = max(len(p.joints) for p in st.panels)
        assert all(len(p.joints) == total for p in st.panels)
        for p, trans in zip(st.panels, (True, False)):
            start = 0
            for x, sg in enumerate(p.segments):
                lt = int(plan.l_t[s, x]) if trans and x else 0
                lc = int(plan.l_c[s, x]) - (2 if x < 2 else 0)
                assert (sg.start, sg.stop, sg.tag) == (start, start + lt + lc, tags[x])
                assert sg.transition == ((start, start + lt) if lt else None)
                # the frames of step x are row s·N + x's, from its first frame on
                np.testing.assert_allclose(p.joints[start:start + lt + lc, 0, 0], 100 * s + x)
                np.testing.assert_allclose(p.joints[start:start + lt + lc, 0, 2],
                                           np.arange(lt + lc), atol=1e-6)
                start += lt + lc
            assert len(p.segments) == 3
        assert st.panels[1].tag.startswith("held from ")
        ref = st.panels[0].segments
        assert {sg.start for sg in ref} <= set(st.frames)
        assert {sg.transition[1] for sg in ref if sg.transition} <= set(st.frames)
        assert ref[-1].stop - 1 in st.frames


def test_long_term_shape_mismatch(plan):
    g = _chain_samples(plan, True)
    bad = MultiActSamples(g.motion, g.l_t, g.l_c, g.labels, g.anchor, n_sequences=N,
                          n_steps=S, items_key=plan.key())
    band = _band("long_term", plan, {"bad": bad})
    strips, notes = table_strips(_rs(band))
    assert strips == [] and "no strips" in notes[0] and "4x3" in notes[0]


# ---------------------------------------------------------------------------------------------
# export


def test_export_pairs_npz_and_bvh(items, pair_band, tmp_path):
    from repro.exporters.samples import export_samples

    rec = export_samples(_rs(pair_band), tmp_path / "npz", row="real", item=2, fmt="npz")
    (f,) = rec["files"]
    lt, lc = int(items.l_t[2]), int(items.l_c[2])
    assert f["file"] == "real-r0-item2.npz"
    assert (f["frames"], f["transition_frames"], f["action_frames"]) == (lt + lc, lt, lc)
    assert (f["tag"], f["prev_tag"]) == (LABELS[2], LABELS[3])
    z = np.load(tmp_path / "npz" / f["file"])
    g = pair_band.load(SimpleNamespace(row_id="real"))
    np.testing.assert_allclose(z["joints"], _np(g.motion, 2)[:lt + lc], atol=1e-5)
    rec = export_samples(_rs(pair_band), tmp_path / "bvh", row="label_only", item=1)
    text = (tmp_path / "bvh" / rec["files"][0]["file"]).read_text()
    assert f"Frames: {int(items.l_c[1])}" in text
    with pytest.raises(ConfigError, match="test pairs are 0..7"):
        export_samples(_rs(pair_band), tmp_path / "bad", item=8)
    assert not (tmp_path / "bad").exists()


def test_export_long_term_chain(plan, lt_band, tmp_path):
    from repro.exporters.samples import export_samples

    rec = export_samples(_rs(lt_band), tmp_path, row="multiact", item=1, fmt="npz")
    (f,) = rec["files"]
    want = [int(plan.l_t[1, x]) + int(plan.l_c[1, x]) - (2 if x < N - 1 else 0)
            for x in range(N)]
    assert f["frames"] == want and f["sequence"] == 1
    assert f["tags"] == [LABELS[(1 + x) % 4] for x in range(N)]
    z = np.load(tmp_path / f["file"])
    assert z["joints"].shape == (sum(want), J, 3)
    assert json.loads(str(z["meta"]))["prev_trim"] == 2
    with pytest.raises(ConfigError, match="label sequences 0..2"):
        export_samples(_rs(lt_band), tmp_path / "bad", item=3)
