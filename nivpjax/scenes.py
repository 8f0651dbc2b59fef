"""A library of classic nonsmooth systems, each built as a [`nivpjax.Scene`][].

Every constructor returns `(scene, x0, args)`: the scene, a default initial state and the
parameters as a dict of arrays (a pytree: `vmap` and `grad` over any entry). Solve with
`scene.solve(t0, t1, x0, args, ...)` and read states and multipliers with `scene.split`.
"""

import jax
import jax.numpy as jnp
import numpy as np

from ._elastic import dense_eig, dense_root, spectral_apply, spectral_apply_np, spectral_symbol
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


def block_on_plane(mu=0.3, gravity=9.81, velocity=(2.0, 1.0), cone=False, push=None):
    r"""A block sliding on a horizontal plane with isotropic Coulomb friction, sliding to
    rest along a straight line: $|v|$ decreases at the rate $\mu g$, it stops at
    $t^* = |v_0|/(\mu g)$ after a distance $|v_0|^2/(2\mu g)$.

    `push=(A, omega)` adds a rotating horizontal force per unit mass
    $F(t) = A(\cos\omega t, \sin\omega t)$ (`args["A"]`, `args["omega"]`): the block then
    slides along a curve, $v_t' = F(t) - \mu g\,v_t/|v_t|$ while $v_t \ne 0$, a smooth ODE
    when the speed stays away from zero (the reaction's direction turns with the velocity).

    `cone=False`: 2-D disk friction on $x = (p_x, p_y, v_x, v_y)$ (no extra states).
    `cone=True`: 3-D frictional contact with the normal direction resolved, on
    $x = (p_x, p_y, p_z, v_x, v_y, v_z)$ with multipliers $\lambda = (\lambda_n,
    \lambda_{t1}, \lambda_{t2})$ (forces per unit mass) in the second-order cone
    $K_\mu$, complementary to De Saxcé's modified velocity
    $(v_n + \mu|v_t|, v_t) \in K_\mu^*$ (multiplier `"lam"`).
    """
    args = {"mu": _f(mu), "g": _f(gravity)}
    if push is not None:
        args.update(A=_f(push[0]), omega=_f(push[1]))

    def force(t, a, dtype):
        if push is None:
            return jnp.zeros(2, dtype)
        angle = a["omega"] * t
        return a["A"] * jnp.stack([jnp.cos(angle), jnp.sin(angle)]).astype(dtype)

    if not cone:

        def dynamics(t, x, a, m):
            return jnp.concatenate([x[2:], force(t, a, x.dtype)])

        friction = Friction([2, 3], lambda t, x, a: a["mu"] * a["g"], isotropic=True)
        return Scene(dynamics, 4, (friction,)), _f([0.0, 0.0, *velocity]), args

    def dynamics(t, x, a, m):
        lam, push_t = m["lam"], force(t, a, x.dtype)
        total = jnp.stack([lam[1] + push_t[0], lam[2] + push_t[1], lam[0] - a["g"]])
        return jnp.concatenate([x[3:], total])

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
    radius=1.0,
    gravity=9.81,
    position=(0.0, -1.0),
    velocity=(1.0, 0.0),
    restitution=0.0,
    friction=None,
    axes=None,
):
    r"""A ball (a point of unit mass) inside a spherical bowl of radius $R$ under gravity:
    $q'' = -g\,e_d$ with the unilateral contact $g(q) = R - |q| \ge 0$ and Newton
    restitution $e$, in as many dimensions as `position` has (2: a circular wall, 3: a
    sphere; gravity along the last axis). State $x = (q, v)$; `args = {"R", "g", "e"}`
    (and `"mu"` with friction, `"axes"` with axes).

    A closed contact on a curved gap: while the ball stays on the wall it is a pendulum,
    $\varphi'' = -(g/R)\sin\varphi$ in 2-D ($\varphi$ from the bottom), pressed by the
    normal force $N = R\varphi'^2 + g\cos\varphi$ (per unit mass). Thrown from the bottom
    with speed $v_0$, $2gR < v_0^2 < 5gR$, it leaves the wall where $N$ reaches zero,
    $\cos\varphi_r = (2g R - v_0^2)/(3gR)$, flies a parabola inside the bowl and lands on
    the wall again. With `gravity=0` it is a bead running uniformly round a circular wall
    that pushes with $v^2/R$.

    - `friction`: Coulomb's $\mu$ on the wall (`None`: frictionless; see
      [`nivpjax.FrictionalContact`][]).
    - `axes`: semi-axes $a_i$ of an ellipsoidal bowl (`radius` is then unused), gap
      $a_{\min}(1 - |D^{-1} q|)$ with $D = \operatorname{diag}(a)$: zero on the wall,
      $R - |q|$ for equal axes, a distance to first order up to the factor
      $a_{\min} |\nabla\,|D^{-1}q|| \le 1$. Its curvature varies along the wall.

    With friction, in 2-D, the ball slides on the wall with
    $\varphi'' = -(g/R)\sin\varphi - \mu\,\sigma N/R$, $\sigma$ the sign of
    $\varphi'$, until $\varphi' = 0$: there it sticks for good if
    $|\tan\varphi| \le \mu$ and turns back otherwise.
    """
    d = len(position)
    if d < 2 or len(velocity) != d:
        raise ValueError(
            "`position` and `velocity` must have the same length, 2 or more, got "
            f"{len(position)} and {len(velocity)}."
        )
    if axes is not None:
        axes = np.asarray(axes, dtype=float)
        if axes.shape != (d,) or not np.all(np.isfinite(axes)) or np.any(axes <= 0):
            raise ValueError(
                f"`axes` must be {d} finite semi-axes > 0 (one per coordinate), got {axes!r}."
            )

    def dynamics(t, x, a, m):
        down = jnp.zeros(d, x.dtype).at[-1].set(-a["g"])
        return jnp.concatenate([x[d:], down])

    def gap(t, x, a):
        q = x[:d] if axes is None else x[:d] / a["axes"]
        sq = jnp.sum(q**2)
        # |q| with a finite derivative at the centre (which a flight may cross).
        norm = jnp.where(sq > 0, jnp.sqrt(jnp.where(sq > 0, sq, 1.0)), 0.0)
        if axes is None:
            return jnp.stack([a["R"] - norm])
        return jnp.stack([jnp.min(a["axes"]) * (1.0 - norm)])

    contact = Contact(
        gap,
        positions=np.arange(d),
        velocities=np.arange(d, 2 * d),
        restitution=lambda t, y, a: a["e"],
        curved=True,
        friction=None if friction is None else (lambda t, y, a: a["mu"]),
    )
    x0 = _f([*position, *velocity])
    args = {"R": _f(radius), "g": _f(gravity), "e": _f(restitution)}
    if friction is not None:
        args["mu"] = _f(friction)
    if axes is not None:
        args["axes"] = _f(axes)
    return Scene(dynamics, 2 * d, (contact,)), x0, args


def fault_units(length=3.0, shear_modulus=3e4, density=2.5e-3, slip_unit=0.1):
    r"""The units of [`nivpjax.scenes.fault`][]'s nondimensional variables, as the study
    sets them (lengths in mm, stresses in MPa, times in ms, densities in g/mm$^3$): the
    patch length $L$ (`length` in km), the slip unit $D$ (`slip_unit` in mm), the stress
    unit $G D / L$, the time unit $L / c_s$ with $c_s = \sqrt{G/\rho}$, and the velocity
    unit $D c_s / L$. Returns a dict `{"length_mm", "slip_mm", "stress_MPa", "time_ms",
    "velocity_mm_per_ms"}`; e.g. $L = 3$ km: stress 1e-3 MPa, time 866.03 ms."""
    L = length * 1e6
    c_s = np.sqrt(shear_modulus / density)
    return dict(
        length_mm=L,
        slip_mm=slip_unit,
        stress_MPa=shear_modulus * slip_unit / L,
        time_ms=L / c_s,
        velocity_mm_per_ms=slip_unit * c_s / L,
    )


def load_fault_kernel(path):
    r"""The study's stiffness kernel from one of its `.npy` files (`kijs_*.npy`, stress
    per unit slip and shear modulus in 1/km): $-10^{-6} \times$ file, in 1/mm, a symmetric
    positive definite matrix for [`nivpjax.scenes.fault`][] (which rescales it; see there).
    Cells are ordered $p = i_x + i_z n_x$."""
    K = -1e-6 * np.load(path)
    if K.ndim != 2 or K.shape[0] != K.shape[1]:
        raise ValueError(f"the kernel in {path!r} must be a square matrix, got {K.shape}.")
    return K


def _fault_grid(kernel, nx, nz):
    if isinstance(kernel, str):
        if kernel != "spectral":
            raise ValueError(f"`kernel` must be 'spectral' or a square matrix, got {kernel!r}.")
        nx, nz = (32 if nx is None else nx), (32 if nz is None else nz)
        return nx, nz
    n = np.shape(kernel)[0]
    if nx is None and nz is None:
        nx = nz = int(round(np.sqrt(n)))
    elif nx is None or nz is None:
        nx, nz = (n // nz, nz) if nx is None else (nx, n // nx)
    if nx * nz != n or np.shape(kernel) != (n, n):
        raise ValueError(
            f"`kernel` must be ({nx * nz}, {nx * nz}) for nx={nx}, nz={nz}, got {np.shape(kernel)}."
        )
    return nx, nz


def fault(
    kernel="spectral",
    nx=None,
    nz=None,
    *,
    length=3.0,
    depth=3.0,
    zeta=0.8 / 3,
    mu_res=0.5,
    delta_mu=0.1,
    Dc=1000.0,
    v_inf=0.0,
    overshoot=1e-5,
    sigma=None,
    sigma_gradient=15.0,
    shear_modulus=3e4,
    slip_unit=0.1,
    normalise=True,
    poisson=0.0,
    k_floor=None,
):
    r"""A vertical strike-slip fault patch of $N = n_x n_z$ frictional cells (the reference's
    companion study), nondimensional, cells ordered $p = i_x + i_z n_x$ ($i_z = 0$ at the
    top):

    $$ \begin{gathered}
       v' = -K u - E (v - v_\infty) - r, \qquad r \in \mu(s)\,\sigma\,\partial|v|, \\
       u' = v - v_\infty, \qquad s' = |v|, \qquad
       \mu(s) = \mu_r + \Delta\mu\, e^{-s/D_c}, \qquad E = 2\zeta K^{1/2},
       \end{gathered} $$

    slip rate $v$, displacement $u$ relative to the load point (driven at $v_\infty$) and
    cumulated slip $s$ per cell, Coulomb friction with a slip-weakening bound on each cell
    ([`nivpjax.Friction`][] on the $N$ velocities), modal damping $E$ (symmetric square
    root). State $x = (v_0..v_{N-1}, u_0..u_{N-1}, s_0..s_{N-1})$ (three blocks).

    **Units** ([`nivpjax.scenes.fault_units`][]): slip by $D$ = `slip_unit` (0.1 mm),
    lengths by $L$ = `length` (the patch's length along strike, km), stresses by $G D/L$,
    times by $L/c_s$; the inertia per unit area is then 1. The effective normal stress is
    $\sigma = $ `sigma_gradient` $\times z$ MPa at each cell's centre depth $z$ (km),
    divided by the stress unit (`sigma` overrides it: a scalar or one value per cell).

    **Kernel** $K$ (stress per unit slip, nondimensional):

    - a dense symmetric positive definite matrix (the study's form; e.g.
      [`nivpjax.scenes.load_fault_kernel`][] of its files). $K^{1/2}$ by `eigh`. A step
      costs two $O(N^2)$ products $K u$, $K^{1/2} v$ per residual evaluation.
    - `"spectral"`: a periodic fault of `length` $\times$ `depth`, $K = F^{-1}
      \mathrm{diag}(\lambda) F$ with the quasi-static symbol of
      `nivpjax._elastic.spectral_symbol` ($|k|/2$ for `poisson=0`, floored at `k_floor`);
      $K^{1/2}$ has the symbol $\sqrt\lambda$, so a residual costs $O(N \log N)$.

    With `normalise=True` (the study's convention) $K$ is scaled by the one factor that
    makes $\overline{K^{-1}\sigma} = \bar\sigma$ (one cell: $K = 1$; any scalar factor of
    the kernel passed in, its sign included, drops out). The initial state is the
    study's: $v = s = 0$, $u = (1 + \text{overshoot})\, u_c$, $u_c = -K^{-1}\mu(0)\sigma$,
    each cell just past its static limit, so that one rupture nucleates, spreads and
    arrests. The study runs $t \in [0, 34.641]$ (30 s at $L$ = 3 km).

    A note on $s' = |v|$: in a stick $v = 0$ exactly (the friction's projection), where
    $|v|$ has a kink; $s$ is still $C^1$ in time between switches, and Newton takes the
    element $\operatorname{sign}(0) = 0$ of its generalised derivative there, which is
    exact on a stuck cell.

    `args`: `K` and `R` ($K^{1/2}$) for a dense kernel, `symbol` for the spectral one, and
    `zeta, mu_res, delta_mu, Dc, sigma, v_inf` (arrays: `vmap` and `grad` over any).
    """
    nx, nz = _fault_grid(kernel, nx, nz)
    n = nx * nz
    units = fault_units(length, shear_modulus, slip_unit=slip_unit)
    depths = (np.arange(n) // nx + 0.5) * depth / nz
    if sigma is None:
        sigma = sigma_gradient * depths / units["stress_MPa"]
    sigma = np.broadcast_to(np.asarray(sigma, dtype=float), (n,))
    spectral = isinstance(kernel, str)
    if spectral:
        symbol = spectral_symbol(nx, nz, 1.0, depth / length, poisson, k_floor)

        def solve_K(b):
            return spectral_apply_np(1.0 / symbol, b, nx, nz)

    else:
        K = np.asarray(kernel, dtype=float)
        lam, Q = dense_eig(K)  # symmetric positive definite, checked before any work

        def solve_K(b):
            return Q @ ((Q.T @ b) / lam)

    scale = np.mean(solve_K(sigma)) / np.mean(sigma) if normalise else 1.0
    u_c = -solve_K((mu_res + delta_mu) * sigma) / scale
    if spectral:
        kernel_args = {"symbol": _f(scale * symbol)}
    else:
        if not scale > 0:
            raise ValueError(
                "`kernel`: the normalisation mean(K^-1 sigma) / mean(sigma) must be positive, "
                f"got {scale:.3g}; pass normalise=False or a kernel of the study's sign."
            )
        kernel_args = {"K": _f(scale * K), "R": _f(dense_root(K, (scale * lam, Q)))}

    def apply(a, w, root):
        if spectral:
            sym = jnp.sqrt(a["symbol"]) if root else a["symbol"]
            return spectral_apply(sym.astype(w.dtype), w, nx, nz)
        return (a["R"] if root else a["K"]) @ w

    def dynamics(t, x, a, m):
        v, u = x[:n], x[n : 2 * n]
        slip_rate = v - a["v_inf"]
        dv = -apply(a, u, False) - 2 * a["zeta"] * apply(a, slip_rate, True)
        return jnp.concatenate([dv, slip_rate, jnp.abs(v)])

    def bound(t, x, a):
        return (a["mu_res"] + a["delta_mu"] * jnp.exp(-x[2 * n :] / a["Dc"])) * a["sigma"]

    scene = Scene(dynamics, 3 * n, (Friction(velocities=np.arange(n), bound=bound),))
    x0 = np.concatenate([np.zeros(n), (1 + overshoot) * u_c, np.zeros(n)])
    args = dict(
        kernel_args,
        zeta=_f(zeta),
        mu_res=_f(mu_res),
        delta_mu=_f(delta_mu),
        Dc=_f(Dc),
        sigma=_f(sigma),
        v_inf=_f(v_inf),
    )
    return scene, _f(x0), args


def spring_block_chain(
    n=40,
    mass=1.0,
    coupling=1.0,
    stiffness=1.0,
    damping=0.0,
    normal=1.0,
    mu_static=0.6,
    mu_kinetic=0.3,
    slip_scale=1.0,
    drive_velocity=0.1,
    perturbation=1e-2,
    seed=0,
):
    r"""A Burridge–Knopoff chain: `n` blocks, each on a spring $k_p$ to a load point driven
    at $V$, neighbours joined by springs $k_c$ (free ends), Coulomb friction with slip
    weakening on every block:

    $$ \begin{gathered}
       m s_i'' = k_c (s_{i+1} - 2 s_i + s_{i-1}) + k_p (V t - s_i) \\
       - c\, s_i' - \mu(s_i) N \operatorname{Sign}(s_i'), \\
       \mu(s) = \mu_k + (\mu_s - \mu_k) e^{-|s|/D_c}, \end{gathered} $$

    (the missing neighbour of an end block is replaced by the block itself). One block is
    [`nivpjax.scenes.spring_slider`][]. State $x = (s_0..s_{n-1}, v_0..v_{n-1})$, friction
    on the $n$ velocities ([`nivpjax.Friction`][], no extra states); the blocks start at
    rest, displaced by `perturbation` $\times$ uniform$(-1, 1)$ draws (`seed`), which
    breaks the symmetry between them. `args`: `m, kc, kp, c, N, mu_s, mu_k, Dc, V`.
    """
    if n < 1:
        raise ValueError(f"`n` must be a positive number of blocks, got {n}.")

    def dynamics(t, x, a, m):
        s, v = x[:n], x[n:]
        padded = jnp.concatenate([s[:1], s, s[-1:]])
        coupling_force = a["kc"] * (padded[2:] - 2 * s + padded[:-2])
        force = coupling_force + a["kp"] * (a["V"] * t - s) - a["c"] * v
        return jnp.concatenate([v, force / a["m"]])

    def bound(t, x, a):
        mu = a["mu_k"] + (a["mu_s"] - a["mu_k"]) * jnp.exp(-jnp.abs(x[:n]) / a["Dc"])
        return mu * a["N"] / a["m"]

    scene = Scene(dynamics, 2 * n, (Friction(velocities=np.arange(n, 2 * n), bound=bound),))
    s0 = perturbation * np.random.default_rng(seed).uniform(-1.0, 1.0, n)
    args = dict(
        m=_f(mass),
        kc=_f(coupling),
        kp=_f(stiffness),
        c=_f(damping),
        N=_f(normal),
        mu_s=_f(mu_static),
        mu_k=_f(mu_kinetic),
        Dc=_f(slip_scale),
        V=_f(drive_velocity),
    )
    return scene, _f(np.concatenate([s0, np.zeros(n)])), args


def chain_of_balls(n=100, radius=0.5, restitution=1.0, spacing=0.0, velocity=1.0):
    r"""A horizontal chain of `n` unit balls of radius $r$ on a line (no gravity), the
    first one thrown at the others with `velocity`: gaps $q_{i+1} - q_i - 2r \ge 0$,
    Newton restitution $e$ at every contact (`n - 1` contacts, simultaneous when the
    balls touch; as in Siconos' ChainOfBalls). State $x = (q_0..q_{n-1}, v_0..v_{n-1})$.

    Momentum $\sum v_i$ is kept by every impact. With `spacing > 0` and $e = 1$ the
    impacts come one at a time, each an exchange of velocities (Newton's cradle): the
    last ball leaves with `velocity` at $t = (n - 1)\,d/v_0$ ($d$ = `spacing`) and the
    others rest, energy kept. With `spacing=0` all contacts are closed at once and the
    velocity-level impact law decides them together (with $e = 0$ the chain moves on as
    one body at $v_0/n$). `args = {"e": e}`.
    """
    if n < 2:
        raise ValueError(f"`n` must be at least 2 balls, got {n}.")

    def dynamics(t, x, a, m):
        return jnp.concatenate([x[n:], jnp.zeros(n, x.dtype)])

    def gap(t, x, a):
        q = x[:n]
        return q[1:] - q[:-1] - 2 * radius

    contact = Contact(
        gap,
        positions=np.arange(n),
        velocities=np.arange(n, 2 * n),
        restitution=lambda t, y, a: a["e"],
    )
    q0 = np.arange(n) * (2 * radius + spacing)
    v0 = np.zeros(n)
    v0[0] = velocity
    x0 = _f(np.concatenate([q0, v0]))
    return Scene(dynamics, 2 * n, (contact,)), x0, {"e": _f(restitution)}
