"""Fixtures shared by the model tests (test_marionet.py, test_baselines.py): one torch thread
for the module, and a small synthetic clip set with its train and test action items.

Import them by name (``from model_fixtures import clips, items, test_items, one_torch_thread``;
``mini_clips`` is the bundled bandai2-mini);
``one_torch_thread`` is autouse, so importing it is enough."""

from __future__ import annotations

import pytest
import torch

from repro.data.clipset import TEST, TRAIN
from test_items import synthetic_clipset
from repro.data.contexts import build_items


@pytest.fixture(autouse=True, scope="module")
def one_torch_thread():
    """Tiny ops: thread hand-offs cost more than they save; the caller's count is restored."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="module")
def clips():
    return synthetic_clipset(n_per_class=6, min_len=14, max_len=26)


@pytest.fixture(scope="module")
def mini_clips():
    """The bundled bandai2-mini clip set (ODMO's window models and protocols)."""
    from repro.data.registry import load_clipset

    return load_clipset("bandai2-mini")


@pytest.fixture(scope="module")
def items(clips):
    return build_items(clips, TRAIN)


@pytest.fixture(scope="module")
def test_items(clips):
    return build_items(clips, TEST)


def assert_resume_is_exact(full, make, items, ckpt_dir, seed: int) -> None:
    """A training of ``make()`` on ``items`` with ``seed`` killed after its first epoch (by
    ``on_epoch``, which runs before that epoch's checkpoint) and resumed from ``ckpt_dir`` ends
    with the weights of ``full`` (the same training, never interrupted)."""

    class Stop(Exception):
        pass

    def stop(epoch, rec):
        if epoch == 1:
            raise Stop

    with pytest.raises(Stop):
        make().fit(items, seed=seed, ckpt_dir=ckpt_dir, on_epoch=stop)
    resumed = make()
    r = resumed.fit(items, seed=seed, ckpt_dir=ckpt_dir)
    assert r.resumed_from == 1
    for (k, v), v2 in zip(full.network.state_dict().items(), resumed.network.state_dict().values()):
        assert torch.equal(v, v2), k
