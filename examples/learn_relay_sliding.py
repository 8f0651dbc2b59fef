"""Train the shipped step-size policy of the `relay_sliding` task (see `nivpjax.learn.tasks`):

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python examples/learn_relay_sliding.py [--iterations N]

The shipped policy: 200 ES iterations on 16 draws (about 30 s of training on one core).
ES on this scene is noisy (the objective of one iteration spreads over 340-850), so the
longer run finds a better iterate than 40 iterations on 8 draws did: 1.22x against 1.04x
PID's Newton iterations at the policy's error on the held-out draws.
"""

from _learn import main


if __name__ == "__main__":
    main("relay_sliding", iterations=200, batch=16)
