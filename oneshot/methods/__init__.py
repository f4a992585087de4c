"""The methods of paper Section IV's comparison, each one object behind one interface (`base.Method`).

    mil           MAML on behavioural cloning (Sections II-III): eq. (1) adapts to one demonstration
    contextual    the demonstration's final image as input
    lstm          an LSTM reads the demonstration, then the policy acts
    random        Gaussian torques

    method = methods.of(cfg)      # the object cfg.method names, bound to cfg

Adding a method: a module with a `base.Method` subclass, and one line in REGISTRY.
"""
from oneshot.methods.contextual import Contextual
from oneshot.methods.lstm import LSTM
from oneshot.methods.mil import MIL
from oneshot.methods.random_policy import RandomPolicy

REGISTRY = {method.name: method for method in (MIL, Contextual, LSTM, RandomPolicy)}


def of(cfg):
    """The method `cfg.method` names, bound to cfg (a TrainConfig). Raises ValueError for an unknown name."""
    if not hasattr(cfg, "method"):
        raise ValueError(f"methods.of takes a TrainConfig, e.g. TrainConfig(method='mil') or a profile of "
                         f"oneshot.training.config.PROFILES; got {cfg!r}")
    if cfg.method not in REGISTRY:
        raise ValueError(f"method must be one of {', '.join(REGISTRY)}; got {cfg.method!r}")
    return REGISTRY[cfg.method](cfg)
