"""Train the shipped step-size policy of the `stick_slip` task (see `nivpjax.learn.tasks`):

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python examples/learn_stick_slip.py [--iterations N]
"""

from _learn import main


if __name__ == "__main__":
    main("stick_slip")
