"""The policy network of paper Section IV: pixels and robot state in, joint torques out.

    layers     the network's layers as autograd primitives (convolution as im2col + matrix product)
    network    the policy: its parameters and the fast forward pass
    reference  the same policy in plain autograd.numpy, to read (the tests prove the two equal)
    inputs     what the policy accepts: the checks of `network.predict` and `network.predict_tasks`
"""
