"""Wedge diffraction by the uniform theory of diffraction (UTD).

Kouyoumjian-Pathak (KP, 1974) wedge coefficient with Luebbers' (1984) heuristic for lossy
faces, in full 3-D, float64, vectorised over ``m`` diffraction points. Time dependence
``exp(+j w t)`` as in :mod:`mmwsim.tracer.fresnel`.

Geometry (per diffraction point Q):

- ``e`` is the edge direction (either sign). The incident ray leaves the source (or its
  image) in direction ``k_in`` = s', the diffracted ray leaves Q in direction ``k_out`` = s;
  on Keller's cone ``k_in . e = k_out . e = cos(beta0)``.
- ``t0`` / ``tn`` lie in the 0-face / n-face, perpendicular to the edge, pointing from the edge
  into the face; ``n0`` / ``nn`` are the outward face normals. The exterior angle from ``t0`` to
  ``tn`` is ``n pi`` with ``n = 2 - acos(t0 . tn) / pi`` in [1, 2] (2: a half-plane).
- ``phi'`` and ``phi`` are the angles of ``-k_in`` and ``k_out``, projected on the plane
  perpendicular to the edge, measured from ``t0`` through the exterior, in [0, n pi].

Edge-fixed unit vectors (KP): ``phi'_hat = -e x s' / |e x s'|``, ``beta0'_hat = s' x phi'_hat``,
``phi_hat = e x s / |e x s|``, ``beta0_hat = s x phi_hat``. The field diffracted at Q is::

    E_d(P) = D @ E_i(Q) * A * exp(-j k s_out),   A = sqrt(s_in / (s_out (s_in + s_out)))

(``A = 1 / sqrt(s_out)`` for a plane wave, ``s_in = inf``), with the 3x3 matrix::

    D = -[beta0_hat, phi_hat] @ K @ [beta0'_hat, phi'_hat]^T
    K = p [ (C+(phi - phi') + C-(phi - phi')) I + C-(phi + phi') R0 + C+(phi + phi') Rn ]
    p = -exp(-j pi/4) / (2 n sqrt(2 pi k) sin beta0)
    C+-(b) = cot((pi +- b) / 2n) F(k L a+-(b)),  a+-(b) = 2 cos^2((2 n pi N+- - b) / 2)
    L = s_in s_out sin^2(beta0) / (s_in + s_out)      (s_out sin^2(beta0) for a plane wave)

For diagonal ``R0 = Rn = diag(R_s, R_h)`` this is KP's ``-beta0' beta0 D_s - phi' phi D_h``,
and a perfect conductor (``R = diag(-1, +1)``, soft = E along ``beta0_hat``) gives KP exactly.

Reflection matrices of lossy faces (the convention of this module). Luebbers evaluates R0 at the
incidence of the actual ray on the 0-face and Rn at the incidence from which the n-face would
reflect into the diffracted direction. In 3-D the face's s/p basis is not the edge-fixed
basis (they coincide only at beta0 = 90 deg), so the reflections are 2x2 matrices, not
scalars::

    R0 = -[beta0_hat_r, phi_hat_r]^T @ M0 @ [beta0'_hat, phi'_hat]
    Rn = -[beta0_hat, phi_hat]^T @ Mn @ [beta0'_hat_v, phi'_hat_v]

where ``M0 = bounce_matrices(s', r0, n0, ...)`` is the specular reflection of s' at the 0-face into
``r0 = s' - 2 (s'.n0) n0`` with the edge-fixed basis ``(beta0_hat_r, phi_hat_r)`` of r0, and
``Mn = bounce_matrices(v, s, nn, ...)`` the reflection at the n-face of the virtual incident
direction ``v = s - 2 (s.nn) nn`` into s, with the edge-fixed incident basis of v. Both use
:meth:`Surface.reflection` (slab or half-space times ``sqrt(1 - S^2)``), the very coefficient
of the specular paths. Reflection in a plane that contains the edge maps the edge-fixed basis
of a ray onto that of its mirror image (``phi_hat -> phi_hat``, ``beta0_hat -> -beta0_hat``),
so a perfect conductor gives ``R = diag(-1, +1)``; on a reflection shadow boundary the diffracted
direction equals ``r0`` (or ``s' = v``), the R term becomes the GO reflection matrix itself and
its jump cancels the jump of the reflected field exactly, at any beta0, polarisation and S.

On a shadow boundary (``eps -> 0``, see :func:`_cot_f`) the limit
``C -> n [sqrt(2 pi k L) sgn(eps) - 2 k L eps exp(j pi/4)] exp(j pi/4)`` replaces the 0 * inf
of cot and F, so nothing is NaN there. Within ``ON_BOUNDARY`` (1e-12 rad) of a boundary the
coefficient is the average of its two one-sided limits, and the caller weights the GO field 1/2
there; :func:`wedge_angles` gives the angles to decide it from (incident shadow boundary at
``phi = phi' +- pi``, reflection shadow boundaries at ``phi = pi - phi'`` (0-face) and
``phi = (2n - 1) pi - phi'`` (n-face)).
"""

from __future__ import annotations

import numpy as np
from scipy.special import wofz

from .fresnel import Surface, bounce_matrices

__all__ = [
    "ON_BOUNDARY",
    "transition_function",
    "diffraction_matrices",
    "keller_point",
    "wedge_angles",
]

_EPS_SMALL = 1e-9  # |eps| below which the boundary limit of cot * F is used (rad)
ON_BOUNDARY = 1e-12  # |eps| (rad) up to which a ray counts as exactly on a shadow boundary


def transition_function(x: np.ndarray | float) -> np.ndarray:
    """KP transition function ``F(x) = 2 j sqrt(x) e^{jx} int_sqrt(x)^inf e^{-j t^2} dt``.

    Evaluated as ``sqrt(pi x) e^{j pi/4} wofz(sqrt(x) e^{j 3 pi/4})`` (Faddeeva function), which
    has no cancellation at large or small ``x``.

    Parameters
    ----------
    x : (...) float
        Argument, >= 0 (tiny negative round-off is taken as 0); ``F(0) = 0``, ``F -> 1``
        for large ``x``.

    Returns
    -------
    (...) complex128
    """
    x = np.maximum(np.asarray(x, dtype=np.float64), 0.0)
    r = np.sqrt(x)
    return np.sqrt(np.pi) * r * np.exp(0.25j * np.pi) * wofz(r * np.exp(0.75j * np.pi))


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def _edge_basis(e: np.ndarray, k: np.ndarray, incident: bool) -> np.ndarray:
    """KP edge-fixed basis ``[beta0_hat, phi_hat]`` (m, 3, 2) of a ray of direction ``k``."""
    phi = _unit(np.cross(e, k))
    if incident:
        phi = -phi
    return np.stack([np.cross(k, phi), phi], axis=-1)


def wedge_angles(
    k_in: np.ndarray, k_out: np.ndarray, edge: np.ndarray, t0: np.ndarray, n0: np.ndarray, tn: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """KP angles ``phi'`` (of ``-k_in``) and ``phi`` (of ``k_out``) and the wedge number ``n``.

    Parameters
    ----------
    k_in, k_out, edge, t0, n0, tn : (m, 3) float
        As in :func:`diffraction_matrices`.

    Returns
    -------
    phi_in, phi_out : (m,) float, radians in [0, n pi]
    n : (m,) float in [1, 2]
    """
    e = _unit(edge)
    n = 2.0 - np.arccos(np.clip(_dot(t0, tn), -1.0, 1.0)) / np.pi

    def angle(d: np.ndarray) -> np.ndarray:
        d = d - _dot(d, e)[:, None] * e
        a = np.mod(np.arctan2(_dot(d, n0), _dot(d, t0)), 2.0 * np.pi)
        # Round-off may put a ray grazing a face a hair inside the wedge: snap to that face.
        a = np.where(a > n * np.pi, np.where(a > (n + 2.0) * np.pi / 2.0, 0.0, n * np.pi), a)
        return a

    return angle(-np.asarray(k_in, np.float64)), angle(np.asarray(k_out, np.float64)), n


def _cot_f(eps: np.ndarray, n: np.ndarray, kl: np.ndarray) -> np.ndarray:
    """``cot(eps / 2n) F(2 k L sin^2(eps / 2))``, the KP term at distance ``eps`` from its boundary."""
    small = np.abs(eps) < _EPS_SMALL
    safe = np.where(small, 1.0, eps)
    far = transition_function(2.0 * kl * np.sin(safe / 2.0) ** 2) / np.tan(safe / (2.0 * n))
    side = np.where(np.abs(eps) <= ON_BOUNDARY, 0.0, np.sign(eps))
    near = n * (np.sqrt(2.0 * np.pi * kl) * side - 2.0 * kl * eps * np.exp(0.25j * np.pi))
    return np.where(small, near * np.exp(0.25j * np.pi), far)


def _c_plus(beta: np.ndarray, n: np.ndarray, kl: np.ndarray) -> np.ndarray:
    big_n = np.round((beta + np.pi) / (2.0 * np.pi * n))
    return _cot_f(np.pi + beta - 2.0 * np.pi * n * big_n, n, kl)


def _c_minus(beta: np.ndarray, n: np.ndarray, kl: np.ndarray) -> np.ndarray:
    big_n = np.round((beta - np.pi) / (2.0 * np.pi * n))
    return _cot_f(np.pi - beta + 2.0 * np.pi * n * big_n, n, kl)


def _reflection_2x2(
    e: np.ndarray,
    k_inc: np.ndarray,
    k_ref: np.ndarray,
    normal: np.ndarray,
    surface: Surface,
    wavelength: float,
) -> np.ndarray:
    """``-B_ref^T M B_inc`` (m, 2, 2): a face's specular reflection in edge-fixed bases."""
    cos = np.minimum(np.abs(_dot(k_inc, normal)), 1.0)
    r_te, r_tm = surface.reflection(cos, wavelength)
    m = bounce_matrices(k_inc, k_ref, normal, r_te, r_tm)
    b_inc = _edge_basis(e, k_inc, incident=True)
    b_ref = _edge_basis(e, k_ref, incident=False)
    return -(np.swapaxes(b_ref, 1, 2) @ (m @ b_inc))


def diffraction_matrices(
    k_in: np.ndarray,
    k_out: np.ndarray,
    edge: np.ndarray,
    t0: np.ndarray,
    n0: np.ndarray,
    tn: np.ndarray,
    nn: np.ndarray,
    s_in: np.ndarray,
    s_out: np.ndarray,
    wavelength: float,
    face0: Surface,
    facen: Surface,
) -> np.ndarray:
    """UTD dyadic diffraction coefficients as 3x3 matrices in global coordinates.

    Parameters
    ----------
    k_in : (m, 3) float
        Unit propagation direction of the incident ray at the diffraction point Q
        (source or source image -> Q).
    k_out : (m, 3) float
        Unit propagation direction of the diffracted ray (Q -> observer or next interaction).
    edge : (m, 3) float
        Unit edge direction (either sign); ``k_in`` must not be parallel to it.
    t0, tn : (m, 3) float
        Unit vectors in the 0-face / n-face, perpendicular to the edge, pointing from the edge
        into that face (``tn = t0`` for a half-plane).
    n0, nn : (m, 3) float
        Outward unit normals of the 0-face / n-face (``nn = -n0`` for a half-plane).
    s_in : (m,) float
        Distance source (image) -> Q, metres; ``np.inf`` for plane-wave incidence.
    s_out : (m,) float
        Distance Q -> observer (image), metres.
    wavelength : float
        Free-space wavelength, metres.
    face0, facen : Surface
        The faces' materials, one entry per diffraction point (``Surface.take``).

    Returns
    -------
    (m, 3, 3) complex128
        ``D`` such that ``E_d(P) = D @ E_i(Q) * A(s_in, s_out) * exp(-j k s_out)`` with
        ``A = sqrt(s_in / (s_out (s_in + s_out)))`` (``1 / sqrt(s_out)`` for a plane wave);
        see the module docstring for the convention.
    """
    k_in = np.asarray(k_in, np.float64).reshape(-1, 3)
    k_out = np.asarray(k_out, np.float64).reshape(-1, 3)
    e = _unit(np.asarray(edge, np.float64).reshape(-1, 3))
    t0, n0, tn, nn = (np.asarray(v, np.float64).reshape(-1, 3) for v in (t0, n0, tn, nn))
    s_in = np.asarray(s_in, np.float64).reshape(-1)
    s_out = np.asarray(s_out, np.float64).reshape(-1)
    k = 2.0 * np.pi / wavelength

    phi_in, phi_out, n = wedge_angles(k_in, k_out, e, t0, n0, tn)
    sin2 = np.maximum(1.0 - _dot(k_in, e) ** 2, 0.0)
    plane = np.isinf(s_in)
    with np.errstate(invalid="ignore"):
        ratio = np.where(plane, 1.0, s_in / (s_in + s_out))
    kl = k * s_out * ratio * sin2

    p = -np.exp(-0.25j * np.pi) / (2.0 * n * np.sqrt(2.0 * np.pi * k) * np.sqrt(sin2))
    d_inc = _c_plus(phi_out - phi_in, n, kl) + _c_minus(phi_out - phi_in, n, kl)
    c_0 = _c_minus(phi_out + phi_in, n, kl)  # 0-face reflection boundary phi = pi - phi'
    c_n = _c_plus(phi_out + phi_in, n, kl)  # n-face reflection boundary phi = (2n - 1) pi - phi'

    r0 = _reflection_2x2(e, k_in, k_in - 2.0 * _dot(k_in, n0)[:, None] * n0, n0, face0, wavelength)
    virt = k_out - 2.0 * _dot(k_out, nn)[:, None] * nn
    rn = _reflection_2x2(e, virt, k_out, nn, facen, wavelength)

    kmat = d_inc[:, None, None] * np.eye(2) + c_0[:, None, None] * r0 + c_n[:, None, None] * rn
    kmat *= p[:, None, None]
    b_in = _edge_basis(e, k_in, incident=True)
    b_out = _edge_basis(e, k_out, incident=False)
    return -(b_out @ (kmat @ np.swapaxes(b_in, 1, 2)))


def keller_point(
    source: np.ndarray, target: np.ndarray, edge_origin: np.ndarray, edge_dir: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Diffraction point on an infinite edge line, where Keller's cone links source and target.

    In closed form: with ``s_z, t_z`` the coordinates of source and target along the edge and
    ``a, b`` their distances from the edge line, the point is at ``x = (b s_z + a t_z) / (a + b)``
    (the target rotated about the edge into the source's half-plane; the shortest path).

    Parameters
    ----------
    source, target : (m, 3) float
        Source (image) and target (image) positions, metres.
    edge_origin : (m, 3) float
        A point of the edge line.
    edge_dir : (m, 3) float
        Edge direction (normalised here).

    Returns
    -------
    x : (m,) float
        Coordinate of the diffraction point along ``edge_dir`` from ``edge_origin``, metres
        (the midpoint of ``s_z, t_z`` when both ends lie on the edge line).
    residual : (m,) float
        ``|cos beta_in - cos beta_out|`` of the two legs at that point (0 on Keller's cone).
    """
    src, tgt, o = (np.asarray(v, np.float64).reshape(-1, 3) for v in (source, target, edge_origin))
    e = _unit(np.asarray(edge_dir, np.float64).reshape(-1, 3))
    s_z = _dot(src - o, e)
    t_z = _dot(tgt - o, e)
    a = np.linalg.norm(src - o - s_z[:, None] * e, axis=1)
    b = np.linalg.norm(tgt - o - t_z[:, None] * e, axis=1)
    total = a + b
    with np.errstate(invalid="ignore", divide="ignore"):
        x = np.where(total > 0, (b * s_z + a * t_z) / np.where(total > 0, total, 1.0), (s_z + t_z) / 2)
    q = o + x[:, None] * e
    leg_in, leg_out = q - src, tgt - q
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_in = _dot(leg_in, e) / np.linalg.norm(leg_in, axis=1)
        cos_out = _dot(leg_out, e) / np.linalg.norm(leg_out, axis=1)
    return x, np.nan_to_num(np.abs(cos_in - cos_out))
