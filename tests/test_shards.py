"""Frame shards: several processes computing one second-order meta-gradient (oneshot.maml.shards)."""
import dataclasses
import os
import select
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from autograd.test_util import check_grads

from oneshot import methods
from oneshot.maml import batched, imitation, shards
from oneshot.policy import network
from oneshot.training import config


def _setup(rng, dtype=np.float64, T=4, B=5, **overrides):
    """A small network (float64: sums in another order then differ by ~1e-16), a meta-batch, and the
    inner-loop settings of the default profile with `overrides`."""
    cfg = dataclasses.replace(config.PROFILES["default"], **overrides)
    net_cfg = network.NetworkConfig(image_size=8, channels=(3, 4), hidden=(5,), bias_transform=2,
                                    feature_points=cfg.feature_points)
    params = network.init_params(net_cfg, rng, dtype)

    def demos():
        return (rng.random((B, T, 8, 8, 3)).astype(dtype), rng.normal(size=(B, T, 6)).astype(dtype),
                rng.normal(size=(B, T, 2)).astype(dtype))

    settings = (imitation.imitation_loss, methods.mil.inner_loop(cfg))
    return settings, params, demos(), demos()


@pytest.mark.parametrize("profile, shard_count", [
    (dict(), 2),                                                                 # default: conv0, 1 step
    (dict(inner_params="all", inner_steps=3, alpha=0.01, feature_points=False), 2),   # MIL's inner loop
    (dict(inner_params="all", inner_steps=2, alpha=0.01), 3),                    # three processes
    (dict(first_order=True, inner_params="all", inner_steps=2), 2),
])
def test_frame_shards_give_the_meta_gradient_of_one_process(rng, profile, shard_count):
    """The second-order meta-gradient does not depend on how the frames are split between processes:
    eq. (1)'s inner gradient is summed across them (`allreduce`) and so is its VJP."""
    settings, params, adapt, evaluate = _setup(rng, **profile)
    one = shards.meta_gradient(params, adapt, evaluate, settings)
    with shards.make_pool(shard_count) as pool:
        split = shards.meta_gradient(params, adapt, evaluate, settings, shard_count, pool)
        again = shards.meta_gradient(params, adapt, evaluate, settings, shard_count, pool)
    assert split[0] == pytest.approx(float(one[0]), rel=1e-12)
    for k in params:
        np.testing.assert_allclose(split[1][k], one[1][k], rtol=1e-10, atol=1e-13, err_msg=k)
        assert np.array_equal(split[1][k], again[1][k]), k                        # the same bits every time
        assert split[1][k].dtype == params[k].dtype
    moved = {k: v for k, v in one[1].items() if np.any(v != 0)}
    assert "conv0_w" in moved and "fc0_w" in moved                                # a real gradient


def test_float32_frame_shards_are_close_to_one_process(rng):
    settings, params, adapt, evaluate = _setup(rng, np.float32, T=20)
    one = shards.meta_gradient(params, adapt, evaluate, settings)
    with shards.make_pool(2) as pool:
        split = shards.meta_gradient(params, adapt, evaluate, settings, 2, pool)
    for k in params:          # float32 sums in another order: error relative to the array's largest entry
        scale = max(1.0, float(np.abs(one[1][k]).max()))
        np.testing.assert_allclose(split[1][k], one[1][k], rtol=1e-4, atol=1e-6 * scale)
        assert split[1][k].dtype == np.float32


class _Twice:
    """Stands in for an Exchange of two processes holding the same x: the sum is 2 x."""

    def sum(self, x):
        return 2 * np.asarray(x)


def test_allreduce_is_its_own_vjp_to_second_order(rng):
    f = lambda x: np.sum(np.sin(shards.allreduce(x * x, _Twice())))
    check_grads(f, modes=["rev"], order=2)(rng.normal(size=(3, 4)))


@pytest.mark.parametrize("how, message", [("raise", "(?s)shard process 0 failed.*boom in the worker"),
                                          ("exit", "shard process 0 died during a meta-gradient")])
def test_a_failing_worker_is_reported_and_the_pool_recovers(rng, monkeypatch, how, message):
    settings, params, adapt, evaluate = _setup(rng)
    real, here = batched.meta_gradient_batched, os.getpid()

    def fails_in_workers(*args, **kwargs):
        if os.getpid() != here:
            if how == "exit":
                os._exit(3)                  # killed mid-computation: the others are waiting for it
            raise FloatingPointError("boom in the worker")
        return real(*args, **kwargs)

    expected = shards.meta_gradient(params, adapt, evaluate, settings)
    with shards.make_pool(2) as pool:
        monkeypatch.setattr(batched, "meta_gradient_batched", fails_in_workers)   # forked with the workers
        with pytest.raises(shards.ShardError, match=message):
            shards.meta_gradient(params, adapt, evaluate, settings, 2, pool)
        monkeypatch.setattr(batched, "meta_gradient_batched", real)
        value, grads = shards.meta_gradient(params, adapt, evaluate, settings, 2, pool)   # new workers
    assert value == pytest.approx(float(expected[0]), rel=1e-12)


def test_a_dead_worker_is_reported_instead_of_waited_for(rng):
    settings, params, adapt, evaluate = _setup(rng)
    with shards.make_pool(2) as pool:
        shards.meta_gradient(params, adapt, evaluate, settings, 2, pool)
        pool.workers[0][0].kill()
        pool.workers[0][0].join()
        with pytest.raises(shards.ShardError, match="shard process 0 died"):
            shards.meta_gradient(params, adapt, evaluate, settings, 2, pool)
        value, _ = shards.meta_gradient(params, adapt, evaluate, settings, 2, pool)        # new workers
    assert np.isfinite(value)


def test_bad_settings_name_the_fix(rng):
    settings, params, adapt, evaluate = _setup(rng, T=4)
    with pytest.raises(ValueError, match="needs a pool"):
        shards.meta_gradient(params, adapt, evaluate, settings, 2)
    with pytest.raises(ValueError, match="cannot split demos of 4 frames into 5"):
        shards.split_frames(adapt, 5)
    with pytest.raises(ValueError, match="shards >= 2"):
        shards.Pool(1)
    with pytest.raises(ValueError, match="an int >= 1; got 0"):
        shards.make_pool(0)
    assert [d[0].shape[1] for d in shards.split_frames(adapt, 3)] == [1, 1, 2]


WORKER_SCRIPT = """
import sys, time
import numpy as np
sys.path.insert(0, {tests!r})
from test_shards import _setup
from oneshot.maml import shards
settings, params, adapt, evaluate = _setup(np.random.default_rng(0))
pool = shards.make_pool(2)
shards.meta_gradient(params, adapt, evaluate, settings, 2, pool)
print(pool.workers[0][0].pid, flush=True)
time.sleep(600)
"""


@pytest.mark.parametrize("how", ["SIGKILL", "SIGTERM"])
def test_shard_workers_die_with_the_training_process(how):
    """Killing the training process (kill -9, or a plain kill) ends its shard workers too, rather than
    leaving them reparented and blocked (issue case 2)."""
    script = WORKER_SCRIPT.format(tests=os.path.dirname(os.path.abspath(__file__)))
    parent = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    worker = None
    try:
        if not select.select([parent.stdout], [], [], 300)[0]:
            pytest.fail("the shard pool did not start within 300 s")
        worker = int(parent.stdout.readline())
        assert os.path.exists(f"/proc/{worker}") or not os.path.exists("/proc")
        parent.send_signal(getattr(signal, how))
        parent.wait(30)
        deadline = time.monotonic() + 10
        while _alive(worker) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive(worker), f"shard worker {worker} outlived its parent"
    finally:
        parent.kill()
        if worker is not None and _alive(worker):          # the test failed: leave nothing behind
            os.kill(worker, signal.SIGKILL)


def _alive(pid):
    """Whether process `pid` exists and is not a zombie."""
    try:
        with open(f"/proc/{pid}/status") as f:
            return "\nState:\tZ" not in f.read()
    except FileNotFoundError:
        return False
    except OSError:
        try:
            os.kill(pid, 0)
            return True
        except ProcessLookupError:
            return False


def test_frame_shards_clip_the_summed_inner_gradient_not_each_part(rng):
    """The released code's inner clip acts on the whole inner gradient: with frame shards, on the sum of
    the processes' parts. Clipping each part before the sum gives other numbers whenever the clip binds,
    and it binds here (the clipped meta-gradient is not the unclipped one)."""
    settings, params, adapt, evaluate = _setup(rng, inner_params="all", inner_steps=2, alpha=0.05, inner_clip=0.02)
    one = shards.meta_gradient(params, adapt, evaluate, settings)
    unclipped = shards.meta_gradient(params, adapt, evaluate, (settings[0], dataclasses.replace(settings[1], clip=0.0)))
    assert any(not np.allclose(one[1][k], unclipped[1][k]) for k in params)
    with shards.make_pool(2) as pool:
        split = shards.meta_gradient(params, adapt, evaluate, settings, 2, pool)
    assert split[0] == pytest.approx(float(one[0]), rel=1e-12)
    for k in params:
        np.testing.assert_allclose(split[1][k], one[1][k], rtol=1e-10, atol=1e-13, err_msg=k)
