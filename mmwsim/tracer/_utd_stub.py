"""TEMPORARY stand-in for utd.diffraction_matrices (perfect conductor, KP), until the physics branch lands."""

import numpy as np
from scipy.special import wofz


def _F(x):
    x = np.maximum(x, 0.0)
    return np.sqrt(np.pi * x) * np.exp(1j * np.pi / 4) * wofz(np.sqrt(x) * np.exp(3j * np.pi / 4))


def diffraction_matrices(k_in, k_out, edge, t0, n0, tn, nn, s_in, s_out, wavelength, face0, facen):
    k = 2 * np.pi / wavelength
    n = 1.0 + np.arccos(np.clip(np.einsum("ij,ij->i", n0, nn), -1, 1)) / np.pi
    cos_b = np.clip(np.einsum("ij,ij->i", k_in, edge), -1, 1)
    sin_b = np.sqrt(np.maximum(1 - cos_b**2, 1e-30))

    def ang(u):
        return np.mod(np.arctan2(np.einsum("ij,ij->i", u, n0), np.einsum("ij,ij->i", u, t0)), 2 * np.pi)

    phi_p = ang(-k_in)
    phi = ang(k_out)
    L = s_in * s_out * sin_b**2 / (s_in + s_out)

    def c(sign, beta):
        N = np.round((beta + sign * np.pi) / (2 * n * np.pi))
        a = 2 * np.cos((2 * n * np.pi * N - beta) / 2) ** 2
        with np.errstate(all="ignore"):
            v = 1 / np.tan((np.pi + sign * beta) / (2 * n)) * _F(k * L * a)
        return np.nan_to_num(v)

    pre = -np.exp(-1j * np.pi / 4) / (2 * n * np.sqrt(2 * np.pi * k) * sin_b)
    d1 = c(1, phi - phi_p) + c(-1, phi - phi_p)
    d2 = c(-1, phi + phi_p) + c(1, phi + phi_p)
    ds, dh = pre * (d1 - d2), pre * (d1 + d2)
    php = -np.cross(edge, k_in)
    php /= np.linalg.norm(php, axis=1, keepdims=True)
    bp = np.cross(k_in, php)
    ph = np.cross(edge, k_out)
    ph /= np.linalg.norm(ph, axis=1, keepdims=True)
    b = np.cross(k_out, ph)
    return -ds[:, None, None] * np.einsum("mi,mj->mij", b, bp) - dh[:, None, None] * np.einsum(
        "mi,mj->mij", ph, php
    )
