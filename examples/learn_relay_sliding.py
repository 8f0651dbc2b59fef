"""Train the shipped step-size policy of the `relay_sliding` task (see `nivpjax.learn.tasks`):

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python examples/learn_relay_sliding.py [--iterations N]
"""

from _learn import main


if __name__ == "__main__":
    main("relay_sliding")
