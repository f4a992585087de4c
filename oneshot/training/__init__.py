"""Meta-training and evaluation (paper Sections II-IV).

    config      the configuration of a run (one frozen dataclass) and its named profiles
    checkpoint  checkpoints: parameters, optimiser, random state, configs; checked when read
    run_folder  a run folder around the training loop: lock, checkpoints, exact resume, log
    scoring     one-shot success with intervals, by colour, and the adaptation gain
"""
