"""Training tasks on the evidence scenes: each draws scene parameters at random.

Scenes and samplers are built once per process, so that equal tasks share compiled
programs."""

import functools

import jax
import jax.numpy as jnp
import jax.random as jr

from .. import scenes
from ._task import Task


def _uniform(key, lo, hi):
    return jr.uniform(key, (), minval=lo, maxval=hi)


@functools.cache
def _scene(name):
    # Cached for the process and possibly first built inside a trace (the samplers run
    # under jit): its arrays must be concrete, never that trace's tracers, which a later
    # trace would take silently as constants (see `nivpjax._custom_types.runtime_float`).
    with jax.ensure_compile_time_eval():
        return _build_scene(name)


def _build_scene(name):
    if name == "ball":
        return scenes.bouncing_ball()
    if name == "slider":
        return scenes.spring_slider(mu_static=0.6, mu_kinetic=0.3, slip_scale=0.05, velocity=0.0)
    if name == "relay":
        return scenes.relay()
    return scenes.half_wave_rectifier()


def _ball_sample(key):
    k1, k2 = jr.split(key)
    x0 = jnp.stack([_uniform(k1, 0.5, 1.5), jnp.zeros(())])
    return x0, {"e": _uniform(k2, 0.5, 0.8), "g": jnp.asarray(9.81)}


def _slider_sample(key):
    k1, k2 = jr.split(key)
    args = dict(_scene("slider")[2])
    args["V"] = _uniform(k1, 0.05, 0.2)
    args["mu_s"] = _uniform(k2, 0.5, 0.7)
    return jnp.zeros(2), args


def _relay_sample(key):
    k1, k2, k3 = jr.split(key, 3)
    x0 = jnp.stack([_uniform(k3, 0.2, 0.8)])
    return x0, {"amplitude": _uniform(k1, 0.6, 1.4), "frequency": _uniform(k2, 0.5, 1.5)}


def _rectifier_sample(key):
    k1, k2 = jr.split(key)
    args = dict(_scene("rectifier")[2])
    args["V"] = _uniform(k1, 0.5, 2.0)
    args["R_L"] = _uniform(k2, 200.0, 2000.0)
    return jnp.zeros(1), args


def ball_zeno(**kwargs) -> Task:
    """A ball dropped from height $H \\in [0.5, 1.5]$ with restitution $e \\in [0.5, 0.8]$,
    integrated through its Zeno point (it ends at rest on the floor)."""
    kwargs.setdefault("max_steps", 3000)
    return Task(_scene("ball")[0], _ball_sample, t1=kwargs.pop("t1", 3.0), **kwargs)


def stick_slip(**kwargs) -> Task:
    """A spring slider under a slow drive $V \\in [0.05, 0.2]$ with static friction above
    kinetic ($\\mu_s \\in [0.5, 0.7]$, $\\mu_k = 0.3$): stick-slip cycles."""
    kwargs.setdefault("max_steps", 2000)
    return Task(_scene("slider")[0], _slider_sample, t1=kwargs.pop("t1", 20.0), **kwargs)


def relay_sliding(**kwargs) -> Task:
    """Relay feedback $x' = -\\operatorname{sign}(x) + a\\sin(2\\pi f t)$ with
    $a \\in [0.6, 1.4]$ (above 1 the state leaves the sliding surface each period),
    $f \\in [0.5, 1.5]$."""
    return Task(_scene("relay")[0], _relay_sample, t1=kwargs.pop("t1", 3.0), **kwargs)


def rectifier(**kwargs) -> Task:
    """A half-wave diode rectifier, amplitude $V \\in [0.5, 2]$, load $R_L \\in [200, 2000]$,
    over three 50 Hz periods."""
    return Task(_scene("rectifier")[0], _rectifier_sample, t1=kwargs.pop("t1", 0.06), **kwargs)


TASKS = {
    "ball_zeno": ball_zeno,
    "stick_slip": stick_slip,
    "relay_sliding": relay_sliding,
    "rectifier": rectifier,
}
