"""Accuracy top-1/top-k, confusion matrix, MultiAct label merging."""

import numpy as np
import pytest
import torch

from repro.errors import DataError
from repro.metrics.accuracy import MULTIACT_LABEL_MERGE, MULTIACT_LABELS, accuracy, confusion_matrix


def test_hand_made_confusion():
    labels = np.array([0, 0, 1, 1, 2, 2])
    preds = np.array([0, 1, 1, 1, 2, 0])
    r = accuracy(preds, labels)
    assert (r.correct, r.n) == (4, 6) and r.value == pytest.approx(4 / 6)
    cm = confusion_matrix(preds, labels, 3)
    np.testing.assert_array_equal(cm, [[1, 1, 0], [0, 2, 0], [1, 0, 1]])
    assert np.trace(cm) / cm.sum() == pytest.approx(r.value)


def test_logits_top1_and_top2_and_ties():
    logits = torch.tensor([[0.1, 0.7, 0.2],   # top1 1, top2 {1, 2}
                           [0.5, 0.5, 0.0],   # tie -> class 0 first
                           [0.3, 0.3, 0.4]])  # top1 2, top2 {2, 0}
    labels = [2, 1, 0]
    assert accuracy(logits, labels).correct == 0
    assert accuracy(logits, labels, top_k=2).correct == 3
    np.testing.assert_array_equal(confusion_matrix(logits, labels, 3).sum(0), [1, 1, 1])


def test_multiact_labels_and_merge_table():
    assert len(MULTIACT_LABELS) == 53 == len(set(MULTIACT_LABELS))
    idx = {n: i for i, n in enumerate(MULTIACT_LABELS)}
    imap = MULTIACT_LABEL_MERGE.index_map()
    assert "pickup" in MULTIACT_LABEL_MERGE.accepts and "pickup" not in idx  # dead key kept as data
    assert idx["pick up"] not in imap  # 'pick up' needs an exact match
    assert imap[idx["pick up object"]] == {idx["pick up object"], idx["pick something up with right hand"]}
    assert idx["turn left"] not in imap[idx["turn right"]]
    assert idx["turn right"] not in imap[idx["turn left"]]
    assert idx["sit"] not in imap  # 'sit' is not a key


@pytest.mark.parametrize("gt, pred, ok", [
    ("turn left", "turn", True),
    ("turn right", "turn left", False),
    ("turn right", "turn back", True),
    ("sit down", "sit", True),
    ("sit", "sit down", False),
    ("pick up object", "pick something up with right hand", True),
    ("pick up", "pick up object", False),
    ("walk forward", "walk backwards", False),
    ("walk", "walk backwards", True),
    ("jog", "run", True),
    ("stop", "look down", True),
    ("take", "take", True),
])
def test_multiact_merged_accuracy(gt, pred, ok):
    idx = {n: i for i, n in enumerate(MULTIACT_LABELS)}
    r = accuracy(np.array([idx[pred]]), np.array([idx[gt]]), merge=MULTIACT_LABEL_MERGE)
    assert r.correct == int(ok)
    assert accuracy(np.array([idx[pred]]), np.array([idx[gt]])).correct == int(gt == pred)


def test_top5_with_merging_counts_any_qualifying_prediction():
    idx = {n: i for i, n in enumerate(MULTIACT_LABELS)}
    logits = np.zeros((1, 53))
    for rank, name in enumerate(["kick", "jump", "squat", "crouch", "turn back", "turn right"]):
        logits[0, idx[name]] = 10.0 - rank  # 'turn back' is 5th, 'turn right' 6th
    gt = np.array([idx["turn right"]])
    assert accuracy(logits, gt, top_k=5).correct == 0
    assert accuracy(logits, gt, top_k=5, merge=MULTIACT_LABEL_MERGE).correct == 1
    assert accuracy(logits, gt, top_k=1, merge=MULTIACT_LABEL_MERGE).correct == 0


def test_index_merge_mapping_and_errors():
    r = accuracy(np.array([1, 0]), np.array([0, 0]), merge={0: [0, 1]})
    assert r.correct == 2
    with pytest.raises(DataError):
        accuracy(np.array([0, 1]), np.array([0]))
    with pytest.raises(DataError, match="top_k"):
        accuracy(np.array([0, 1]), np.array([0, 1]), top_k=2)
    with pytest.raises(DataError, match="class indices"):
        confusion_matrix(np.array([0, 3]), np.array([0, 1]), 3)
