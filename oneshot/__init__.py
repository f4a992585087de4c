"""oneshot: one-shot visual imitation learning via meta-learning (Finn et al., 2017), in NumPy."""

__version__ = "0.1.0"

GYM_ENV_ID = "oneshot/Reach-v0"       # the world of paper Section IV as a Gymnasium environment


def _register_with_gymnasium():
    """Register `oneshot/Reach-v0` with Gymnasium, if it is installed (the extra: pip install ".[gym]").

    Done on `import oneshot`, as Gymnasium's conventions ask, so that `gymnasium.make("oneshot/Reach-v0")`
    works after `import oneshot`, and `gymnasium.make("oneshot:oneshot/Reach-v0")` (which imports
    `oneshot` first) without it. Entry points are strings: nothing of the environment is imported until
    `make` builds one. max_episode_steps is the world's horizon, T = 20 (`WorldConfig.horizon`; the env
    also truncates itself there, so the two agree).
    """
    try:
        import gymnasium
    except ImportError:                 # no Gymnasium: the rest of the package does not need it
        return
    if GYM_ENV_ID not in gymnasium.registry:
        gymnasium.register(id=GYM_ENV_ID, entry_point="oneshot.world.gym:ReachEnv",
                           vector_entry_point="oneshot.world.gym:vector_env", max_episode_steps=20)


_register_with_gymnasium()
