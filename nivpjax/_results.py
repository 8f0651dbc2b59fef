"""Result codes. Failures are values inside compiled code and exceptions at the public boundary."""

import warnings

import optimistix as optx


# `successful` is inherited from optimistix with the empty message, which printed as
# `RESULTS<>`. Redefining it gives it a readable one (`print(sol.result)` shows
# `nivpjax.RESULTS<successful>`); equinox warns that the message changed, which is the point.
with warnings.catch_warnings():
    warnings.filterwarnings("ignore", "Enumeration has duplicate incompatible values")

    class RESULTS(optx.RESULTS):  # pyright: ignore[reportGeneralTypeIssues]
        __module__ = "nivpjax"  # the public name, in its repr
        successful = "successful"
        nonlinear_failure = (
            "The nonlinear solve of an implicit step did not converge, and shrinking the step "
            "did not help before `h_min` was reached. Try a smaller `h_min`, a larger solver "
            "`max_steps`, looser solver tolerances, or the other nonlinear solver."
        )
        h_min_reached = (
            "The step size fell below `h_min` while the local error was still too large. The "
            "problem may be too stiff for the tolerances, have a discontinuity the scheme "
            "cannot step over, or events that accumulate (a Zeno point) closer than `h_min` "
            "apart before the state is within tolerance of their limit; loosen `rtol`/`atol` "
            "or lower `h_min`."
        )
        time_max_steps_reached = (
            "The maximum number of time steps was reached before `t1`. Increase `max_steps`."
        )
        initial_state_infeasible = (
            "The initial state violates a constraint that the integrator cannot restore (e.g. a "
            "contact that starts penetrated: velocity-level contact never pushes a body out). "
            "Move `y0` into the admissible set."
        )
        line_search_failure = (
            "The Armijo line search of semismooth Newton found no step that decreases the merit."
        )
        nonfinite_y0 = (
            "`y0` contains NaN or inf (a traced `y0`, checked inside the compiled program)."
        )
        empty_span = (
            "`t1` must be greater than `t0` (traced times, checked inside the compiled program)."
        )
