"""The policy network of paper Section IV: pixels and robot state in, joint torques out.

    layers   the network's layers as autograd primitives (convolution as im2col + matrix product)
    network  the policy: a plain reference version and the fast one, proved equal by the tests
    inputs   what the policy accepts: the checks of `network.predict` and `network.predict_tasks`
"""
