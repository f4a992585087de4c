"""What a researcher passes to the API (issue 30, class 8), each refused with one ValueError saying what
to pass instead: images in 0..255 (the network would silently act on them), no frames, a missing
parameter (a bare KeyError before), big-endian arrays (refused as "must be float32; got float32"),
and metadata JSON nested deep enough to be a RecursionError."""
import json

import autograd.numpy as anp
import numpy as np
import pytest
from autograd import grad
from autograd.tracer import getval

from oneshot import methods
from oneshot.data import datasets
from oneshot.maml import imitation
from oneshot.policy.network import NetworkConfig, forward, images_to_float, init_params, predict, predict_tasks
from oneshot.training import checkpoint
from oneshot.training.config import TrainConfig
from test_checkpoint import save_tiny
from test_data import _rewrite, tiny_file  # noqa: F401 (a fixture)

CONFIG = NetworkConfig(image_size=8, channels=(3, 4), hidden=(5, 5), bias_transform=2)


def problem(T=3, B=None, seed=0):
    """params of CONFIG, images in [0, 1) and states for T frames (of B tasks, if B is given)."""
    rng = np.random.default_rng(seed)
    lead = (T,) if B is None else (B, T)
    return (init_params(CONFIG, rng), rng.random((*lead, 8, 8, 3), dtype=np.float32),
            rng.standard_normal((*lead, 6)).astype(np.float32))


ENTRIES = {"predict": (predict, None), "predict_tasks": (predict_tasks, 2)}


# --- the network's inputs -----------------------------------------------------------------------------

@pytest.mark.parametrize("entry", ENTRIES)
def test_images_in_0_to_255_are_refused_saying_to_divide_by_255(entry):
    """The camera's uint8 values as floats: the network would act on inputs 255 times too large, and
    nothing would look wrong but the success rate."""
    f, B = ENTRIES[entry]
    params, images, states = problem(B=B)
    camera = np.round(images * 255)
    with pytest.raises(ValueError, match=r"float in \[0, 1\]; got values up to 2\d\d: divide images in 0..255 by "
                                         r"255 \(oneshot.policy.network.images_to_float does it"):
        f(params, camera, states)
    np.testing.assert_allclose(f(params, camera / 255, states), f(params, images_to_float(camera.astype(np.uint8)),
                                                                     states), rtol=1e-6)


@pytest.mark.parametrize("change, message", [(lambda x: x - 0.5, r"got values down to -0\.\d+"),
                                             (lambda x: np.where(x > 0.5, np.nan, x), "they hold NaN or inf"),
                                             (lambda x: x + np.inf, "they hold NaN or inf")])
def test_images_outside_0_1_are_refused(change, message):
    params, images, states = problem()
    with pytest.raises(ValueError, match=message):
        predict(params, change(images), states)


@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_states_that_are_not_finite_are_refused(value):
    params, images, states = problem()
    states[1, 2] = value
    with pytest.raises(ValueError, match="states must be finite; they hold NaN or inf"):
        predict(params, images, states)


def test_predict_differentiates_with_respect_to_its_inputs():
    """A saliency map: d(actions)/d(images) and d/d(states) through the checked entry, as through forward."""
    params, images, states = problem()
    to_images = grad(lambda x: anp.sum(predict(params, x, states)))(images)
    np.testing.assert_array_equal(to_images, grad(lambda x: anp.sum(forward(params, x, states)))(images))
    to_states = grad(lambda s: anp.sum(predict(params, images, s)))(states)
    assert to_images.shape == images.shape and to_states.shape == states.shape and np.any(to_states != 0)
    dtypes = []                                     # float64 inputs are cast to the parameters' float32, boxed too

    def actions_sum(x):
        actions = predict(params, x, states.astype(np.float64))
        dtypes.append(getval(actions).dtype)
        return anp.sum(actions)
    np.testing.assert_allclose(grad(actions_sum)(images.astype(np.float64)), to_images, rtol=1e-6)
    assert dtypes == [np.float32]


# --- a demonstration, as eq. (1) adapts on it (imitation.adapt, a method's conditioner) --------------------

def demo_of(T=3):
    params, images, states = problem(T)
    return params, (images, states, np.random.default_rng(1).standard_normal((T, 2)).astype(np.float32))


@pytest.mark.parametrize("change, message", [
    (lambda d: (np.round(d[0] * 255).astype(np.uint8), d[1], d[2]), r"got uint8 \(3, 8, 8, 3\): imitation.prepare_demos converts"),
    (lambda d: (np.round(d[0] * 255), d[1], d[2]), r"got values up to 2\d\d: divide images in 0..255 by 255"),
    (lambda d: (d[0][:0], d[1][:0], d[2][:0]), r"with T >= 1; got \(0, 8, 8, 3\)"),
    (lambda d: (d[0], d[1], d[2][:1]), r"demo actions must be \(3, n\) float .* got \(1, 2\)"),
    (lambda d: (d[0], d[1], d[2][:, :1]), r"actions must be \(3, 2\) float"),
    (lambda d: (d[0], d[1], np.full_like(d[2], np.nan)), "actions must be finite"),
    (lambda d: (d[0], d[1]), r"a demo is \(images, states, actions\)"),
    (lambda d: (d[0][:, :4, :4], d[1], d[2]), "more than the .* inputs|states must be"),
])
def test_adapting_checks_the_demonstration(change, message):
    """eq. (1) on a wrong demo fails in one line at its entry: raw camera images would make a step 255
    times too large and a policy that fails without a word (0/10 trials instead of 10/10)."""
    params, demo = demo_of()
    with pytest.raises(ValueError, match=message):
        imitation.adapt(params, change(demo), 0.1, 1)


@pytest.mark.parametrize("name", ["contextual", "lstm"])
@pytest.mark.parametrize("camera", ["uint8", "0..255"])
def test_a_baselines_conditioner_checks_the_demonstration(name, camera):
    """The baselines read the demo too: camera images went in as they were, without a word."""
    method = methods.of(TrainConfig(method=name, channels=(3, 4), hidden=(5, 5)))
    params = method.init_params(method.network_config(8), np.random.default_rng(0))
    _, (images, states, actions) = demo_of()
    raw = np.round(images * 255)
    with pytest.raises(ValueError, match="got uint8" if camera == "uint8" else "divide images in 0..255 by 255"):
        method.conditioner(params)((raw.astype(np.uint8) if camera == "uint8" else raw, states, actions))
    assert callable(method.conditioner(params)((images, states, actions)))


def test_adapting_casts_a_float64_demo_to_the_parameters_dtype():
    params, demo = demo_of()
    adapted = imitation.adapt(params, tuple(a.astype(np.float64) for a in demo), np.float64(0.1), 1)
    assert all(v.dtype == np.float32 for v in adapted.values())
    np.testing.assert_array_equal(adapted["conv0_w"], imitation.adapt(params, demo, 0.1, 1)["conv0_w"])


def test_images_of_exactly_0_and_1_are_accepted():
    params, images, states = problem()
    edges = np.where(images > 0.5, 1.0, 0.0).astype(np.float32)
    assert np.all(np.isfinite(predict(params, edges, states)))


@pytest.mark.parametrize("entry, lead", [("predict", (0,)), ("predict_tasks", (2, 0)), ("predict_tasks", (0, 3))])
def test_no_frames_or_no_tasks_is_one_clear_error(entry, lead):
    """T = 0 (or B = 0) was a raw reshape error from deep inside the network."""
    f, _ = ENTRIES[entry]
    params, _, _ = problem()
    shape = ", ".join(map(str, lead))
    with pytest.raises(ValueError, match=r"with at least one (task, )?frame and pixel; got \(" + shape):
        f(params, np.zeros((*lead, 8, 8, 3), np.float32), np.zeros((*lead, 6), np.float32))


@pytest.mark.parametrize("key", [k for k in init_params(CONFIG, np.random.default_rng(0)) if k != "bias_transform"])
def test_a_missing_parameter_is_named_with_what_makes_the_params(key):
    """Every array the network reads: missing, it is named (not a bare KeyError), with where params
    come from. (Without "bias_transform" the first dense layer's width is what is wrong: the states
    error says so.)"""
    params, images, states = problem()
    del params[key]
    for f, B in ENTRIES.values():
        with pytest.raises(ValueError, match=f"'{key}'.*init_params\\(NetworkConfig"):
            f(params, *(x if B is None else np.stack([x] * B) for x in (images, states)))


def test_a_parameter_that_is_not_an_array_is_named():
    params, images, states = problem()
    with pytest.raises(ValueError, match=r"params\['out_b'\] must be an array; got list"):
        predict(dict(params, out_b=[0.0, 0.0]), images, states)
    with pytest.raises(ValueError, match="params must be a dict of arrays .*init_params.*; got list"):
        predict(list(params.values()), images, states)


# --- big-endian arrays --------------------------------------------------------------------------------------

def test_big_endian_arrays_are_named_by_their_byte_order(tiny_file, tmp_path):
    """A dtype of the other byte order has the same name: the error said "must be float32; got float32"."""
    data = datasets.load(tiny_file)
    words = (r"states must be 4-d float32; got 4-d float32 in big-endian byte order "
             r"\(>f4; convert with \.astype\(np\.float32\)\)")
    with pytest.raises(datasets.DatasetError, match="dataset: " + words):
        datasets.save(dict(data, states=data["states"].astype(">f4")), tmp_path / "d.npz")
    path = tmp_path / "big.npz"
    path.write_bytes(tiny_file.read_bytes())
    _rewrite(path, states=data["states"].astype(">f4"))
    with pytest.raises(datasets.DatasetError, match=words):
        datasets.load(path)


def test_the_network_takes_big_endian_inputs_as_the_same_numbers():
    params, images, states = problem()
    big = predict(params, images.astype(">f4"), states.astype(">f8"))
    assert big.dtype == np.float32 and np.array_equal(big, predict(params, images, states))


# --- deeply nested metadata ---------------------------------------------------------------------------------

def _nested(text, depth):
    """A JSON object's text with one more key, "deep", holding `depth` arrays each inside the next."""
    return text.rstrip()[:-1] + ', "deep": ' + "[" * depth + "]" * depth + "}"


@pytest.mark.parametrize("depth", [33, 100_000])
def test_deeply_nested_dataset_metadata_is_a_dataset_error(tiny_file, tmp_path, depth):
    """100,000 levels were a RecursionError traceback; 33 parsed, then waited for whatever walks it."""
    path = tmp_path / "d.npz"
    path.write_bytes(tiny_file.read_bytes())
    with np.load(path) as f:
        text = str(f["metadata"])
    _rewrite(path, metadata=np.array(_nested(text, depth)))
    with pytest.raises(datasets.DatasetError, match=f"^'{path}' has corrupt metadata \\(arrays and objects nested "
                                                    r"deeper than 32: line 1 column \d+ \(char \d+\)\); re-create"):
        datasets.load(path)


@pytest.mark.parametrize("depth", [33, 100_000])
def test_deeply_nested_checkpoint_metadata_is_a_checkpoint_error(tmp_path, depth):
    path = tmp_path / "c.npz"
    save_tiny(path)
    with np.load(path) as f:
        arrays = {k: f[k] for k in f.files}
    np.savez(path, **dict(arrays, meta=np.array(_nested(str(arrays["meta"]), depth))))
    with pytest.raises(checkpoint.CheckpointError, match=f"^'{path}' has corrupt metadata \\(arrays and objects "
                                                         f"nested deeper than 32"):
        checkpoint.load(path)


def test_the_depth_limit_counts_brackets_outside_strings_only():
    from oneshot.tools.files import MAX_JSON_DEPTH, JSONTooDeep, loads_json
    deepest = "[" * MAX_JSON_DEPTH + "]" * MAX_JSON_DEPTH
    assert loads_json(deepest) == json.loads(deepest)
    quoted = json.dumps({"a": "[" * 100 + '\\"{' * 100, "b": ["]]]\\"]})          # brackets and quotes in strings
    assert loads_json(quoted) == json.loads(quoted)
    with pytest.raises(JSONTooDeep, match=r"nested deeper than 32: line 1 column 33 \(char 32\)") as e:
        loads_json("[" + deepest + "]")
    assert isinstance(e.value, json.JSONDecodeError) and isinstance(e.value, ValueError)


def test_the_depth_limit_counts_nesting_not_brackets():
    """A hundred arrays side by side are one level deep, not a hundred."""
    from oneshot.tools.files import loads_json
    wide = json.dumps({"runs": [[1, 2]] * 100, "deep": [[[]]]})
    assert loads_json(wide) == json.loads(wide)
