"""The paper's experiments (Section IV): `python -m oneshot.experiments fig2 --help`.

    sweep  independent runs through any concurrent.futures.Executor, resumable, one CSV row per run
    fig2   Figure 2: one-shot success against meta-training data, per method
"""
