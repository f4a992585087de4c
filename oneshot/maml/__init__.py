"""MAML (paper Section II) and one-shot imitation (Section III).

    inner      eq. (1), the inner update, and the meta-objective: the plain path, to read
    batched    the same inner update applied to a whole meta-batch in one graph: the training path
    shards     one meta-gradient shared by several processes, each on its block of frames
    optim      Adam and gradient clipping
    imitation  eq. (2), behavioural cloning as MAML's loss, meta-batches, and meta-test in the world
"""
