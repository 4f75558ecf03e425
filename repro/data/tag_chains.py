"""Tag chains of Neural Marionette's multi-action test sets (supp. §4.2): which test
action sits at each position of each test sequence, and the next tag it is conditioned on.

Each sequence starts from an action candidate (a seeded choice of ``sequences`` of them, or
every candidate once); each next tag is drawn uniformly among the tags connected to the current
one in training (``"overall"``), or among the top ``sufficient_top_k`` connected tags, the
current tag and the current action's own next tag (``"sufficient"``), restricted to tags that
have a candidate; the action is a uniform draw among that tag's candidates.  Everything is
drawn from ``test_set_seed``, so every method and replicate scores the same set.
"""

from __future__ import annotations

import numpy as np

from repro.seeding import numpy_rng


def draw_test_sequences(labels: np.ndarray, own_next: np.ndarray, cand: np.ndarray,
                        counts: np.ndarray, C: int, p, protocol_id: str
                        ) -> tuple[np.ndarray, np.ndarray]:
    """``(actions (S, L), next_labels (S, L))``: positions in the test items and the next tag
    each is conditioned on (module docstring); ``labels``/``own_next`` of the test items,
    ``cand`` the candidate positions, ``counts`` (C, C) training tag-pair counts, ``p`` the
    protocol's parameters, ``protocol_id`` the seed namespace."""
    by_tag = {c: cand[labels[cand] == c] for c in range(C)}
    has = np.array([by_tag[c].size > 0 for c in range(C)])
    # the caller passes MultiAction.id: Table 5 (ss_ar) scores the same overall set as Table 3;
    # the first actions do not depend on the set either (overall and sufficient start alike)
    first_rng = numpy_rng(p.test_set_seed, protocol_id, "first_actions")
    rng = numpy_rng(p.test_set_seed, protocol_id, "test_set", p.test_set)
    S = cand.size if p.sequences is None else p.sequences
    if S <= cand.size:
        first = np.sort(first_rng.choice(cand, size=S, replace=False))
    else:  # more sequences than candidates: every candidate once, the rest drawn again
        first = np.concatenate([cand, first_rng.choice(cand, size=S - cand.size,
                                                       replace=True)])
    L = p.actions_per_sequence
    acts = np.empty((S, L), np.int64)
    acts[:, 0] = first
    for s in range(S):
        for i in range(1, L):
            cur = acts[s, i - 1]
            tag = labels[cur]
            connected = np.flatnonzero(counts[tag] > 0)
            if p.test_set == "overall":
                options = connected
            else:
                order = connected[np.argsort(-counts[tag, connected], kind="stable")]
                options = np.unique(np.concatenate(
                    [order[:p.sufficient_top_k], [tag], [own_next[cur]]]).astype(np.int64))
            options = options[(options >= 0) & has[options]] if options.size else options
            if options.size == 0:
                options = np.array([tag])
            nxt = int(rng.choice(options))
            acts[s, i] = int(rng.choice(by_tag[nxt]))
    nl = np.empty_like(acts)
    nl[:, :-1] = labels[acts[:, 1:]]
    nl[:, -1] = labels[acts[:, -1]] if p.last_next_tag == "same" else own_next[acts[:, -1]]
    return acts, nl


def chain_labels(labels: np.ndarray, acts: np.ndarray) -> np.ndarray:
    """Tags (S, L) of the actions ``acts`` (positions into ``labels``)."""
    return np.asarray(labels, np.int64)[np.asarray(acts, np.int64)]


def test_set_stats(tags: np.ndarray, counts: np.ndarray, C: int) -> dict:
    """What a test set holds (issue 26; supp. §4.2): over the tag chains ``tags`` (S, L) and
    the training tag-pair ``counts`` (C, C):

    - ``unseen_share``: share of the chains' transitions (tag i → tag i+1) whose training
      count is 0;
    - ``median_support``: median training count of those transitions;
    - ``class_share_by_position``: (L, C) share of the chains whose action at position x has
      each class (rows sum to 1);
    - ``self_share``: share of the transitions that repeat the tag (a composer that made every
      tag its own favourite successor would show here).
    """
    tags = np.asarray(tags, np.int64)
    counts = np.asarray(counts, np.int64)
    if tags.ndim != 2 or tags.shape[0] == 0:
        raise ValueError("tags must be a non-empty (S, L) array")
    S, L = tags.shape
    support = counts[tags[:, :-1], tags[:, 1:]].reshape(-1)
    repeat = (tags[:, :-1] == tags[:, 1:]).reshape(-1)
    share = np.stack([np.bincount(tags[:, x], minlength=C)[:C] / S for x in range(L)])
    return {
        "chains": int(S), "length": int(L),
        "unseen_share": round(float((support == 0).mean()), 4) if support.size else None,
        "median_support": float(np.median(support)) if support.size else None,
        "self_share": round(float(repeat.mean()), 4) if repeat.size else None,
        "class_share_by_position": np.round(share, 4).tolist(),
    }

