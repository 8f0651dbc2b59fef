"""Shared pieces of the calibration examples: the observed solve, noise, the report and
the figure."""

import numpy as np

import nivpjax as nj


def observe(scene, t1, x0, args, times, **controller):
    """The scene's states at `times`: the solve every example differentiates (Bathe, PID at
    rtol 1e-6 / atol 1e-9 plus `controller` options, forward-mode adjoint for the
    Levenberg-Marquardt Jacobian, failures left to `fit` through the result code)."""
    sol = scene.solve(
        0.0,
        t1,
        x0,
        args,
        stepper=nj.Bathe(),
        controller=nj.PIDController(rtol=1e-6, atol=1e-9, **controller),
        t_eval=times,
        max_steps=4096,
        adjoint="forward",
        throw=False,
    )
    return sol.y_eval


def noisy(values, sigma, seed=0):
    """`values` plus Gaussian noise of standard deviation `sigma` (NumPy, seeded)."""
    rng = np.random.default_rng(seed)
    return np.asarray(values) + sigma * rng.standard_normal(np.shape(values))


def report(names, truth, start, fit):
    """Print estimate, standard error and error per parameter; return the largest relative
    error."""
    worst = 0.0
    print("parameter      truth      start     estimate     stderr    error")
    for name in names:
        est, se = float(fit.params[name]), float(fit.stderr[name])
        err = abs(est - truth[name]) / abs(truth[name])
        worst = max(worst, err)
        print(
            f"{name:>10} {truth[name]:10.4g} {float(start[name]):10.4g} {est:12.6g} "
            f"{se:10.2g} {100 * err:7.2f}%"
        )
    print(f"Levenberg-Marquardt steps: {int(fit.steps)}, noise estimate {float(fit.sigma):.3g}")
    return worst


def figure(path, title, t_data, data, t_fit, curves, histories, ylabel):
    """Left: data and fitted trajectory (`curves`: label -> values on `t_fit`); right: the
    loss against iterations for each run in `histories` (label -> array, NaN past the
    end)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    ax1.plot(t_data, data, ".", color="0.4", label="noisy data")
    for label, values in curves.items():
        ax1.plot(t_fit, values, label=label)
    ax1.set_xlabel("t")
    ax1.set_ylabel(ylabel)
    ax1.legend()
    ax1.set_title(title)
    for label, h in histories.items():
        h = np.asarray(h)
        h = h[np.isfinite(h)]
        ax2.semilogy(np.arange(h.size), h, "o-", label=label)
    ax2.set_xlabel("Levenberg-Marquardt step")
    ax2.set_ylabel("loss 0.5 |r|^2")
    ax2.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")
