"""The expert demonstrator of paper Section IV.

    ilqg        iLQG in NumPy: a time-varying feedback controller for a model
    controller  the expert: iLQG planned on the analytic arm, its feedback controller run in Pymunk
"""
