"""Diffuse scattering from rough surfaces: Degli-Esposti's effective-roughness model.

A surface of scattering coefficient S reflects specularly ``sqrt(1 - S^2)`` of the smooth field
(:meth:`Surface.reflection`) and scatters the power fraction ``S^2`` of the reflected power into
the half-space in front of it, with a pattern ``f_s`` (1/sr) that integrates to one over that
hemisphere. The power scattered by a tile of area ``dA`` into a unit solid angle in direction
``k_out``, for a field ``E_i`` incident at the tile, is::

    dP / dOmega = (S Gamma)^2 f_s(k_in, k_out) cos(theta_i) dA |E_i|^2,
    Gamma^2 = (|r_te E_s|^2 + |r_tm E_p|^2) / |E_i|^2

with the smooth-surface Fresnel coefficients (no ``sqrt(1 - S^2)``), split into a fraction
``1 - Kx`` in the co-polarisation and ``Kx`` in the cross-polarisation. Patterns:

- Lambertian: ``f_s = cos(theta_s) / pi``;
- directive: ``f_s = ((1 + k_r . k_s) / 2)^alpha_R / F_alpha(theta_i)``, ``k_r`` the specular
  direction and :func:`directive_normalisation` ``F_alpha`` making it integrate to one.

This is the model of Sionna RT's primer ("Scattering"), without its random phases: the
contributions of tiles are meant to be summed in power, deterministically.
"""

from __future__ import annotations

from math import comb

import numpy as np
from scipy.special import comb as binom

from .fresnel import Surface

__all__ = ["directive_normalisation", "scattering_pattern", "diffuse_matrices"]


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def directive_normalisation(alpha_r: np.ndarray | int, cos_theta_i: np.ndarray | float) -> np.ndarray:
    """``F_alpha(theta_i)``: the integral of ``((1 + k_r . k_s) / 2)^alpha`` over the hemisphere.

    ``F_alpha = 2^-alpha sum_{j=0}^{alpha} C(alpha, j) I_j`` with ``I_j = 2 pi / (j + 1)`` for
    even ``j`` and ``I_j = 2 pi / (j + 1) cos(theta_i) sum_{w=0}^{(j-1)/2} C(2w, w)
    sin^{2w}(theta_i) / 4^w`` for odd ``j`` (Degli-Esposti et al. 2007).

    Parameters
    ----------
    alpha_r : (...) int
        Lobe exponents, >= 1.
    cos_theta_i : (...) float
        Cosine of the incidence angle from the normal, in [0, 1].

    Returns
    -------
    (...) float64, steradians
    """
    alpha = np.asarray(alpha_r)
    if not np.issubdtype(alpha.dtype, np.integer) or np.any(alpha < 1):
        raise ValueError("alpha_r must be integers >= 1")
    c = np.clip(np.asarray(cos_theta_i, dtype=np.float64), 0.0, 1.0)
    alpha, c = np.broadcast_arrays(alpha, c)
    sin2 = 1.0 - c * c
    total = np.zeros(c.shape)
    odd_sum = np.zeros(c.shape)  # sum_{w <= (j-1)/2} C(2w, w) sin^{2w} / 4^w, grown with j
    for j in range(int(alpha.max(initial=1)) + 1):
        if j % 2:
            w = (j - 1) // 2
            odd_sum = odd_sum + comb(2 * w, w) * sin2**w / 4.0**w
            i_j = 2.0 * np.pi / (j + 1) * c * odd_sum
        else:
            i_j = np.full(c.shape, 2.0 * np.pi / (j + 1))
        total += binom(alpha, j) * i_j  # 0 where j > alpha
    return total / 2.0**alpha


def _front_normal(k_in: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """The unit normal on the side the incident wave comes from."""
    n = _unit(np.asarray(normal, np.float64))
    return np.where((_dot(k_in, n) > 0)[..., None], -n, n)


def scattering_pattern(
    k_in: np.ndarray,
    k_out: np.ndarray,
    normal: np.ndarray,
    pattern: str | np.ndarray,
    alpha_r: np.ndarray | int = 4,
) -> np.ndarray:
    """Scattering pattern ``f_s`` in 1/sr; zero for ``k_out`` behind the surface.

    Parameters
    ----------
    k_in : (m, 3) float
        Unit propagation direction of the incident wave (towards the surface).
    k_out : (m, 3) float
        Unit direction of the scattered wave (away from the surface).
    normal : (m, 3) float
        Unit surface normals, either sign.
    pattern : str or (m,) str
        ``"lambertian"`` or ``"directive"``, one for all or one per entry.
    alpha_r : int or (m,) int
        Directive lobe exponents (>= 1); unused where the pattern is Lambertian.

    Returns
    -------
    (m,) float64, 1/sr
    """
    k_in = np.asarray(k_in, np.float64)
    k_out = np.asarray(k_out, np.float64)
    n = _front_normal(k_in, normal)
    cos_s = _dot(k_out, n)
    kind = np.broadcast_to(np.asarray(pattern), cos_s.shape)
    bad = ~np.isin(kind, ("lambertian", "directive"))
    if np.any(bad):
        raise ValueError(f"unknown scattering pattern {kind[bad].flat[0]!r}")
    f = cos_s / np.pi
    directive = kind == "directive"
    if np.any(directive):
        alpha = np.broadcast_to(np.asarray(alpha_r), cos_s.shape)[directive]
        cos_i = -_dot(k_in[directive], n[directive])
        k_r = k_in[directive] + 2.0 * cos_i[:, None] * n[directive]
        lobe = ((1.0 + _dot(k_r, k_out[directive])) / 2.0) ** alpha
        f[directive] = lobe / directive_normalisation(alpha, cos_i)
    return np.where(cos_s > 0.0, f, 0.0)


def _transverse_basis(k: np.ndarray, n: np.ndarray, fallback: np.ndarray | None) -> np.ndarray:
    """``e_s = k x n / |k x n|`` (m, 3); where ``k`` is along ``n``, ``fallback`` or any vector ⟂ n."""
    e_s = np.cross(k, n)
    norm = np.linalg.norm(e_s, axis=-1)
    along = norm < 1e-9
    if np.any(along):
        if fallback is None:
            alt = np.where(np.abs(n[along, 0:1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
            e_s[along] = np.cross(alt, n[along])
        else:
            e_s[along] = fallback[along]
        norm = np.linalg.norm(e_s, axis=-1)
    return e_s / norm[:, None]


def diffuse_matrices(
    k_in: np.ndarray,
    k_out: np.ndarray,
    normal: np.ndarray,
    surface: Surface,
    scattering_coefficient: np.ndarray | float,
    xpd: np.ndarray | float,
    pattern: str | np.ndarray,
    alpha_r: np.ndarray | int,
    area: np.ndarray | float,
    wavelength: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Co- and cross-polar field maps of diffuse scattering by surface tiles.

    Parameters
    ----------
    k_in : (m, 3) float
        Unit propagation direction of the incident wave at the tile.
    k_out : (m, 3) float
        Unit direction tile -> observer.
    normal : (m, 3) float
        Unit tile normals, either sign.
    surface : Surface
        The tiles' materials (m entries); their smooth Fresnel coefficients give Gamma.
    scattering_coefficient : (m,) float
        S in [0, 1].
    xpd : (m,) float
        Cross-polarised power fraction Kx in [0, 1].
    pattern : str or (m,) str
        ``"lambertian"`` or ``"directive"``.
    alpha_r : int or (m,) int
        Directive lobe exponents.
    area : (m,) float
        Tile areas dA, square metres.
    wavelength : float
        Free-space wavelength, metres.

    Returns
    -------
    co, cross : (m, 3, 3) complex128
        ``|co @ E_i|^2 + |cross @ E_i|^2 = (S Gamma)^2 f_s cos(theta_i) dA |E_i|^2`` (W/sr per
        unit incident power density, in the field units of ``E_i``), ``(1 - Kx)`` of it in ``co``
        and ``Kx`` in ``cross``. ``co = S sqrt((1 - Kx) f_s cos(theta_i) dA) (r_te e_s' e_s^T +
        r_tm e_p' e_p^T)`` with the incident s/p basis of :func:`bounce_matrices`
        (``e_s = k_in x n``, ``e_p = k_in x e_s``) and the outgoing ``e_s' = k_out x n``,
        ``e_p' = k_out x e_s'`` (so ``co`` is the specular bounce matrix, scaled, when ``k_out``
        is the specular direction); ``cross`` exchanges the outgoing s and p vectors, with
        ``sqrt(Kx)``. The matrices include S, the pattern, ``cos(theta_i)``, ``dA`` and the
        smooth Fresnel coefficients; they do NOT include the distance tile -> observer (divide
        the field by ``r_s``), the incident spreading and phase (``E_i`` at the tile is the
        caller's, e.g. ``lambda / (4 pi r_i)`` times the transmit field) or any phase of the
        scattered wave: sum ``|co @ E_i / r_s|^2 + |cross @ E_i / r_s|^2`` over tiles in power.
    """
    k_in = np.asarray(k_in, np.float64).reshape(-1, 3)
    k_out = np.asarray(k_out, np.float64).reshape(-1, 3)
    m = len(k_in)
    n = _front_normal(k_in, np.asarray(normal, np.float64).reshape(-1, 3))
    cos_i = np.clip(-_dot(k_in, n), 0.0, 1.0)
    r_te, r_tm = surface.smooth_reflection(cos_i, wavelength)
    f_s = scattering_pattern(k_in, k_out, n, pattern, alpha_r)
    s = np.broadcast_to(np.asarray(scattering_coefficient, np.float64), (m,))
    kx = np.broadcast_to(np.asarray(xpd, np.float64), (m,))
    amp = s * np.sqrt(f_s * cos_i * np.broadcast_to(np.asarray(area, np.float64), (m,)))

    e_s = _transverse_basis(k_in, n, None)
    e_p = np.cross(k_in, e_s)
    e_s_out = _transverse_basis(k_out, n, e_s)
    e_p_out = np.cross(k_out, e_s_out)
    s_in = r_te[:, None, None] * e_s[:, None, :]  # rows: the s and p parts, weighted by Fresnel
    p_in = r_tm[:, None, None] * e_p[:, None, :]
    co = e_s_out[:, :, None] * s_in + e_p_out[:, :, None] * p_in
    cross = e_p_out[:, :, None] * s_in - e_s_out[:, :, None] * p_in
    co *= (amp * np.sqrt(1.0 - kx))[:, None, None]
    cross *= (amp * np.sqrt(kx))[:, None, None]
    return co, cross
