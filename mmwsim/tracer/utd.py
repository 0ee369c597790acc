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

from .._jit import njit
from ._vec import cross, dot, row, scale, sub, unit
from .fresnel import Surface, reflection_scalar, sp_basis

__all__ = [
    "ON_BOUNDARY",
    "diffraction_scalar",
    "transition_function",
    "diffraction_matrices",
    "keller_point",
    "wedge_angles",
]

_EPS_SMALL = 1e-9  # |eps| below which the boundary limit of cot * F is used (rad)
ON_BOUNDARY = 1e-12  # |eps| (rad) up to which a ray counts as exactly on a shadow boundary


def transition_function(x: np.ndarray | float) -> np.ndarray:
    """KP transition function ``F(x) = 2 j sqrt(x) e^{jx} int_sqrt(x)^inf e^{-j t^2} dt``.

    Through the Fresnel integrals of ``u = sqrt(2 x / pi)`` (Cephes' rational approximations):
    for ``u < 1.6`` from the power series of C and S, above from their auxiliary functions
    ``f``, ``g``, where ``F = f(u) + j g(u)`` exactly, with no cancellation at large ``x``.

    Parameters
    ----------
    x : (...) float
        Argument, >= 0 (tiny negative round-off is taken as 0); ``F(0) = 0``, ``F -> 1``
        for large ``x``.

    Returns
    -------
    (...) complex128
    """
    x = np.asarray(x, dtype=np.float64)
    out = np.empty(x.shape, np.complex128)
    _transition_into(x.reshape(-1), out.reshape(-1))
    return out


# Cephes (fresnl.c) coefficients: C and S below u^2 = 2.5625, auxiliary functions f and g above.
_SN = np.array(
    [-2.99181919401019853726e3, 7.08840045257738576863e5, -6.29741486205862506537e7,
     2.54890880573376359104e9, -4.42979518059697779103e10, 3.18016297876567817986e11]
)  # fmt: skip
_SD = np.array(
    [1.0, 2.81376268889994315696e2, 4.55847810806532581675e4, 5.17343888770096400730e6,
     4.19320245898111231129e8, 2.24411795645340920940e10, 6.07366389490084639049e11]
)  # fmt: skip
_CN = np.array(
    [-4.98843114573573548651e-8, 9.50428062829859605134e-6, -6.45191435683965050962e-4,
     1.88843319396703850064e-2, -2.05525900955013891793e-1, 9.99999999999999998822e-1]
)  # fmt: skip
_CD = np.array(
    [3.99982968972495980367e-12, 9.15439215774657478799e-10, 1.25001862479598821474e-7,
     1.22262789024179030997e-5, 8.68029542941784300606e-4, 4.12142090722199792936e-2,
     1.00000000000000000118e0]
)  # fmt: skip
_FN = np.array(
    [4.21543555043677546506e-1, 1.43407919780758885261e-1, 1.15220955073585758835e-2,
     3.45017939782574027900e-4, 4.63613749287867322088e-6, 3.05568983790257605827e-8,
     1.02304514164907233465e-10, 1.72010743268161828879e-13, 1.34283276233062758925e-16,
     3.76329711269987889006e-20]
)  # fmt: skip
_FD = np.array(
    [1.0, 7.51586398353378947175e-1, 1.16888925859191382142e-1, 6.44051526508858611005e-3,
     1.55934409164153020873e-4, 1.84627567348930545870e-6, 1.12699224763999035261e-8,
     3.60140029589371370404e-11, 5.88754533621578410010e-14, 4.52001434074129701496e-17,
     1.25443237090011264384e-20]
)  # fmt: skip
_GN = np.array(
    [5.04442073643383265887e-1, 1.97102833525523411709e-1, 1.87648584092575249293e-2,
     6.84079380915393090172e-4, 1.15138826111884280931e-5, 9.82852443688422223854e-8,
     4.45344415861750144738e-10, 1.08268041139020870318e-12, 1.37555460633261799868e-15,
     8.36354435630677421531e-19, 1.86958710162783235106e-22]
)  # fmt: skip
_GD = np.array(
    [1.0, 1.47495759925128324529e0, 3.37748989120019970451e-1, 2.53603741420338795122e-2,
     8.14679107184306179049e-4, 1.27545075667729118702e-5, 1.04314589657571990585e-7,
     4.60680728146520428211e-10, 1.10273215066240270757e-12, 1.38796531259578871258e-15,
     8.39158816283118707363e-19, 1.86958710162783236342e-22]
)  # fmt: skip


@njit(cache=True)
def _polevl(x, coef):  # pragma: no cover - compiled
    """Horner's rule, coefficients from the highest power."""
    acc = 0.0
    for c in coef:
        acc = acc * x + c
    return acc


@njit(cache=True)
def _transition(x):  # pragma: no cover - compiled
    if not x > 0.0:
        return 0.0j
    u2 = 2.0 * x / np.pi
    if u2 < 2.5625:
        u = np.sqrt(u2)
        t = u2 * u2
        ss = u * u2 * _polevl(t, _SN) / _polevl(t, _SD)
        cc = u * _polevl(t, _CN) / _polevl(t, _CD)
        return 1j * np.sqrt(2.0 * np.pi * x) * np.exp(1j * x) * ((0.5 - 0.5j) - cc + 1j * ss)
    t = np.pi * u2
    w = 1.0 / (t * t)
    f = 1.0 - w * _polevl(w, _FN) / _polevl(w, _FD)
    g = _polevl(w, _GN) / _polevl(w, _GD) / t
    return f + 1j * g


@njit(cache=True)
def _transition_into(x, out):  # pragma: no cover - compiled
    for i in range(len(x)):
        out[i] = _transition(x[i])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


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
    args = [
        np.ascontiguousarray(np.asarray(v, np.float64).reshape(-1, 3))
        for v in (k_in, k_out, edge, t0, n0, tn)
    ]
    m = len(args[0])
    out = np.empty((3, m))
    _angles_into(*args, out)
    return out[0], out[1], out[2]


@njit(cache=True)
def _wedge_n(t0, tn):  # pragma: no cover - compiled
    return 2.0 - np.arccos(min(max(dot(t0, tn), -1.0), 1.0)) / np.pi


@njit(cache=True)
def _angle(d, e, t0, n0, n):  # pragma: no cover - compiled
    """Angle of ``d`` about the edge from the 0-face through the exterior, in [0, n pi]."""
    d = sub(d, scale(e, dot(d, e)))
    a = np.arctan2(dot(d, n0), dot(d, t0)) % (2.0 * np.pi)
    # Round-off may put a ray grazing a face a hair inside the wedge: snap to that face.
    if a > n * np.pi:
        a = 0.0 if a > (n + 2.0) * np.pi / 2.0 else n * np.pi
    return a


@njit(cache=True)
def _angles_into(k_in, k_out, edge, t0, n0, tn, out):  # pragma: no cover - compiled
    for i in range(len(k_in)):
        e = unit(row(edge, i))
        a0, an = row(t0, i), row(tn, i)
        n = _wedge_n(a0, an)
        out[0, i] = _angle(scale(row(k_in, i), -1.0), e, a0, row(n0, i), n)
        out[1, i] = _angle(row(k_out, i), e, a0, row(n0, i), n)
        out[2, i] = n


@njit(cache=True)
def _cot_f(eps, n, kl):  # pragma: no cover - compiled
    """``cot(eps / 2n) F(2 k L sin^2(eps / 2))``, the KP term at distance ``eps`` from its boundary."""
    if abs(eps) < _EPS_SMALL:
        side = 0.0 if abs(eps) <= ON_BOUNDARY else np.sign(eps)
        near = n * (np.sqrt(2.0 * np.pi * kl) * side - 2.0 * kl * eps * np.exp(0.25j * np.pi))
        return near * np.exp(0.25j * np.pi)
    return _transition(2.0 * kl * np.sin(eps / 2.0) ** 2) / np.tan(eps / (2.0 * n))


@njit(cache=True)
def _c_plus(beta, n, kl):  # pragma: no cover - compiled
    big_n = np.rint((beta + np.pi) / (2.0 * np.pi * n))
    return _cot_f(np.pi + beta - 2.0 * np.pi * n * big_n, n, kl)


@njit(cache=True)
def _c_minus(beta, n, kl):  # pragma: no cover - compiled
    big_n = np.rint((beta - np.pi) / (2.0 * np.pi * n))
    return _cot_f(np.pi - beta + 2.0 * np.pi * n * big_n, n, kl)


@njit(cache=True)
def _edge_basis(e, k, incident):  # pragma: no cover - compiled
    """KP edge-fixed unit vectors ``(beta0_hat, phi_hat)`` of a ray of direction ``k``."""
    phi = unit(cross(e, k))
    if incident:
        phi = scale(phi, -1.0)
    return cross(k, phi), phi


@njit(cache=True)
def _reflection_2x2(
    k_inc, k_ref, normal, b_inc, b_ref, eps, thick, rough, wavelength, out
):  # pragma: no cover
    """``-B_ref^T M B_inc`` into ``out`` (2, 2): a face's specular reflection in edge-fixed bases.

    ``M = r_TE e_s e_s^T + r_TM e_p,ref e_p,inc^T`` is :func:`~mmwsim.tracer.fresnel.bounce_matrices`;
    ``b_inc``, ``b_ref`` are the edge-fixed bases (pairs of 3-vectors) of the two directions.
    """
    r_te, r_tm = reflection_scalar(eps, thick, rough, min(abs(dot(k_inc, normal)), 1.0), wavelength)
    e_s, e_pi, e_po = sp_basis(k_inc, k_ref, normal)
    for a in range(2):
        ra = b_ref[a]
        for b in range(2):
            cb = b_inc[b]
            out[a, b] = -(r_te * dot(ra, e_s) * dot(e_s, cb) + r_tm * dot(ra, e_po) * dot(e_pi, cb))


@njit(cache=True)
def diffraction_scalar(
    k_in, k_out, e, t0, n0, tn, nn, s_in, s_out, wavelength,
    eps0, thick0, rough0, epsn, thickn, roughn, r0, rn, out, nudge=0.0,
):  # pragma: no cover - compiled  # fmt: skip
    """:func:`diffraction_matrices` of one diffraction point into ``out`` (3, 3) complex.

    ``r0``, ``rn`` (2, 2) complex are work arrays. ``nudge`` (radians) is added to the
    diffraction angle ``phi``: a ray exactly on a shadow boundary takes the one-sided limit
    of the side its geometrical-optics partner is on (see ``Tracer``).
    """
    k = 2.0 * np.pi / wavelength
    e = unit(e)
    n = _wedge_n(t0, tn)
    phi_in = _angle(scale(k_in, -1.0), e, t0, n0, n)
    phi_out = _angle(k_out, e, t0, n0, n) + nudge
    ce = dot(k_in, e)
    sin2 = max(1.0 - ce * ce, 0.0)
    ratio = 1.0 if np.isinf(s_in) else s_in / (s_in + s_out)
    kl = k * s_out * ratio * sin2
    p = -np.exp(-0.25j * np.pi) / (2.0 * n * np.sqrt(2.0 * np.pi * k) * np.sqrt(sin2))
    d_inc = _c_plus(phi_out - phi_in, n, kl) + _c_minus(phi_out - phi_in, n, kl)
    c_0 = _c_minus(phi_out + phi_in, n, kl)  # 0-face reflection boundary phi = pi - phi'
    c_n = _c_plus(phi_out + phi_in, n, kl)  # n-face reflection boundary phi = (2n - 1) pi - phi'
    b_in = _edge_basis(e, k_in, True)
    b_out = _edge_basis(e, k_out, False)
    mirror0 = sub(k_in, scale(n0, 2.0 * dot(k_in, n0)))
    _reflection_2x2(
        k_in, mirror0, n0, b_in, _edge_basis(e, mirror0, False), eps0, thick0, rough0, wavelength, r0
    )
    virt = sub(k_out, scale(nn, 2.0 * dot(k_out, nn)))
    _reflection_2x2(virt, k_out, nn, _edge_basis(e, virt, True), b_out, epsn, thickn, roughn, wavelength, rn)
    for a in range(2):
        for b in range(2):
            diag = d_inc if a == b else 0.0j
            r0[a, b] = p * (diag + c_0 * r0[a, b] + c_n * rn[a, b])
    bi0, bi1 = b_in
    bo0, bo1 = b_out
    for i in range(3):
        for j in range(3):
            out[i, j] = -(
                bo0[i] * (r0[0, 0] * bi0[j] + r0[0, 1] * bi1[j])
                + bo1[i] * (r0[1, 0] * bi0[j] + r0[1, 1] * bi1[j])
            )


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
    vecs = [
        np.ascontiguousarray(np.asarray(v, np.float64).reshape(-1, 3))
        for v in (k_in, k_out, edge, t0, n0, tn, nn)
    ]
    m = len(vecs[0])
    s_in = np.broadcast_to(np.asarray(s_in, np.float64).reshape(-1), (m,))
    s_out = np.broadcast_to(np.asarray(s_out, np.float64).reshape(-1), (m,))
    out = np.empty((m, 3, 3), np.complex128)
    _diffraction_into(
        *vecs, s_in, s_out, float(wavelength),
        face0.eps, face0.thickness, face0.roughness, facen.eps, facen.thickness, facen.roughness, out,
    )  # fmt: skip
    return out


@njit(cache=True)
def _diffraction_into(
    k_in, k_out, edge, t0, n0, tn, nn, s_in, s_out, wavelength, eps0, th0, ro0, epsn, thn, ron, out
):  # pragma: no cover - compiled
    r0 = np.empty((2, 2), np.complex128)
    rn = np.empty((2, 2), np.complex128)
    for i in range(len(k_in)):
        diffraction_scalar(
            row(k_in, i), row(k_out, i), row(edge, i), row(t0, i), row(n0, i), row(tn, i), row(nn, i),
            s_in[i], s_out[i], wavelength, eps0[i], th0[i], ro0[i], epsn[i], thn[i], ron[i], r0, rn, out[i],
        )  # fmt: skip


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
