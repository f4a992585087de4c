"""The benchmark's peers (oneshot/benchmark/peers.py) do the same work as ours: the same meta-objective
and the same second-order meta-gradient, in PyTorch and in JAX, on a small network. Skipped where the
peer is not installed (it is an optional extra: pip install -e .[peers])."""
import numpy as np
import pytest

from oneshot.benchmark import peers
from oneshot.maml import batched, imitation
from oneshot.maml.inner import InnerLoop
from oneshot.policy import network


@pytest.mark.parametrize("peer", sorted(peers.PEERS))
@pytest.mark.parametrize("options, inner", [
    ({}, InnerLoop(alpha=0.01, steps=2)),
    ({"feature_points": True, "bias_transform": 3}, InnerLoop(alpha=0.05, steps=1, only=("conv0_",))),
    ({}, InnerLoop(alpha=0.01, steps=1, first_order=True))], ids=["flat", "points", "first-order"])
def test_peer_meta_gradient_equals_ours(peer, options, inner):
    pytest.importorskip(peer)
    cfg = network.NetworkConfig(image_size=8, channels=(3, 4), hidden=(5, 4), **options)
    rng = np.random.default_rng(0)
    params = network.init_params(cfg, rng)
    demos = [(rng.random((2, 3, 8, 8, 3), dtype=np.float32), rng.standard_normal((2, 3, 6), dtype=np.float32),
              rng.standard_normal((2, 3, 2), dtype=np.float32)) for _ in range(2)]
    value, grads = batched.meta_gradient_batched(params, *demos, imitation.imitation_loss, inner)
    peer_value, peer_grads = peers.meta_gradient(peer, cfg, inner)(params, *demos)
    assert peer_value == pytest.approx(float(value), rel=1e-5)
    assert set(peer_grads) == set(grads)
    for k in grads:
        np.testing.assert_allclose(peer_grads[k], grads[k], rtol=2e-4, atol=2e-5 * np.abs(grads[k]).max(), err_msg=k)


def test_a_missing_peer_is_named_with_what_to_install(monkeypatch):
    monkeypatch.setattr(peers, "available", lambda peer: False)
    with pytest.raises(ValueError, match=r"PyTorch is not installed.*pip install"):
        peers.require("torch")


@pytest.mark.parametrize("options, inner, named", [
    ({}, InnerLoop(clip=20.0), "inner clip"), ({}, InnerLoop(loss_scale=250.0), "loss scale"),
    ({}, InnerLoop(frozen=("ln",)), "never adapt"), ({"layer_norm": True}, InnerLoop(), "layer norm")])
def test_what_the_peers_do_not_do_is_refused_not_left_out(monkeypatch, options, inner, named):
    monkeypatch.setattr(peers, "available", lambda peer: True)      # refused before the peer is imported
    cfg = network.NetworkConfig(image_size=8, channels=(3, 4), hidden=(5, 4), **options)
    with pytest.raises(ValueError, match=named):
        peers.meta_gradient("torch", cfg, inner)
