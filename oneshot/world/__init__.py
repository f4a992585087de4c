"""The world of paper Section IV: a planar 2-link arm reaching for coloured discs.

    arm       the analytic arm (kinematics, dynamics and their derivatives), what the expert plans on
    palette   the colours, and so the tasks, split into meta-training, validation and test colours
    render    the 32x32 RGB image the policy sees
    scene     a scene: the target and distractor discs of one episode, checked or sampled
    reach     the Pymunk world: observations, steps, the success criterion
    gym       the same world as a Gymnasium environment (optional extra)
"""
