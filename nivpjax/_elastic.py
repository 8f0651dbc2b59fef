r"""Elastic stiffness kernels of a fault plane: a dense matrix, or a periodic spectral
symbol applied by FFT. Used by [`nivpjax.scenes.fault`][]; both apply $K u$ and
$K^{1/2} v$ with matrix-vector products only, so a step's cost is that of its kernel
products (a dense matrix: $O(N^2)$; the spectral symbol: $O(N \log N)$)."""

import jax.numpy as jnp
import numpy as np


def dense_eig(K):
    r"""`(lam, Q)`, $K = Q\,\mathrm{diag}(\lambda)\,Q^T$ (NumPy `eigh`), of a symmetric
    positive definite matrix. Raises `ValueError` if `K` is not symmetric positive
    definite. One `eigh` serves the square root and the solves of a fault's set-up (at
    10^4 cells it takes two minutes on one core)."""
    K = np.asarray(K, dtype=float)
    if K.ndim != 2 or K.shape[0] != K.shape[1]:
        raise ValueError(f"`kernel` must be a square matrix, got shape {K.shape}.")
    if not np.allclose(K, K.T, rtol=1e-10, atol=1e-12 * np.abs(K).max()):
        raise ValueError("`kernel` must be symmetric.")
    lam, Q = np.linalg.eigh(0.5 * (K + K.T))
    if lam[0] <= 0:
        raise ValueError(
            f"`kernel` must be positive definite after the study's sign (-file), got the "
            f"smallest eigenvalue {lam[0]:.3g}."
        )
    return lam, Q


def dense_root(K, eig=None):
    r"""The symmetric square root $K^{1/2} = Q \Lambda^{1/2} Q^T$ of a symmetric positive
    definite matrix (NumPy), from `eig` = `dense_eig(K)` where given. Raises `ValueError`
    if `K` is not symmetric positive definite."""
    lam, Q = dense_eig(K) if eig is None else eig
    return (Q * np.sqrt(lam)) @ Q.T


def spectral_symbol(nx, nz, length_x, length_z, poisson=0.0, k_floor=None):
    r"""The stiffness symbol $\lambda(k)$ of a periodic fault plane of
    `length_x` $\times$ `length_z` (nondimensional lengths) on `nx` $\times$ `nz` cells,
    slip along $x$:

    $$ \lambda(k) = \frac{k_x^2/(1 - \nu) + k_z^2 + k_0^2}{2\sqrt{k_x^2 + k_z^2 + k_0^2}}, $$

    the full-space quasi-static stress of a sinusoidal slip per unit shear modulus
    ($\nu = 0$: the antiplane form $|k|/2$). The floor $k_0$ (default $2\pi/\max(L_x, L_z)$,
    the longest wave of the box) gives uniform slip a finite stiffness, without which a
    periodic fault has none. Shape `(nz, nx // 2 + 1)`, the layout of `rfft2` on the
    cells reshaped to `(nz, nx)`."""
    if k_floor is None:
        k_floor = 2 * np.pi / max(length_x, length_z)
    if not k_floor > 0:
        raise ValueError(f"`k_floor` must be positive (or None), got {k_floor}.")
    if not -1.0 <= poisson < 1.0:
        raise ValueError(f"`poisson` must lie in [-1, 1), got {poisson}.")
    kx = 2 * np.pi * np.fft.rfftfreq(nx, d=length_x / nx)
    kz = 2 * np.pi * np.fft.fftfreq(nz, d=length_z / nz)
    kx2, kz2 = kx[None, :] ** 2, kz[:, None] ** 2
    k2 = kx2 + kz2 + k_floor**2
    return (kx2 / (1 - poisson) + kz2 + k_floor**2) / (2 * np.sqrt(k2))


def spectral_apply(symbol, u, nx, nz):
    r"""$F^{-1}\,\mathrm{diag}(\lambda)\,F u$ for cells ordered $p = i_x + i_z n_x$ (a
    real, even symbol: the result is the periodic convolution, symmetric in $u$)."""
    grid = u.reshape(u.shape[:-1] + (nz, nx))
    out = jnp.fft.irfft2(symbol * jnp.fft.rfft2(grid), s=(nz, nx))
    return out.reshape(u.shape)


def spectral_apply_np(symbol, u, nx, nz):
    """`spectral_apply` in NumPy (set-up: initial states, normalisation)."""
    grid = np.asarray(u).reshape(nz, nx)
    return np.fft.irfft2(symbol * np.fft.rfft2(grid), s=(nz, nx)).ravel()
