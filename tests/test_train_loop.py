"""The shared training loop: determinism, exact resume after a kill, config guard."""

import torch

from repro.train import linear_ramp, train


def _setup(seed=0):
    torch.manual_seed(123)
    model = torch.nn.Sequential(torch.nn.Linear(4, 8), torch.nn.Dropout(0.2), torch.nn.Linear(8, 1))
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    X = torch.linspace(-1, 1, 64 * 4).reshape(64, 4)
    y = X.sum(1, keepdim=True) ** 2

    def batches(epoch, gen):
        perm = torch.randperm(64, generator=gen)
        for i in range(0, 64, 16):
            idx = perm[i:i + 16]
            yield X[idx], y[idx]

    def step(m, batch, epoch):
        xb, yb = batch
        loss = torch.nn.functional.mse_loss(m(xb), yb)
        return {"loss": loss}

    return model, opt, batches, step


def _weights(m):
    return torch.cat([p.detach().flatten() for p in m.parameters()])


def test_same_seed_same_weights_and_resume_is_exact(tmp_path):
    cfg = {"what": "toy regression", "lr": 1e-2}
    m1, o1, b, s = _setup()
    train(m1, o1, batches=b, step=s, epochs=6, seed=7, config=cfg)
    m2, o2, b, s = _setup()
    train(m2, o2, batches=b, step=s, epochs=6, seed=7, config=cfg)
    assert torch.equal(_weights(m1), _weights(m2))

    # "killed" after 3 epochs (checkpoint written), then the same command again
    m3, o3, b, s = _setup()
    train(m3, o3, batches=b, step=s, epochs=3, seed=7, config=cfg, ckpt_dir=tmp_path)
    m4, o4, b, s = _setup()
    res = train(m4, o4, batches=b, step=s, epochs=6, seed=7, config=cfg, ckpt_dir=tmp_path)
    assert res.resumed_from == 3
    assert len(res.history) == 6
    assert torch.equal(_weights(m4), _weights(m1))

    m5, o5, b, s = _setup()
    train(m5, o5, batches=b, step=s, epochs=6, seed=8, config=cfg)
    assert not torch.equal(_weights(m5), _weights(m1))


def test_checkpoint_with_other_config_is_not_resumed(tmp_path):
    m, o, b, s = _setup()
    train(m, o, batches=b, step=s, epochs=2, seed=1, config={"lr": 1}, ckpt_dir=tmp_path)
    m, o, b, s = _setup()
    res = train(m, o, batches=b, step=s, epochs=2, seed=1, config={"lr": 2}, ckpt_dir=tmp_path)
    assert res.resumed_from is None


def test_linear_ramp():
    assert linear_ramp(0, 250, 750) == 0.0
    assert linear_ramp(500, 250, 750) == 0.5
    assert linear_ramp(1000, 250, 750) == 1.0
    assert abs(linear_ramp(2000, 0, 4000, 1.0, 0.3) - 0.65) < 1e-12
