"""The lines of Figure 2 (Section IV) and of the sweeps around it: each a method (`oneshot.methods`) with
its training configuration (`oneshot.training.config.TrainConfig`), by name; which lines each sweep
draws (`FIGURE`, `SEARCH`, `ABLATION`); and lines trained longer than their sweep (`LONGER`). How a
sweep runs them: `oneshot.experiments.fig2`.
"""
import dataclasses

from oneshot.training.config import PROFILES as PROFILES_TRAIN


def _default(**changes):
    return dataclasses.replace(PROFILES_TRAIN["default"], **changes)


# The lines of the figure and the variants of the hyperparameter search (`--profile search`), each a
# method (`oneshot.methods`) with its training configuration. All share the default profile's recipe
# (feature points, bias transformation, Adam 3e-3, clipping, moving average 0.999, meta-batch 5); they
# differ in how one demonstration enters, and MIL's variants in what eq. (1) adapts:
#   mil-conv0  the default profile: one inner step of 0.3 on the first convolution
#   mil-all    every parameter adapts (the paper's inner loop), one step of 0.25: MIL's released code
#              scores eq. (2) as mean((100 (u - u_hat))^2), 10^4 times the mean squared error, with a
#              nominal step of 0.001, i.e. a step of 10 on the mean squared error; our eq. (2) is a sum
#              over 20 frames x 2 torques (40 times the mean), so that step is alpha = 10 / 40 = 0.25
LINES = {
    "mil-conv0": _default(),
    "mil-all": _default(inner_params="all", alpha=0.25),
    "contextual": _default(method="contextual"),
    "lstm": _default(method="lstm"),
    "random": _default(method="random"),
    "mil-all-a0.05": _default(inner_params="all", alpha=0.05),
    "mil-all-a0.01": _default(inner_params="all", alpha=0.01),
    "contextual-lr1e-3": _default(method="contextual", lr=1e-3),
    "lstm-lr1e-3": _default(method="lstm", lr=1e-3),
    "lstm-512": _default(method="lstm", lstm_units=512),
    "lstm-2048": _default(method="lstm", lstm_units=2048),   # the workshop paper's width (`--profile lstm-2048`)
}
# MIL's released code (tianheyu927/mil) in its inner loop and network, detail by detail, as changes to
# mil-all (`--profile released` is all of them on the released training settings):
RELEASED = {
    "clip": dict(alpha=0.001, inner_loss_scale=250.0, inner_clip=20.0),  # its loss convention, gradient clip 20
    "ln": dict(layer_norm=True, never_adapt=("ln",)),                    # layer norm, offsets never adapted
    "flat": dict(feature_points=False),                                  # conv output flattened (--fp=False)
    "mb25": dict(meta_batch=25),                                         # meta-batch 25
    "adam": dict(lr=1e-3, clip=0.0),                                     # Adam 1e-3, no outer clip
    "init": dict(init="released"),                                       # --init=xavier; dense N(0, 0.01^2)
}
_ALL = {k: v for change in RELEASED.values() for k, v in change.items()}
# The ablation (issue 29): from mil-all add each detail; from all of them (below: on the released widths)
# remove each; and 3 inner steps.
LINES.update({f"mil-all+{d}": dataclasses.replace(LINES["mil-all"], **change) for d, change in RELEASED.items()})
LINES["mil-released"] = dataclasses.replace(LINES["mil-all"], **_ALL)
LINES.update({f"mil-released-{d}": dataclasses.replace(LINES["mil-released"], **{k: getattr(LINES["mil-all"], k)
                                                                                for k in change})
              for d, change in RELEASED.items()})
# The released sim_vision_reach widths (--num_filters=30, --num_fc_layers=3 --layer_size=200: two hidden
# layers of 200 and the output) in place of the seed paper's 3 x 40 and 4 x 100. With all six details,
# our widths learnt nothing (`mil-released`: meta-loss flat at 6.2-6.5) and the released widths fit the
# training tasks (meta-loss 0.29): so the full released set is `mil-released+widths`, and the details are
# removed one at a time from it (docs/results.md section 10; `mil-released-clip` and `-init`, from the
# set on our widths, said which details stopped that one learning).
WIDTHS = dict(channels=(30, 30, 30), hidden=(200, 200))
LINES["mil-released+widths"] = dataclasses.replace(LINES["mil-released"], **WIDTHS)
LINES.update({f"mil-released+widths-{d}": dataclasses.replace(LINES[f"mil-released-{d}"], **WIDTHS)
              for d in RELEASED})
LINES["mil-released+widths+3steps"] = dataclasses.replace(LINES["mil-released+widths"], inner_steps=3)
# Three steps on the set with feature points, the figure's every-parameter line: its seed 0 learnt the task
# (95.6%) and its seed 1 memorised its training scenes (18.9%), as one step on the flattened set did with
# both seeds, and three steps on that set learnt it in part (47.2%) (docs/results.md section 10).
LINES["mil-released+widths-flat+3steps"] = dataclasses.replace(LINES["mil-released+widths-flat"], inner_steps=3)
# Lines trained longer than their profile's iterations: {line: (the line it continues, its iterations)}.
# Its run starts from the shorter line's finished run of the same size and seed when that exists (the
# checkpoint holds parameters, Adam, moving average and sampling state, and the step size is constant,
# so this is the same run as one trained from scratch: `fig2._continue_shorter`); the released code
# trains 30,000.
# Three steps on the full set were still learning at 10,000 iterations (validation checks 3, 7, 4, 24 and
# 46% at 2000-10000; docs/results.md section 10), where one step had long been flat: the same to 30,000.
LONGER = {"mil-released+widths+30k": ("mil-released+widths", 30000),
          "mil-released+widths+3steps+30k": ("mil-released+widths+3steps", 30000)}
LINES.update({line: LINES[shorter] for line, (shorter, _) in LONGER.items()})
# The queue: mil-all and each detail added; the full set on our widths and the two removals that said
# why it learnt nothing; the full released set and each detail removed from it (first the output
# layer's feature points, without which `mil-all` scored lower (`mil-all+flat`), and meta-batch 5, the
# cheapest), 3 inner steps;
# the longer line last: by the time a worker reaches it, the run it continues has finished.
ABLATION = ("mil-all", *(f"mil-all+{d}" for d in RELEASED), "mil-released", "mil-released-clip", "mil-released-init",
            "mil-released+widths", *(f"mil-released+widths-{d}" for d in ("flat", "mb25", "ln", "adam", "clip", "init")),
            "mil-released+widths+3steps", "mil-released+widths-flat+3steps", "mil-released+widths+30k",
            "mil-released+widths+3steps+30k")
# The lines of the figure (`--profile paper`): its every-parameter line is the ablation's choice on the
# validation colours (`mil-released+widths-flat`, docs/results.md section 10). The first figure, scored
# on the validation colours before the test split existed (`--profile paper-validation`), and the cheap
# profiles (`quick`, `tiny`) have `mil-all`, the every-parameter line it replaced.
FIGURE = ("mil-conv0", "mil-released+widths-flat", "contextual", "lstm", "random")
FIRST_FIGURE = ("mil-conv0", "mil-all", "contextual", "lstm", "random")
SEARCH = ("mil-conv0", "mil-all", "contextual", "lstm", "mil-all-a0.05", "mil-all-a0.01", "contextual-lr1e-3",
          "lstm-lr1e-3", "lstm-512")                                  # the hyperparameter search's variants

LABELS = {"mil-conv0": "MIL, first convolution adapts", "mil-all": "MIL, every parameter adapts (step 0.25)",
          "mil-released+widths-flat": "MIL, every parameter adapts (the released code's loop, feature points)",
          "contextual": "contextual policy", "lstm": "LSTM", "random": "random policy"}
