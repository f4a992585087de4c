"""Meta-training: checkpoints, exact resume, NaN handling, learning, and the evaluate command."""
import dataclasses
import glob
import importlib.metadata
import itertools
import json
import os

import numpy as np
import pytest

from oneshot.data import collection, datasets
from oneshot.expert.controller import ExpertConfig
from oneshot.maml import batched, imitation, inner, optim
from oneshot.policy import network
from oneshot.training import checkpoint, config, run_data, run_folder, scoring
from oneshot import evaluate, methods
from oneshot.methods.mil import INNER_PARAMS, inner_loop
from oneshot.training import loop
from oneshot.world.reach import WorldConfig
from test_checkpoint import _set, rewrite


@pytest.fixture
def tiny(tiny_split_datasets):
    paths = tiny_split_datasets
    return dataclasses.replace(config.PROFILES["smoke"], train_data=paths["train"], validation_data=paths["validation"],
                               test_data=paths["test"])


def _same(p, q):
    return set(p) == set(q) and all(np.array_equal(p[k], q[k]) for k in p)


@pytest.mark.parametrize("world, says", [({"image_size": 16}, "holds 32x32 images but"),
                                         ({"horizon": 12}, "holds 20-step demos but")])
def test_a_fresh_run_refuses_validation_data_of_another_world(tiny, tmp_path, world, says):
    """Validation data of another image size or horizon than the meta-training data is refused before the
    first iteration (it would fail at the first validation check, or score the policy in another world)."""
    other = str(tmp_path / "validation_other.npz")
    datasets.save(collection.collect(2, 2, "validation", seed=1, workers=1, progress=False,
                                     world_cfg=WorldConfig(**world), expert_cfg=ExpertConfig(action_noise=tiny.demo_noise)),
                  other)
    with pytest.raises(datasets.DatasetError, match=f"{tiny.train_data} {says} {other} holds .*; collect {other} in "
                                                    f"the meta-training data's world"):
        run_folder.train(dataclasses.replace(tiny, validation_data=other), tmp_path / "run", progress=False)
    assert not (tmp_path / "run" / "checkpoint.npz").exists()


def test_a_dataset_of_fewer_colours_than_the_profile_collects_is_used_and_said(tiny, tmp_path, capsys):
    """A small or stale file at a profile's path (3 of the hues palette's 36 meta-training colours, 2 of
    its 12 validation colours) trained silently on what it held; a note now says so, and how to collect
    the whole set. Asking for the first `tasks` colours says nothing of the meta-training set."""
    run_data.ensure(tiny)
    err = capsys.readouterr().err
    assert f"note: {tiny.train_data} holds 3 of the 36 train colours this profile collects; the run uses those 3 " \
           f"(the whole set: move it away, or python -m oneshot.collect --out {tiny.train_data} --split train --tasks 36" in err
    assert f"note: {tiny.validation_data} holds 2 of the 12 validation colours" in err
    run_data.ensure(dataclasses.replace(tiny, tasks=2))
    assert "train colours" not in capsys.readouterr().err
    assert run_data.fewer_colours(tiny, "validation", 12, "x") is None                  # the whole split: no note
    assert run_data.fewer_colours(tiny, "validation", 11, "x").startswith(f"note: {tiny.validation_data} holds 11 of")


def test_a_resume_with_another_config_is_refused_before_any_data_is_collected(tiny, tmp_path):
    run_folder.train(dataclasses.replace(tiny, iterations=2), tmp_path / "run", progress=False)
    other = dataclasses.replace(tiny, iterations=4, meta_batch=3, train_data=str(tmp_path / "missing.npz"))
    with pytest.raises(ValueError, match="was trained with a different config .*meta_batch: checkpoint 2, now 3"):
        run_folder.train(other, tmp_path / "run", resume=True, progress=False)
    assert not (tmp_path / "missing.npz").exists()                 # nothing collected for a run it refuses


def test_a_fresh_run_into_a_folder_holding_a_run_is_refused_before_any_data_is_collected(tiny, tmp_path):
    run_folder.train(dataclasses.replace(tiny, iterations=1), tmp_path / "run", progress=False)
    with pytest.raises(FileExistsError, match="already holds a run; use --resume, or another --run folder"):
        run_folder.train(dataclasses.replace(tiny, train_data=str(tmp_path / "missing.npz")), tmp_path / "run",
                         progress=False)
    assert not (tmp_path / "missing.npz").exists()


def test_checkpoint_round_trip(tiny, tmp_path):
    params = run_folder.train(dataclasses.replace(tiny, iterations=2), tmp_path / "run", progress=False)
    ckpt = checkpoint.load(tmp_path / "run" / "checkpoint.npz")
    assert _same(ckpt["params"], params) and ckpt["iteration"] == 2
    assert ckpt["config"] == dataclasses.replace(tiny, iterations=2)
    assert all(v.dtype == np.float32 for v in ckpt["params"].values())
    assert ckpt["adam"]["step"] == 2
    assert [p.name for p in (tmp_path / "run").iterdir() if p.name.startswith(".tmp")] == []
    umask = os.umask(0)
    os.umask(umask)
    assert (tmp_path / "run" / "checkpoint.npz").stat().st_mode & 0o777 == 0o666 & ~umask


def test_widths_and_init_reach_the_network_the_checkpoint_and_a_resume(tiny, tmp_path):
    """The released code's widths and init as TrainConfig fields: the network has them, the checkpoint
    records them (tuples stay tuples), and a resumed run continues exactly."""
    cfg = dataclasses.replace(tiny, iterations=4, checkpoint_every=2, channels=(4, 4), hidden=(8,), init="released",
                              layer_norm=True)
    whole = run_folder.train(cfg, tmp_path / "whole", progress=False)
    ckpt = checkpoint.load(tmp_path / "whole" / "checkpoint.npz")
    assert ckpt["config"] == cfg and ckpt["network"].channels == (4, 4) and ckpt["network"].hidden == (8,)
    assert ckpt["network"].init == "released" and whole["conv1_w"].shape == (3, 3, 4, 4)
    assert whole["fc0_w"].shape[1] == 8 and "fc1_w" not in whole
    run_folder.train(cfg, tmp_path / "split", progress=False, stop_after=2)
    assert _same(run_folder.train(cfg, tmp_path / "split", resume=True, progress=False), whole)


@pytest.mark.parametrize("shards", [1, 2])
def test_resume_gives_the_parameters_of_an_uninterrupted_run(tiny, tmp_path, shards):
    cfg = dataclasses.replace(tiny, iterations=8, checkpoint_every=3, shards=shards)
    whole = run_folder.train(cfg, tmp_path / "whole", progress=False)
    run_folder.train(cfg, tmp_path / "split", progress=False, stop_after=4)   # "killed" after iteration 4
    ckpt = checkpoint.load(tmp_path / "split" / "checkpoint.npz")
    assert ckpt["iteration"] == 4
    resumed = run_folder.train(cfg, tmp_path / "split", resume=True, progress=False)
    assert _same(resumed, whole)
    lines = [json.loads(x) for x in open(tmp_path / "split" / "log.jsonl")]
    assert [r["iteration"] for r in lines] == list(range(1, 9))          # no duplicated log lines
    with pytest.raises(FileExistsError, match="--resume"):
        run_folder.train(cfg, tmp_path / "whole", progress=False)
    with pytest.raises(ValueError, match=r"different config \(alpha: checkpoint .*, now 0\.01\)"):
        run_folder.train(dataclasses.replace(cfg, alpha=0.01), tmp_path / "whole", resume=True, progress=False)


def test_the_checkpoint_and_log_count_meta_training_time_over_every_sitting(tiny, tmp_path, monkeypatch):
    """A resumed run's seconds go on from the killed sitting's (checkpoint and log); a run whose older
    checkpoint recorded no time keeps it unknown, not a wrong number. The clock: 1 s per reading,
    from 0 in each sitting, as a new process's."""
    def new_sitting():
        ticks = itertools.count()
        monkeypatch.setattr(run_folder.time, "perf_counter", lambda: float(next(ticks)))
    cfg = dataclasses.replace(tiny, iterations=8, checkpoint_every=2, log_every=1)
    run = tmp_path / "run"
    new_sitting()
    run_folder.train(cfg, run, progress=False, stop_after=4)
    first = checkpoint.load(run / "checkpoint.npz")["seconds"]
    new_sitting()
    run_folder.train(cfg, run, resume=True, progress=False, stop_after=2)
    second = checkpoint.load(run / "checkpoint.npz")["seconds"]
    logged = [json.loads(x)["seconds"] for x in open(run / "log.jsonl")]
    assert 0 < first < second and logged == sorted(logged) and logged[3] <= first < logged[4]
    rewrite(run / "checkpoint.npz", _set(None, "seconds", None))    # as a checkpoint before this record
    new_sitting()
    run_folder.train(cfg, run, resume=True, progress=False)
    assert checkpoint.load(run / "checkpoint.npz")["seconds"] is None


def test_nan_stops_training_and_keeps_the_last_good_checkpoint(tiny, tmp_path, monkeypatch):
    cfg = dataclasses.replace(tiny, iterations=10, checkpoint_every=2)
    real = batched.meta_gradient_batched
    calls = {"n": 0}

    def poisoned(*args, **kwargs):
        calls["n"] += 1
        value, grads = real(*args, **kwargs)
        return (np.float32(np.nan), grads) if calls["n"] == 5 else (value, grads)

    monkeypatch.setattr(batched, "meta_gradient_batched", poisoned)
    with pytest.raises(run_folder.TrainingDiverged, match=r"iteration 5.*iteration 4"):
        run_folder.train(cfg, tmp_path / "run", progress=False)
    assert checkpoint.load(tmp_path / "run" / "checkpoint.npz")["iteration"] == 4


def test_a_short_seeded_run_lowers_the_meta_objective(tiny, tmp_path):
    cfg = dataclasses.replace(tiny, iterations=25, meta_batch=3, lr=1e-3)
    train_set = datasets.load(cfg.train_data)
    demos = imitation.prepare_demos(train_set["images"], train_set["states"], train_set["actions"], 0.5)
    batches = [imitation.sample_meta_batch(demos, np.random.default_rng(100 + i), 3) for i in range(4)]

    def objective(p):
        return np.mean([batched.meta_objective_batched(p, a, e, imitation.imitation_loss, inner_loop(cfg))
                        for a, e in batches])

    first = run_folder.train(dataclasses.replace(cfg, iterations=1), tmp_path / "one", progress=False)
    last = run_folder.train(cfg, tmp_path / "last", progress=False)
    assert objective(last) < 0.5 * objective(first)


def test_unknown_inner_params_is_refused_before_training(tiny, tmp_path):
    with pytest.raises(ValueError, match="inner_params must be one of"):
        run_folder.train(dataclasses.replace(tiny, inner_params="fc"), tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()


def test_inner_params_choose_which_parameters_adapt():
    net = network.init_params(network.NetworkConfig(bias_transform=4, feature_points=True), np.random.default_rng(0))
    adapted = {name: inner.adapted_keys(net, INNER_PARAMS[name])
               for name in ("all", "conv", "conv0")}
    assert adapted["all"] == list(net)
    assert adapted["conv"] == ["conv0_w", "conv0_b", "conv1_w", "conv1_b", "conv2_w", "conv2_b"]
    assert adapted["conv0"] == ["conv0_w", "conv0_b"]


def test_learnt_step_sizes_are_meta_trained_checkpointed_and_used_at_meta_test(tiny, tmp_path):
    cfg = dataclasses.replace(tiny, iterations=4, inner_params="conv0", inner_steps=1, alpha=0.1, learn_alpha=True)
    params = run_folder.train(cfg, tmp_path / "run", progress=False)
    steps = {k: v for k, v in params.items() if k.startswith(inner.STEP_PREFIX)}
    assert sorted(steps) == [inner.STEP_PREFIX + "conv0_b", inner.STEP_PREFIX + "conv0_w"]
    assert all(v.shape == params[k[len(inner.STEP_PREFIX):]].shape for k, v in steps.items())
    assert all(not np.allclose(v, 0.1) for v in steps.values())              # Adam moved them
    assert _same(checkpoint.load(tmp_path / "run" / "checkpoint.npz")["params"], params)
    # meta-test adapts with the learnt sizes, not with alpha: zero sizes leave the policy as it is
    demo = imitation.prepare_demos(*(datasets.load(cfg.validation_data)[k][0, 0] for k in ("images", "states", "actions")), 0.5)
    frozen = {**params, **{k: np.zeros_like(v) for k, v in steps.items()}}
    adapted = imitation.adapt(frozen, demo, cfg.alpha, 1, only=INNER_PARAMS[cfg.inner_params])
    assert _same(adapted, {k: v for k, v in params.items() if k not in steps})


def test_moving_average_of_the_parameters_resumes_exactly_and_is_what_the_policy_uses(tiny, tmp_path):
    cfg = dataclasses.replace(tiny, iterations=4, checkpoint_every=2, ema=0.5)
    whole = run_folder.train(cfg, tmp_path / "whole", progress=False)
    # the same run one iteration at a time (each call resumes), recording the parameters after each step
    trajectory = [run_folder.train(cfg, tmp_path / "split", progress=False, stop_after=1)]
    for _ in range(3):
        trajectory.append(run_folder.train(cfg, tmp_path / "split", resume=True, progress=False, stop_after=1))
    a, b = (checkpoint.load(tmp_path / r / "checkpoint.npz") for r in ("whole", "split"))
    assert _same(a["params"], whole) and _same(b["params"], whole) and _same(a["ema"], b["ema"])
    # ema_0 = initial parameters, ema_t = 0.5 ema_{t-1} + 0.5 params_t, written out in float64
    expected = {k: v.astype(np.float64) for k, v in network.init_params(a["network"], np.random.default_rng(0)).items()}
    for p in trajectory:
        expected = {k: 0.5 * expected[k] + 0.5 * p[k].astype(np.float64) for k in p}
    for k in whole:
        np.testing.assert_allclose(a["ema"][k], expected[k], rtol=1e-6, atol=1e-7)
        assert a["ema"][k].dtype == np.float32
    assert not _same(a["ema"], a["params"])
    assert checkpoint.policy_params(a) is a["ema"] and checkpoint.policy_params(a, raw=True) is a["params"]
    run_folder.train(dataclasses.replace(tiny, iterations=1), tmp_path / "plain", progress=False)
    assert checkpoint.load(tmp_path / "plain" / "checkpoint.npz")["ema"] is None
    with pytest.raises(ValueError, match="decay, in"):
        run_folder.train(dataclasses.replace(tiny, ema=1.0), tmp_path / "bad", progress=False)


def test_learning_rate_schedules():
    cfg = dataclasses.replace(config.TrainConfig(), lr=1e-3, iterations=100)
    assert [loop.learning_rate(cfg, i) for i in (0, 50, 99)] == [1e-3] * 3
    cos = dataclasses.replace(cfg, lr_schedule="cosine")
    assert loop.learning_rate(cos, 0) == pytest.approx(1e-3)
    assert loop.learning_rate(cos, 50) == pytest.approx(0.5e-3)
    assert loop.learning_rate(cos, 100) == pytest.approx(0.0, abs=1e-15)
    lrs = [loop.learning_rate(cos, i) for i in range(101)]
    assert all(a >= b for a, b in itertools.pairwise(lrs))             # never increases
    with pytest.raises(ValueError, match="lr_schedule must be"):
        loop.learning_rate(dataclasses.replace(cfg, lr_schedule="step"), 0)


def test_corrupt_checkpoint_is_named(tmp_path):
    bad = tmp_path / "checkpoint.npz"
    bad.write_bytes(b"PK\x03\x04 not really")
    with pytest.raises(ValueError, match="not a readable oneshot checkpoint"):
        checkpoint.load(bad)
    with pytest.raises(FileNotFoundError, match="oneshot.train"):
        checkpoint.load(tmp_path / "missing.npz")
    # NaN in the parameters or in their moving average: refused, naming the array
    net_cfg = network.NetworkConfig(image_size=8, channels=(3, 4), hidden=(5,))
    params = network.init_params(net_cfg, np.random.default_rng(0))
    for where in ("params", "ema"):
        poisoned = {**params, "out_b": np.full_like(params["out_b"], np.nan)}
        path = tmp_path / f"nan_{where}.npz"
        save = lambda p, e: checkpoint.save(path, p, optim.adam_init(params), 1, np.random.default_rng(0),
                                            config.TrainConfig(ema=0.5), net_cfg, ema=e)
        with pytest.raises(ValueError, match=f"save would write a file that checkpoint.load refuses: .*'{where}/out_b' "
                                             f"contains NaN"):                      # not written
            save(poisoned if where == "params" else params, poisoned if where == "ema" else params)
        assert not path.exists()
        save(params, params)                             # written, then poisoned by hand (its checksum too)
        rewrite(path, edit_meta=lambda meta: meta.pop("checksum"),
                edit_arrays=lambda arrays: arrays.update({f"{where}/out_b": poisoned["out_b"]}))
        with pytest.raises(ValueError, match=f"'{where}/out_b' contains NaN"):
            checkpoint.load(path)


def _checkpoint_recording_stride(tmp_path, stride):
    """A checkpoint as older oneshot versions wrote it: the network metadata records a "stride"."""
    net_cfg = network.NetworkConfig(image_size=8, channels=(3, 4), hidden=(5,), feature_points=True, bias_transform=2)
    params = network.init_params(net_cfg, np.random.default_rng(0))
    path = tmp_path / f"stride_{stride}.npz"
    checkpoint.save(path, params, optim.adam_init(params), 3, np.random.default_rng(0), config.TrainConfig(), net_cfg)
    with np.load(path) as f:
        arrays = {k: f[k] for k in f.files}
    meta = json.loads(str(arrays.pop("meta")))
    assert "stride" not in meta["network"]                 # today's checkpoints do not record it
    meta["network"]["stride"] = stride
    np.savez(path, meta=np.array(json.dumps(meta)), **arrays)
    return path, params, net_cfg


def test_checkpoints_recording_the_network_stride_load_only_with_stride_2(tmp_path):
    """Older checkpoints (the shipped one among them) record "stride": 2 in their network metadata: they
    load, into today's NetworkConfig. A network of another stride is refused, naming the stride."""
    path, params, net_cfg = _checkpoint_recording_stride(tmp_path, 2)
    ckpt = checkpoint.load(path)
    assert ckpt["network"] == net_cfg and _same(ckpt["params"], params) and ckpt["iteration"] == 3
    path, _, _ = _checkpoint_recording_stride(tmp_path, 1)
    with pytest.raises(ValueError, match=r"stride_1\.npz.*trained with convolution stride 1.*network has stride 2"):
        checkpoint.load(path)


def test_wilson_interval_against_known_values():
    lo, hi = scoring.wilson_interval(8, 10)
    assert lo == pytest.approx(0.4902, abs=1e-4) and hi == pytest.approx(0.9433, abs=1e-4)
    lo, hi = scoring.wilson_interval(100, 100)
    assert hi == pytest.approx(1.0) and lo == pytest.approx(0.9630, abs=1e-4)


def test_evaluate_command_counts_trials_and_uses_new_scenes(tiny, tmp_path, capsys):
    run_folder.train(dataclasses.replace(tiny, iterations=2), tmp_path / "run", progress=False)
    out = tmp_path / "eval.json"
    results = evaluate.main([str(tmp_path / "run" / "checkpoint.npz"), "--validation", tiny.validation_data,
                             "--train", "", "--trials", "3", "--json", str(out), "--unadapted"])
    r = results["validation"]
    assert r["trials"] == 2 * 3 and 0 <= r["successes"] <= 6
    assert r["ci95"][0] <= r["rate"] <= r["ci95"][1]
    assert sum(r["failures"].values()) == r["trials"] - r["successes"]   # every failure gets a kind
    printed = capsys.readouterr().out
    assert "validation colours: one-shot success" in printed
    assert f"\nnote: {tiny.validation_data} holds 2 of the 12 validation colours this profile collects; this " \
           f"scored those 2 (the whole set: " in printed                   # not the reported numbers' colours
    lines = printed.splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith("validation colours, by colour: "))
    block = [lines[first], *itertools.takewhile(lambda line: line.startswith("  "), lines[first + 1:])]
    by_colour = " ".join(line.strip() for line in block)
    assert all(len(line) <= 100 for line in block)                              # wrapped for a terminal
    counts = [item.split()[-1].split("/") for item in by_colour.split(": ", 1)[1].split("; ")]
    assert len(counts) == 2 and all(t == "3" for _, t in counts)            # 2 colours, 3 trials each
    assert sum(int(s) for s, _ in counts) == r["successes"]
    with open(out) as f:
        written = json.load(f)
    assert written["validation"]["trials"] == 6 and written["adaptation_gain"]["pairs"] == 2
    assert results["validation_unadapted"]["trials"] == 6
    assert results["adaptation_gain"]["pairs"] == 2
    evaluate.main([str(tmp_path / "run" / "checkpoint.npz"), "--validation", tiny.validation_data, "--train", "",
                   "--trials", "1", "--json", str(out), "--no-progress"])         # an earlier result is replaced
    with open(out) as f:
        assert json.load(f)["validation"]["trials"] == 2
    # the trial scenes are not the demos' scenes
    heldout = datasets.load(tiny.validation_data)
    world_seeds = {imitation.trial_seed(0, i, j) for i in range(2) for j in range(3)}
    assert not world_seeds & set(heldout["seeds"].ravel().tolist())


def test_evaluate_contrasts_only_the_colours_the_run_meta_trained_on(tiny, tmp_path, capsys):
    # a run on the first 2 of the dataset's 3 training colours (as a Figure 2 run on part of the data):
    # the contrast scores those 2 colours, not the third, which the run never saw
    run_folder.train(dataclasses.replace(tiny, iterations=2, tasks=2, demos=2), tmp_path / "run", progress=False)
    colours = datasets.load(tiny.train_data)["task_colours"].tolist()
    assert len(colours) == 3
    results = evaluate.main([str(tmp_path / "run" / "checkpoint.npz"), "--validation", tiny.validation_data,
                             "--trials", "2", "--unadapted"])
    train = results["train"]
    assert train["trials"] == 2 * 2 and sorted(train["per_colour"]) == sorted(colours[:2])
    # --unadapted: the policy without its inner step on the same colours (and scenes) too
    assert sorted(results["train_unadapted"]["per_colour"]) == sorted(colours[:2])
    assert results["validation_unadapted"]["trials"] == results["validation"]["trials"] == 2 * 2
    printed = capsys.readouterr().out                   # the small file scored is noted; the contrast's, not
    assert "validation colours this profile collects" in printed and "train colours this profile" not in printed


def test_evaluate_can_act_in_the_scenes_of_the_demonstrations(tiny, tmp_path, monkeypatch):
    # --demo-scenes: trial j adapts on demo j and acts in the recorded scene of demo j + 1 (mod k, the
    # demos the trials use: here 2 of the 3 training demos): the same target, distractors and positions
    # as that demonstration; without it, no recorded scene
    run_folder.train(dataclasses.replace(tiny, iterations=2), tmp_path / "run", progress=False)
    played, rollout = [], imitation.rollout
    monkeypatch.setattr(imitation, "rollout", lambda *a, **k: played.append(rollout(*a, **k)) or played[-1])
    ckpt = str(tmp_path / "run" / "checkpoint.npz")
    results = evaluate.main([ckpt, "--validation", tiny.validation_data, "--trials", "2", "--demo-scenes",
                             "--json", str(tmp_path / "e.json")])
    train, heldout = datasets.load(tiny.train_data), datasets.load(tiny.validation_data)
    assert train["seeds"].shape[1] == 3
    expected = [(d, i, (j + 1) % min(2, d["seeds"].shape[1])) for d in (heldout, train)
                for i in range(d["seeds"].shape[0]) for j in range(2)]
    assert len(played) == len(expected) == results["validation"]["trials"] + results["train"]["trials"]
    for trial, (d, i, k) in zip(played, expected):
        assert trial["scene"].target == d["target_index"][i, k]
        np.testing.assert_allclose(trial["scene"].positions, d["positions"][i, k], atol=1e-6)
        assert list(trial["scene"].colours) == list(d["colours"][i, k])
    with open(tmp_path / "e.json") as f:
        assert json.load(f)["policy"]["recipe"]["demo_scenes"] is True
    with pytest.raises(SystemExit):                       # 1 trial would act in its own demo's scene
        evaluate.main([ckpt, "--validation", tiny.validation_data, "--trials", "1", "--demo-scenes"])
    with pytest.raises(ValueError, match="demo scenes need 2 <= trials per colour <= the 2 demos"):
        imitation.one_shot_success(lambda demo: None, heldout, 3, demo_scenes=True)   # a trial would repeat one
    played.clear()
    evaluate.main([ckpt, "--validation", tiny.validation_data, "--trials", "3", "--train", ""])
    recorded = {tuple(np.round(p, 6).ravel()) for p in heldout["positions"].reshape(-1, *heldout["positions"].shape[2:])}
    assert played and not {tuple(np.round(t["scene"].positions, 6).ravel()) for t in played} & recorded


def test_evaluate_can_condition_on_a_demonstration_of_another_colour(tiny, tmp_path, monkeypatch, capsys):
    # --other-colour-demo, the control for what the demonstration carries: trial j of colour i is
    # conditioned on demo j of the other colour (of two) and still scored on colour i's target (which
    # other colour, the farthest in hue, is test_imitation.py's)
    run_folder.train(dataclasses.replace(tiny, iterations=2), tmp_path / "run", progress=False)
    ckpt = str(tmp_path / "run" / "checkpoint.npz")
    params = checkpoint.policy_params(checkpoint.load(ckpt), False)
    heldout = datasets.load(tiny.validation_data)
    n, k = heldout["images"].shape[:2]
    assert n == 2
    demos = imitation.prepare_demos(heldout["images"], heldout["states"], heldout["actions"],
                                    WorldConfig().arm.max_torque)
    played, rollout = [], imitation.rollout
    monkeypatch.setattr(imitation, "rollout",
                        lambda p, w, seed, colour: played.append(colour) or rollout(p, w, seed, colour))
    for other in (False, True):
        shown, played[:] = [], []
        imitation.one_shot_success(lambda demo: shown.append(demo) or params, heldout, 2, progress=False,
                                   other_colour_demo=other)
        assert played == [int(heldout["task_colours"][i]) for i in range(n) for j in range(2)]   # scored on its own
        for t, demo in enumerate(shown):
            i, j = divmod(t, 2)
            for got, want in zip(demo, demos):
                np.testing.assert_array_equal(got, want[1 - i if other else i, j % k])
    results = evaluate.main([ckpt, "--validation", tiny.validation_data, "--trials", "2", "--other-colour-demo",
                             "--json", str(tmp_path / "e.json")])
    assert results["validation"]["trials"] == 2 * n
    with open(tmp_path / "e.json") as f:
        assert json.load(f)["policy"]["recipe"]["other_colour_demo"] is True       # never pooled with the plain
    with pytest.raises(ValueError, match="another task needs 2 tasks or more; got 1"):
        imitation.one_shot_success(lambda demo: params, run_data.subset(heldout, 1, k), 2, other_colour_demo=True)
    run_folder.train(dataclasses.replace(tiny, iterations=1, tasks=1), tmp_path / "one", progress=False)
    capsys.readouterr()
    with pytest.raises(SystemExit) as stop:            # its contrast, the 1 colour it trained on: refused up front
        evaluate.main([str(tmp_path / "one" / "checkpoint.npz"), "--validation", tiny.validation_data,
                       "--other-colour-demo"])
    assert stop.value.code == 2 and "the train split has 1: skip the contrast with --train ''" in capsys.readouterr().err


def test_evaluate_command_can_meta_test_with_another_step_size(tiny, tmp_path, capsys):
    # alpha 0 leaves the policy as it is, so its "adapted" trials are the unadapted ones, scene by scene.
    run_folder.train(dataclasses.replace(tiny, iterations=2), tmp_path / "run", progress=False)
    ckpt = str(tmp_path / "run" / "checkpoint.npz")
    results = evaluate.main([ckpt, "--validation", tiny.validation_data, "--train", "", "--trials", "3",
                             "--unadapted", "--alpha", "0", "--inner-steps", "2"])
    assert results["validation"]["per_colour"] == results["validation_unadapted"]["per_colour"]
    assert results["adaptation_gain"]["before"] == pytest.approx(results["adaptation_gain"]["after"], rel=1e-6)
    trained = evaluate.main([ckpt, "--validation", tiny.validation_data, "--train", "", "--trials", "1"])
    assert trained["adaptation_gain"]["after"] != trained["adaptation_gain"]["before"]  # the flag did it
    with pytest.raises(SystemExit):
        evaluate.main([ckpt, "--validation", tiny.validation_data, "--train", "", "--alpha", "-1"])
    assert "alpha" in capsys.readouterr().err


def test_adaptation_gain_scores_a_second_demo_before_and_after_adapting(tiny, tmp_path):
    params = run_folder.train(dataclasses.replace(tiny, iterations=2), tmp_path / "run", progress=False)
    heldout = datasets.load(tiny.validation_data)                       # 2 colours x 2 demos: 2 pairs
    g = scoring.adaptation_gain(params, heldout, lambda demo: imitation.adapt(params, demo, 0.01, 2))
    demos = imitation.prepare_demos(heldout["images"], heldout["states"], heldout["actions"],
                                    heldout["metadata"]["world"]["arm"]["max_torque"])
    task = [tuple(a[i] for a in demos) for i in range(2)]
    before = [float(imitation.imitation_loss(params, (im[1], st[1], ac[1]))) for im, st, ac in task]
    after = [float(imitation.imitation_loss(imitation.adapt(params, (im[0], st[0], ac[0]), 0.01, 2),
                                            (im[1], st[1], ac[1]))) for im, st, ac in task]
    assert g["pairs"] == 2
    assert np.isclose(g["before"], np.mean(before), rtol=1e-5) and np.isclose(g["after"], np.mean(after), rtol=1e-5)
    assert g["after"] != g["before"]
    same = scoring.adaptation_gain(params, heldout, lambda demo: imitation.adapt(params, demo, 0.0, 1))   # no step
    assert np.isclose(same["before"], same["after"], rtol=1e-6)


def test_demo_adapts_a_checkpoint_and_reports_counts(tiny, tmp_path, capsys):
    from oneshot import demo
    run_folder.train(dataclasses.replace(tiny, iterations=1), tmp_path / "run", progress=False)
    result = demo.main(["--checkpoint", str(tmp_path / "run" / "checkpoint.npz"), "--trials", "1",
                        "--out", str(tmp_path / "out")])
    assert result["trials"] == 24 and 0 <= result["successes"] <= 24          # the 24 test colours, 1 trial each
    out = capsys.readouterr().out
    assert "one-shot success on test colours" in out and "expert success: 24/24" in out
    assert (tmp_path / "out" / "one_shot.png").exists()
    # the animation: one frame per time step, the demo and the policy before and after adapting side by side
    from PIL import Image
    from oneshot.world.reach import WorldConfig
    with Image.open(tmp_path / "out" / "one_shot_trial.gif") as gif:
        assert gif.n_frames == WorldConfig().horizon and gif.width > 3 * gif.height / 2


def test_maml_benchmark_reports_the_settings_it_timed(capsys):
    from oneshot.benchmark import __main__ as benchmark
    benchmark.main(["maml", "--profile", "smoke", "--iterations", "1", "--inner-steps", "1", "--shards", "1",
                    "--inner-params", "conv0", "--meta-batch", "3"])
    result = json.loads(capsys.readouterr().out)
    assert (result["inner_steps"], result["inner_params"], result["shards"], result["meta_batch"],
            result["first_order"]) == (1, "conv0", 1, 3, False)
    assert result["seconds_per_iteration"] > 0 and result["gflop_per_second"] > 0
    # A figure names the machine it was measured on: checked against what the test reads itself.
    machine = result["machine"]
    assert machine["numpy"] == importlib.metadata.version("numpy")
    try:
        cpuinfo = open("/proc/cpuinfo").read().splitlines()
    except OSError:
        cpuinfo = None
    if cpuinfo is not None:                               # Linux: the CPU model and the processor count
        models = [line.partition(":")[2].strip() for line in cpuinfo if line.split(":")[0].strip() == "model name"]
        assert machine["cpu"] == (models[0] if models else "unknown")
        assert machine["cores"] == sum(line.split(":")[0].strip() == "processor" for line in cpuinfo)
    blas_name, _, blas_version = machine["blas"].partition(" ")
    assert blas_name not in ("", "?") and blas_version not in ("", "?"), machine["blas"]
    bundled = glob.glob(os.path.join(os.path.dirname(np.__file__), os.pardir, "numpy.libs", "*openblas*"))
    if bundled:                                           # a wheel's bundled OpenBLAS: the BLAS it names
        assert "openblas" in blas_name.lower()


def test_the_shipped_policy_is_the_default_profiles_run():
    """The README's claim: `python -m oneshot.train --profile default` reproduces the shipped policy."""
    from oneshot.demo import PRETRAINED
    ckpt = checkpoint.load(PRETRAINED)
    assert ckpt["config"] == config.PROFILES["default"]
    assert ckpt["iteration"] == config.PROFILES["default"].iterations
    assert ckpt["ema"] is not None and set(ckpt["ema"]) == set(ckpt["params"])   # the profile keeps an average
    assert os.path.getsize(PRETRAINED) < 2_000_000


def test_evaluate_scores_the_test_colours_on_test_scenes_and_names_the_split(tiny, tmp_path, capsys):
    """`--split test` scores the checkpoint's own test set (the path its run recorded), on the test
    split's scene seeds: none of them a validation scene's or a dataset's."""
    run_folder.train(dataclasses.replace(tiny, iterations=2), tmp_path / "run", progress=False)
    results = evaluate.main([str(tmp_path / "run" / "checkpoint.npz"), "--split", "test", "--train", "", "--trials", "2"])
    assert set(results) == {"test", "adaptation_gain"} and results["test"]["trials"] == 2 * 2
    assert "test colours: one-shot success" in capsys.readouterr().out
    test = datasets.load(tiny.test_data)
    scenes = {imitation.trial_seed(0, i, j, "test") for i in range(2) for j in range(2)}
    assert not scenes & {imitation.trial_seed(0, i, j, "validation") for i in range(100) for j in range(100)}
    assert not scenes & set(test["seeds"].ravel().tolist())
    with pytest.raises(datasets.DatasetError, match="holds validation colours, not test colours"):
        evaluate.main([str(tmp_path / "run" / "checkpoint.npz"), "--split", "test", "--test", tiny.validation_data,
                       "--train", ""])


def test_update_ema_weights_the_old_average_by_the_decay():
    """ema <- decay ema + (1 - decay) params: with decay 0.9, from 0 towards 1, 0.1 (not 0.9: mutant T01,
    which decay 0.5 in the suite cannot tell apart)."""
    out = loop.update_ema({"w": np.zeros(3, np.float32)}, {"w": np.ones(3, np.float32)}, 0.9)
    np.testing.assert_allclose(out["w"], 0.1, rtol=1e-6)
    assert out["w"].dtype == np.float32


class _StubMethod:
    """A method whose meta-gradient is given; it records what the validation check conditions on."""
    def __init__(self, grads):
        self.grads, self.conditioned = grads, []

    def meta_gradient(self, params, adapt, evaluate, pool):
        return 1.0, {k: np.full_like(v, self.grads) for k, v in params.items()}

    def conditioner(self, params, seed):
        self.conditioned.append(params)
        return lambda demo: params


def _stub_run(monkeypatch, grads, **cfg_fields):
    cfg = dataclasses.replace(config.TrainConfig(), meta_batch=1, iterations=2, log_every=1, lr=1e-3,
                              lr_schedule="constant", **cfg_fields)
    params = {"w": np.zeros(3, np.float32)}
    rng = np.random.default_rng(0)
    state = loop.State(params, optim.adam_init(params), dict(params) if cfg.ema else None, 0, rng.bit_generator.state)
    demos = (np.zeros((2, 2, 1, 8, 8, 3), np.float32), np.zeros((2, 2, 1, 6), np.float32), np.zeros((2, 2, 1, 2), np.float32))
    monkeypatch.setattr(imitation, "one_shot_success", lambda *a, **k: {"rate": 0.0, "trials": 1})
    seen = []
    real_adam = optim.adam_step
    monkeypatch.setattr(optim, "adam_step", lambda p, g, s, lr: seen.append(g) or real_adam(p, g, s, lr))
    method = _StubMethod(grads)
    states = [s for s, _ in loop.steps(method, cfg, state, demos, validation=object())]
    return method, states, seen


def test_the_validation_check_during_training_scores_the_moving_average(monkeypatch):
    """With a moving average, the policy that acts is the average (checkpoint.policy_params): so must the
    validation check's be (mutant T07 scored the raw parameters)."""
    method, states, _ = _stub_run(monkeypatch, 0.5, ema=0.9, eval_every=1, eval_trials=1, clip=10.0)
    assert len(method.conditioned) == 2
    for s, conditioned in zip(states, method.conditioned):
        assert not np.array_equal(s.ema["w"], s.params["w"])
        assert conditioned is s.ema


def test_adam_receives_the_meta_gradient_clipped_to_cfg_clip(monkeypatch):
    """MIL clips the meta-gradient to [-10, 10] before Adam (mutant T10 skipped the clip: Adam's first
    step hides it, being invariant to the gradient's scale, so check what Adam is given)."""
    _, _, seen = _stub_run(monkeypatch, 1e3, ema=0.0, eval_every=0, clip=10.0)
    assert len(seen) == 2 and all(np.all(g["w"] == 10.0) for g in seen)
    _, _, seen = _stub_run(monkeypatch, 1e3, ema=0.0, eval_every=0, clip=0.0)      # 0: off
    assert all(np.all(g["w"] == 1e3) for g in seen)


def _untrained_checkpoint(tiny, path, method):
    """A checkpoint of `method`'s initial parameters for the tiny datasets' world, a narrow network (no
    training, and fast to adapt)."""
    cfg = dataclasses.replace(tiny, method=method, channels=(4, 4, 4), hidden=(8,))
    rng = np.random.default_rng(0)
    net_cfg = methods.of(cfg).network_config(32)
    params = methods.of(cfg).init_params(net_cfg, rng)
    world = datasets.load(tiny.train_data)["metadata"]["world"]
    checkpoint.save(path, params, optim.adam_init(params), 0, rng, cfg, net_cfg, world=world)
    return str(path), params


def test_evaluate_passes_its_seed_and_scenes_to_every_run_and_unadapted_means_the_parameters_as_they_are(
        tiny, tmp_path, monkeypatch):
    """What evaluate asks of `one_shot_success` (recorded, not run): with --seed 5 --demo-scenes --unadapted,
    the adapted and the unadapted runs both use seed 5 and the demos' scenes; the unadapted condition gives
    the checkpoint's parameters for any demo, the adapted one eq. (1)'s. A random policy's torques are
    drawn from --seed (`conditioner(params, seed)`)."""
    calls = []

    def recorded(condition, dataset, trials, seed, **options):
        calls.append((condition, trials, seed, options))
        n = len(dataset["task_colours"])
        return {"successes": 0, "trials": n * trials, "rate": 0.0, "failures": {"near_miss": n * trials, "wrong_object": 0},
                "per_colour": {int(c): 0.0 for c in dataset["task_colours"]}}
    monkeypatch.setattr(imitation, "one_shot_success", recorded)
    monkeypatch.setattr(evaluate, "adaptation_gain", lambda *a: {"before": 1.0, "after": 0.5, "pairs": 1})
    heldout = datasets.load(tiny.validation_data)
    demo = tuple(a[0, 0] for a in imitation.prepare_demos(heldout["images"], heldout["states"], heldout["actions"], 0.5))
    ckpt, params = _untrained_checkpoint(tiny, tmp_path / "mil.npz", "mil")
    evaluate.main([ckpt, "--validation", tiny.validation_data, "--train", "", "--trials", "2", "--seed", "5",
                   "--demo-scenes", "--unadapted"])
    assert [(trials, seed, options.get("demo_scenes")) for _, trials, seed, options in calls] == [(2, 5, True)] * 2
    adapted, unadapted = calls[0][0](demo), calls[1][0](demo)
    assert all(np.array_equal(unadapted[k], params[k]) for k in params)
    assert np.abs(adapted["conv0_w"] - params["conv0_w"]).max() > 0
    calls.clear()
    ckpt, params = _untrained_checkpoint(tiny, tmp_path / "random.npz", "random")
    evaluate.main([ckpt, "--validation", tiny.validation_data, "--train", "", "--trials", "2", "--seed", "5"])
    (condition, _, seed, _), = calls
    std = float(params["std"][0])
    assert seed == 5 and std > 0
    np.testing.assert_allclose(condition(demo)(None, None, None), std * np.random.default_rng(5).standard_normal((1, 2)),
                               rtol=1e-6)


def test_wilson_intervals_are_the_roots_of_the_score_equation_and_hold_the_rate():
    """For every count of 0..n successes in n = 1..150 trials, the interval is the set of rates p whose
    score test accepts s/n: the roots of (s/n - p)^2 = z^2 p (1 - p) / n, a quadratic in p solved here by
    numpy.roots (an independent reference); and it holds the rate exactly, 0 <= lo <= s/n <= hi <= 1
    (rounding had put the upper end of 6 of 6 at 0.9999999999999999 and the lower of 0 of 5 at -3e-17:
    evaluate's `lo <= rate <= hi` check failed for a policy that won 6 of 6). No trials: (0, 1)."""
    z = 1.96
    for n in range(1, 151):
        for s in range(n + 1):
            lo, hi = scoring.wilson_interval(s, n, z)
            rate = s / n
            roots = np.sort(np.roots([1 + z * z / n, -(2 * rate + z * z / n), rate * rate]).real)
            np.testing.assert_allclose([lo, hi], roots, atol=1e-12, err_msg=f"{s} of {n}")
            assert 0.0 <= lo <= rate <= hi <= 1.0, (s, n)
    assert scoring.wilson_interval(6, 6)[1] == 1.0 and scoring.wilson_interval(0, 5)[0] == 0.0
    assert scoring.wilson_interval(0, 0) == (0.0, 1.0)


def test_the_progress_bar_keeps_the_last_meta_loss_between_logs(tiny, tmp_path, capsys):
    """The bar shows the latest logged meta-loss on every update, not only on the iterations that log it
    (it appeared and vanished every `log_every` iterations)."""
    run_folder.train(dataclasses.replace(tiny, iterations=6, log_every=3), tmp_path / "run", progress=True)
    frames = [f for f in capsys.readouterr().err.split("\r") if "meta-training" in f and "/6 " in f]
    counts = [int(f.split("|")[2].split("/")[0]) for f in frames]
    assert max(counts) == 6 and any(c > 3 for c in counts)
    assert all("meta_loss=" in f for f, c in zip(frames, counts) if c >= 3)


def test_evaluate_wraps_the_per_colour_line_between_colours():
    """48 colours on lines of at most 100 characters, each "hue ... k/n" whole, nothing lost or added."""
    items = [f"hue {h:.2f} deg {h % 11:.0f}/10" for h in np.arange(48) * 7.5]
    text = evaluate._wrapped("test colours, by colour:", items)
    lines = text.splitlines()
    assert len(lines) > 5 and all(len(line) <= 100 for line in lines)
    assert all(line.startswith("  hue") for line in lines[1:])
    assert " ".join(line.strip() for line in lines) == "test colours, by colour: " + "; ".join(items)
    assert evaluate._wrapped("head:", ["x" * 120, "y"]) == "head: " + "x" * 120 + ";\n  y"   # too long: alone
