"""oneshot: one-shot visual imitation learning via meta-learning (Finn et al., 2017), in NumPy."""
import importlib.abc
import importlib.util
import signal
import sys

__version__ = "0.1.0"

GYM_ENV_ID = "oneshot/Reach-v0"       # the world of paper Section IV as a Gymnasium environment


def interrupted_while_importing(signum, frame):
    """Ctrl-C while a command (e.g. `python -m oneshot.train`) imports, before `oneshot.tools.cli.run`
    takes over (which puts Python's own handler back): the same one line and exit status 130 as
    cli.run's, not a traceback through NumPy's imports."""
    sys.stderr.write("error: interrupted\n")
    raise SystemExit(130)


if sys.argv[:1] == ["-m"] and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
    signal.signal(signal.SIGINT, interrupted_while_importing)   # (argv[0] is "-m" while -m locates the module)


def _register(gymnasium):
    """Register `oneshot/Reach-v0` with Gymnasium. Entry points are strings: nothing of the environment
    is imported until `make` builds one. No max_episode_steps: the env truncates itself after its
    horizon (`WorldConfig.horizon`, T = 20 unless `make(..., horizon=T)`), where it judges success; a
    registered TimeLimit of 20 would end a longer episode before that, and `make` does not tell the env."""
    if GYM_ENV_ID not in gymnasium.registry:
        gymnasium.register(id=GYM_ENV_ID, entry_point="oneshot.world.gym:ReachEnv",
                           vector_entry_point="oneshot.world.gym:vector_env")


class _RegisterWhenGymnasiumLoads(importlib.abc.MetaPathFinder):
    """Registers the environment the moment Gymnasium is imported, after `import oneshot` (the optional
    extra: pip install ".[gym]"). So `gymnasium.make("oneshot/Reach-v0")` works after `import oneshot`,
    as Gymnasium's conventions ask, and `gymnasium.make("oneshot:oneshot/Reach-v0")` (which imports
    `oneshot` itself) without it; yet `import oneshot` imports nothing but the standard library (the
    exercise grader relies on that: a student's numpy.py must not be imported before it guards)."""

    def find_spec(self, name, path=None, target=None):
        if name != "gymnasium":
            return None
        sys.meta_path.remove(self)                 # once: the real finders locate Gymnasium
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.loader is not None and hasattr(spec.loader, "exec_module"):
            run = spec.loader.exec_module

            def exec_module(module):
                run(module)
                _register(module)
            spec.loader.exec_module = exec_module
        return spec


if sys.modules.get("gymnasium") is not None:             # None: marked missing
    _register(sys.modules["gymnasium"])
elif "gymnasium" not in sys.modules and not any(isinstance(f, _RegisterWhenGymnasiumLoads) for f in sys.meta_path):
    sys.meta_path.insert(0, _RegisterWhenGymnasiumLoads())
