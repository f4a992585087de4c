"""oneshot: one-shot visual imitation learning via meta-learning (Finn et al., 2017), in NumPy."""

__version__ = "0.1.0"
