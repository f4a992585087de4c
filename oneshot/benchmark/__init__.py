"""Speed and quality benchmarks: `python -m oneshot.benchmark {expert,collect,maml,privileged} --help`.

    maml        seconds per meta-iteration, GFLOP/s against the machine's matrix-product ceiling, memory;
                where the time goes (--breakdown)
    expert      iLQG solve time and the expert's success; collect: collection wall time
    privileged  ceilings for the policy network given what one-shot imitation must infer
"""
