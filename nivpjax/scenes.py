"""A library of classic nonsmooth systems, each built as a [`nivpjax.Scene`][].

Every constructor returns `(scene, x0, args)`: the scene, a default initial state and the
parameters as a dict of arrays (a pytree: `vmap` and `grad` over any entry). Solve with
`scene.solve(t0, t1, x0, args, ...)` and read states and multipliers with `scene.split`.
"""

import jax
import jax.numpy as jnp
import numpy as np

from ._projector import SecondOrderCone
from ._scene import Contact, Diode, Friction, Relay, Saturation, Scene, SetValued


def _f(x):
    return jnp.asarray(x, dtype=float)


def bouncing_ball(restitution=0.8, gravity=9.81, height=1.0, velocity=0.0):
    r"""A ball on the floor: $q'' = -g$, $q \ge 0$, Newton restitution $e$.

    State $x = (q, v)$; `args = {"e": e, "g": g}`. Apex heights fall by $e^2$ per bounce;
    dropped from rest at height $H$ the impacts accumulate (Zeno) at
    $t_\infty = \sqrt{2H/g}\,(1 + 2e/(1 - e))$.
    """

    def dynamics(t, x, args, m):
        return jnp.stack([x[1], -args["g"] * jnp.ones_like(x[1])])

    contact = Contact(
        gap=lambda t, x, args: x[:1],
        positions=[0],
        velocities=[1],
        restitution=lambda t, y, args: args["e"],
    )
    scene = Scene(dynamics, 2, (contact,))
    return scene, _f([height, velocity]), {"e": _f(restitution), "g": _f(gravity)}


def spring_slider(
    mass=1.0,
    stiffness=1.0,
    damping=0.0,
    normal=1.0,
    mu_static=0.6,
    mu_kinetic=0.6,
    slip_scale=0.1,
    drive_velocity=0.0,
    velocity=0.1,
    position=0.0,
):
    r"""A block on a spring with Coulomb friction:

    $$ m s'' = k(V t - s) - c s' - \mu(s) N \operatorname{Sign}(s'), \qquad
       \mu(s) = \mu_k + (\mu_s - \mu_k) e^{-|s|/D_c}, $$

    a load point driven at velocity $V$ (stick-slip when $V > 0$) and slip-weakening friction
    from $\mu_s$ to $\mu_k$ over the slip distance $D_c$ (constant friction when equal).
    State $x = (s, v)$, friction acts on $v$ without extra states. `args` holds every
    parameter (`m, k, c, N, mu_s, mu_k, Dc, V`).
    """

    def dynamics(t, x, a, m):
        s, v = x
        force = a["k"] * (a["V"] * t - s) - a["c"] * v
        return jnp.stack([v, force / a["m"]])

    def bound(t, x, a):
        mu = a["mu_k"] + (a["mu_s"] - a["mu_k"]) * jnp.exp(-jnp.abs(x[0]) / a["Dc"])
        return mu * a["N"] / a["m"]

    scene = Scene(dynamics, 2, (Friction(velocities=[1], bound=bound),))
    args = dict(
        m=_f(mass),
        k=_f(stiffness),
        c=_f(damping),
        N=_f(normal),
        mu_s=_f(mu_static),
        mu_k=_f(mu_kinetic),
        Dc=_f(slip_scale),
        V=_f(drive_velocity),
    )
    return scene, _f([position, velocity]), args


def relay(amplitude=0.5, frequency=1.0, x0=0.5):
    r"""Relay feedback with a disturbance: $x' = -\operatorname{sign}(x) + d(t)$,
    $d(t) = a \sin(2\pi f t)$. With $|a| < 1$ the state reaches $x = 0$ in finite time and
    slides there for good with the Filippov selection $w = d(t)$; with $|a| > 1$ it slides
    while $|d(t)| \le 1$ and leaves the surface every half period. Multiplier `"w"`."""

    def dynamics(t, x, a, m):
        return -m["w"] + a["amplitude"] * jnp.sin(2 * jnp.pi * a["frequency"] * t)

    scene = Scene(dynamics, 1, (Relay("w", lambda t, x, a: x[:1]),))
    return scene, _f([x0]), {"amplitude": _f(amplitude), "frequency": _f(frequency)}


@jax.custom_jvp
def sqrt_abs(s):
    r"""$\sqrt{|s|}$ with a bounded derivative: the slope $1/(2\sqrt{|s|})$ is capped at
    $1/(2\sqrt{\delta})$, $\delta = 10^{-12}$ (the value is exact). Newton's Jacobian stays
    finite on the sliding surface $s = 0$, where the super-twisting term vanishes anyway."""
    return jnp.sqrt(jnp.abs(s))


@sqrt_abs.defjvp
def _sqrt_abs_jvp(primals, tangents):
    (s,), (ds,) = primals, tangents
    slope = 0.5 / jnp.sqrt(jnp.maximum(jnp.abs(s), 1e-12))
    return sqrt_abs(s), jnp.sign(s) * slope * ds


def super_twisting(k1=None, k2=None, c=1.0, lipschitz=1.5, x0=(0.5, 0.0)):
    r"""The super-twisting sliding-mode controller on a double integrator with a bounded
    disturbance $d(t) = 0.3\sin 5t$:

    $$ \begin{gathered}
       x_1' = x_2, \quad x_2' = u + d(t), \quad \sigma = x_2 + c x_1, \\
       u = -k_1 \sqrt{|\sigma|}\,w + \nu, \quad \nu' = -k_2 w,
       \quad w \in \operatorname{sign}(\sigma).
       \end{gathered} $$

    With $k_1 = 1.5\sqrt{L}$, $k_2 = 1.1 L$ ($L$ bounding $|\dot d|$) $\sigma$ reaches 0 in
    finite time and stays there without chattering; then $x_1$ decays like $e^{-ct}$.
    State $x = (x_1, x_2, \nu)$, multiplier `"w"`.
    """
    L = lipschitz
    k1 = 1.5 * np.sqrt(L) if k1 is None else k1
    k2 = 1.1 * L if k2 is None else k2

    def sigma(x, a):
        return x[1] + a["c"] * x[0]

    def dynamics(t, x, a, m):
        w = m["w"][0]
        s = sigma(x, a)
        u = -a["k1"] * sqrt_abs(s) * w + x[2]
        d = 0.3 * jnp.sin(5.0 * t)
        return jnp.stack([x[1], u + d, -a["k2"] * w])

    scene = Scene(dynamics, 3, (Relay("w", lambda t, x, a: sigma(x, a)[None]),))
    args = {"k1": _f(k1), "k2": _f(k2), "c": _f(c)}
    return scene, _f([x0[0], x0[1], 0.0]), args


def half_wave_rectifier(amplitude=1.0, omega=2 * np.pi * 50, R_s=1.0, R_L=1000.0, C=1e-4):
    r"""A half-wave rectifier: source $V\sin\omega t$, an ideal diode with series resistance
    $R_s$, and an $RC$ load. $C v' = i - v/R_L$, $0 \le i \perp (V\sin\omega t - v - R_s i)
    \le 0$ complementarity, i.e. $i = \max(0, (V\sin\omega t - v)/R_s)$. State $x = (v)$,
    multiplier `"i"` (diode current)."""

    def dynamics(t, x, a, m):
        return (m["i"] - x / a["R_L"]) / a["C"]

    def voltage(t, x, i, a):
        return a["V"] * jnp.sin(a["omega"] * t) - x - a["R_s"] * i

    scene = Scene(dynamics, 1, (Diode("i", voltage),))
    args = dict(V=_f(amplitude), omega=_f(omega), R_s=_f(R_s), R_L=_f(R_L), C=_f(C))
    return scene, _f([0.0]), args


def diode_bridge(amplitude=1.0, omega=2 * np.pi * 50, R_s=1.0, R_L=1000.0, C=1e-4):
    r"""A four-diode (Graetz) bridge full-wave rectifier with an $RC$ load. Diodes $D_1, D_2$
    conduct on the positive half-wave, $D_3, D_4$ on the negative one; each pair has series
    resistance $R_s$. With load voltage $v$: $C v' = i_{12} + i_{34} - v/R_L$ and
    $0 \le i_{12} \perp (V\sin\omega t - v - R_s i_{12}) \le 0$,
    $0 \le i_{34} \perp (-V\sin\omega t - v - R_s i_{34}) \le 0$
    (a pair in series conducts the same current). Multiplier `"i"` = $(i_{12}, i_{34})$."""

    def dynamics(t, x, a, m):
        return (jnp.sum(m["i"]) - x / a["R_L"]) / a["C"]

    def voltage(t, x, i, a):
        src = a["V"] * jnp.sin(a["omega"] * t)
        return jnp.stack([src, -src]) - x[0] - a["R_s"] * i

    scene = Scene(dynamics, 1, (Diode("i", voltage, n=2),))
    args = dict(V=_f(amplitude), omega=_f(omega), R_s=_f(R_s), R_L=_f(R_L), C=_f(C))
    return scene, _f([0.0]), args


def chua(alpha=15.6, beta=28.0, m0=-1.143, m1=-0.714, x0=(0.7, 0.0, 0.0)):
    r"""Chua's circuit (dimensionless) with its piecewise-linear diode:

    $$ \begin{gathered}
       x' = \alpha(y - x - g(x)),\ y' = x - y + z,\ z' = -\beta y, \\
       g(x) = m_0 x + (m_1 - m_0)\,\operatorname{sat}(x),
       \end{gathered} $$

    $\operatorname{sat}(x) = \operatorname{clip}(x, -1, 1)$ as a saturation effect
    (multiplier `"sat"`). The double-scroll attractor."""

    def dynamics(t, x, a, m):
        g = a["m0"] * x[0] + (a["m1"] - a["m0"]) * m["sat"][0]
        return jnp.stack([a["alpha"] * (x[1] - x[0] - g), x[0] - x[1] + x[2], -a["beta"] * x[1]])

    scene = Scene(dynamics, 3, (Saturation("sat", lambda t, x, a: x[:1]),))
    args = dict(alpha=_f(alpha), beta=_f(beta), m0=_f(m0), m1=_f(m1))
    return scene, _f(list(x0)), args


def block_on_plane(mu=0.3, gravity=9.81, velocity=(2.0, 1.0), cone=False):
    r"""A block sliding on a horizontal plane with isotropic Coulomb friction, sliding to
    rest along a straight line: $|v|$ decreases at the rate $\mu g$, it stops at
    $t^* = |v_0|/(\mu g)$ after a distance $|v_0|^2/(2\mu g)$.

    `cone=False`: 2-D disk friction on $x = (p_x, p_y, v_x, v_y)$ (no extra states).
    `cone=True`: 3-D frictional contact with the normal direction resolved, on
    $x = (p_x, p_y, p_z, v_x, v_y, v_z)$ with multipliers $\lambda = (\lambda_n,
    \lambda_{t1}, \lambda_{t2})$ (forces per unit mass) in the second-order cone
    $K_\mu$, complementary to De Saxcé's modified velocity
    $(v_n + \mu|v_t|, v_t) \in K_\mu^*$ (multiplier `"lam"`).
    """
    args = {"mu": _f(mu), "g": _f(gravity)}
    if not cone:

        def dynamics(t, x, a, m):
            return jnp.concatenate([x[2:], jnp.zeros(2, x.dtype)])

        friction = Friction([2, 3], lambda t, x, a: a["mu"] * a["g"], isotropic=True)
        return Scene(dynamics, 4, (friction,)), _f([0.0, 0.0, *velocity]), args

    def dynamics(t, x, a, m):
        lam = m["lam"]
        force = jnp.stack([lam[1], lam[2], lam[0] - a["g"]])
        return jnp.concatenate([x[3:], force])

    def modified_velocity(t, x, lam, a):
        vt, vn = x[3:5], x[5]
        sq = jnp.sum(vt**2)
        norm = jnp.where(sq > 0, jnp.sqrt(jnp.where(sq > 0, sq, 1.0)), 0.0)
        # The stage solves lam = P_K(lam + rho * row): row = -(v_n + mu|v_t|, v_t).
        return -jnp.concatenate([jnp.stack([vn + a["mu"] * norm]), vt])

    contact = SetValued("lam", SecondOrderCone(lambda t, y, a: a["mu"]), modified_velocity, n=3)
    x0 = _f([0.0, 0.0, 0.0, *velocity, 0.0])
    return Scene(dynamics, 6, (contact,)), x0, args


def ball_stack(n=10, radius=0.5, restitution=0.0, gravity=9.81, spacing=0.0):
    r"""A vertical column of `n` balls of radius $r$ on the floor: gaps $q_0 - r$ and
    $q_i - q_{i-1} - 2r$, all contacts with restitution $e$ (`n` simultaneous contacts).
    With `spacing=0` the stack starts at rest in contact: it stays there, with contact
    forces equal to the weight carried, $(n - i)\,m g$ at contact $i$. State
    $x = (q_0..q_{n-1}, v_0..v_{n-1})$ (unit masses)."""

    def dynamics(t, x, a, m):
        return jnp.concatenate([x[n:], -a["g"] * jnp.ones(n, x.dtype)])

    def gap(t, x, a):
        q = x[:n]
        return jnp.concatenate([q[:1] - radius, q[1:] - q[:-1] - 2 * radius])

    contact = Contact(
        gap,
        positions=np.arange(n),
        velocities=np.arange(n, 2 * n),
        restitution=lambda t, y, a: a["e"],
    )
    q0 = radius + np.arange(n) * (2 * radius + spacing)
    x0 = _f(np.concatenate([q0, np.zeros(n)]))
    return Scene(dynamics, 2 * n, (contact,)), x0, {"e": _f(restitution), "g": _f(gravity)}


def filippov_spiral(stiffness=300.0, coupling=0.02, x0=(5.0, 8.0)):
    r"""A Filippov spiral into a Zeno point: $x' = -B w$, $w \in \operatorname{sign}(x)$
    componentwise, with

    $$ B = S \begin{pmatrix} a & 1 - a \\ -(1 - a) & a \end{pmatrix}. $$

    Inside each open quadrant $V = |x_1| + |x_2|$ falls at exactly $2 S a$
    ($V' = -\operatorname{sign}(x)^\top B \operatorname{sign}(x)$), so the state spirals
    into the origin at $t^* = V(0) / (2 S a)$ after infinitely many switchings, and rests
    there with $w$ inside the box. Large $S$ makes the switchings stiff. State
    $x = (x_1, x_2)$, multiplier `"w"` (two components)."""

    def dynamics(t, x, a, m):
        s, c = a["S"], a["a"]
        B = s * jnp.stack([jnp.stack([c, 1 - c]), jnp.stack([c - 1, c])])
        return -B @ m["w"]

    scene = Scene(dynamics, 2, (Relay("w", lambda t, x, a: x, n=2),))
    return scene, _f(list(x0)), {"S": _f(stiffness), "a": _f(coupling)}


def ball_in_bowl(
    radius=1.0, gravity=9.81, position=(0.0, -1.0), velocity=(1.0, 0.0), restitution=0.0
):
    r"""A ball (a point of unit mass) inside a spherical bowl of radius $R$ under gravity:
    $q'' = -g\,e_d$ with the unilateral contact $g(q) = R - |q| \ge 0$ and Newton
    restitution $e$, in as many dimensions as `position` has (2: a circular wall, 3: a
    sphere; gravity along the last axis). State $x = (q, v)$; `args = {"R", "g", "e"}`.

    A closed contact on a curved gap: while the ball stays on the wall it is a pendulum,
    $\varphi'' = -(g/R)\sin\varphi$ in 2-D ($\varphi$ from the bottom), pressed by the
    normal force $N = R\varphi'^2 + g\cos\varphi$ (per unit mass). Thrown from the bottom
    with speed $v_0$, $2gR < v_0^2 < 5gR$, it leaves the wall where $N$ reaches zero,
    $\cos\varphi_r = (2g R - v_0^2)/(3gR)$, flies a parabola inside the bowl and lands on
    the wall again. With `gravity=0` it is a bead running uniformly round a circular wall
    that pushes with $v^2/R$.
    """
    d = len(position)
    if d < 2 or len(velocity) != d:
        raise ValueError(
            "`position` and `velocity` must have the same length, 2 or more, got "
            f"{len(position)} and {len(velocity)}."
        )

    def dynamics(t, x, a, m):
        down = jnp.zeros(d, x.dtype).at[-1].set(-a["g"])
        return jnp.concatenate([x[d:], down])

    def gap(t, x, a):
        sq = jnp.sum(x[:d] ** 2)
        # |q| with a finite derivative at the centre (which a flight may cross).
        norm = jnp.where(sq > 0, jnp.sqrt(jnp.where(sq > 0, sq, 1.0)), 0.0)
        return jnp.stack([a["R"] - norm])

    contact = Contact(
        gap,
        positions=np.arange(d),
        velocities=np.arange(d, 2 * d),
        restitution=lambda t, y, a: a["e"],
        curved=True,
    )
    x0 = _f([*position, *velocity])
    args = {"R": _f(radius), "g": _f(gravity), "e": _f(restitution)}
    return Scene(dynamics, 2 * d, (contact,)), x0, args
