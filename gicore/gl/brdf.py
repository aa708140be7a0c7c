"""The scene materials' BRDFs in numpy, as Mitsuba 3 evaluates them, for the GL shaders' tables.

A scene object is Mitsuba's ``roughplastic`` (GGX ``alpha`` = the spec's roughness, ``int_ior`` 1.45 over
air, linear, white specular) or, without a roughness, ``diffuse``. ``roughplastic`` needs two numbers that
Mitsuba integrates when it loads a material and that a shader cannot: the rough interface's transmittance
as a function of the cosine (a 64-entry table read with linear interpolation) and the internal diffuse
reflectance. :func:`roughplastic_tables` integrates them the way Mitsuba does (Gauss-Legendre nodes
through visible-normal sampling); :func:`roughplastic_eval` is the BRDF times the cosine, as Mitsuba's
``BSDF.eval`` returns it, and is the reference the GLSL code is written from (tested against Mitsuba).
"""

from __future__ import annotations

from functools import cache, lru_cache

import numpy as np

#: Mitsuba's ``roughplastic`` defaults as ``gicore.render`` uses them: polypropylene-like 1.45 over air.
INT_IOR, EXT_IOR = 1.45, 1.000277
ETA = INT_IOR / EXT_IOR
#: Entries of the transmittance table (Mitsuba's MI_ROUGH_TRANSMITTANCE_RES).
TABLE_RES = 64


def fresnel(cos_i: np.ndarray, eta: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unpolarised dielectric Fresnel reflectance, signed cos of the transmitted direction and eta_ti."""
    cos_i = np.asarray(cos_i, dtype=np.float64)
    outside = cos_i >= 0.0
    eta_it = np.where(outside, eta, 1.0 / eta)
    eta_ti = np.where(outside, 1.0 / eta, eta)
    cos_t_sqr = 1.0 - eta_ti**2 * (1.0 - cos_i**2)
    ci, ct = np.abs(cos_i), np.sqrt(np.maximum(cos_t_sqr, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        a_s = (-eta_it * ct + ci) / (eta_it * ct + ci)
        a_p = (-eta_it * ci + ct) / (eta_it * ci + ct)
    r = 0.5 * (a_s**2 + a_p**2)
    r = np.where(ci == 0.0, 1.0, r) if eta != 1.0 else np.zeros_like(r)
    return r, np.where(outside, -ct, ct), eta_ti


def ggx_d(m: np.ndarray, alpha: float) -> np.ndarray:
    """GGX normal distribution of microfacet normals ``m`` (..., 3) in the local frame."""
    c2 = m[..., 2] ** 2
    d = 1.0 / (np.pi * alpha**2 * ((m[..., 0] ** 2 + m[..., 1] ** 2) / alpha**2 + c2) ** 2)
    return np.where(d * m[..., 2] > 1e-20, d, 0.0)


def smith_g1(v: np.ndarray, m: np.ndarray, alpha: float) -> np.ndarray:
    """Smith's masking for GGX, with Mitsuba's guards (normal incidence 1; back of the microfacet 0)."""
    xy = alpha**2 * (v[..., 0] ** 2 + v[..., 1] ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        g = 2.0 / (1.0 + np.sqrt(1.0 + xy / v[..., 2] ** 2))
    g = np.where(xy == 0.0, 1.0, g)
    return np.where(np.sum(v * m, axis=-1) * v[..., 2] <= 0.0, 0.0, g)


def _sample_visible(wi: np.ndarray, u1: np.ndarray, u2: np.ndarray, alpha: float) -> np.ndarray:
    """GGX visible normals for ``wi`` (3,) at the unit-square points (u1, u2) (Heitz 2018)."""
    vh = np.array([alpha * wi[0], alpha * wi[1], wi[2]])
    vh /= np.linalg.norm(vh)
    lensq = vh[0] ** 2 + vh[1] ** 2
    t1 = np.array([-vh[1], vh[0], 0.0]) / np.sqrt(lensq) if lensq > 0 else np.array([1.0, 0.0, 0.0])
    t2 = np.cross(vh, t1)
    r, phi = np.sqrt(u1), 2.0 * np.pi * u2
    p1, p2 = r * np.cos(phi), r * np.sin(phi)
    s = 0.5 * (1.0 + vh[2])
    p2 = (1.0 - s) * np.sqrt(np.maximum(1.0 - p1**2, 0.0)) + s * p2
    nh = p1[..., None] * t1 + p2[..., None] * t2 + np.sqrt(np.maximum(1.0 - p1**2 - p2**2, 0.0))[..., None] * vh
    ne = np.stack([alpha * nh[..., 0], alpha * nh[..., 1], np.maximum(nh[..., 2], 0.0)], axis=-1)
    return ne / np.linalg.norm(ne, axis=-1, keepdims=True)


def _interface(wi: np.ndarray, alpha: float, eta: float, transmit: bool) -> float:
    """Mitsuba's ``eval_reflectance`` / ``eval_transmittance``: the energy a rough dielectric interface
    reflects (or transmits) for incident ``wi``, integrated over visible normals with Gauss-Legendre nodes."""
    u1, u2, weight = _gauss_legendre_square(32 if eta > 1 else 128)
    m = _sample_visible(wi, u1, u2, alpha)
    cos_im = m @ wi
    f, cos_t, eta_ti = fresnel(cos_im, eta)
    if transmit:
        wo = m * (cos_im * eta_ti + cos_t)[..., None] - wi * eta_ti[..., None]
        g = smith_g1(wo, m, alpha) * (1.0 - f)
        g = np.where(wo[..., 2] * wi[2] >= 0.0, 0.0, g)
    else:
        wo = 2.0 * cos_im[..., None] * m - wi
        g = smith_g1(wo, m, alpha) * f
        g = np.where((wo[..., 2] <= 0.0) | (wi[2] <= 0.0), 0.0, g)
    return float(np.sum(g * weight) * 0.25)


@cache
def _gauss_legendre_square(res: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes on the unit square, ``res`` per axis, and their weights (over [-1, 1]²)."""
    x, w = np.polynomial.legendre.leggauss(res)
    u1, u2 = np.meshgrid(0.5 * x + 0.5, 0.5 * x + 0.5, indexing="ij")
    return u1, u2, np.outer(w, w)


@lru_cache(maxsize=64)  # a scene has a few roughnesses; every renderer and asset export of a process shares them
def roughplastic_tables(alpha: float, eta: float = ETA) -> tuple[np.ndarray, float]:
    """(external transmittance at cos = linspace(0, 1, TABLE_RES), internal diffuse reflectance); the table
    is read-only (it is shared)."""
    mu = np.maximum(1e-6, np.linspace(0.0, 1.0, TABLE_RES))
    wis = np.stack([np.sqrt(1.0 - mu**2), np.zeros_like(mu), mu], axis=-1)
    transmittance = np.array([_interface(wi, alpha, eta, transmit=True) for wi in wis])
    internal = np.mean([_interface(wi, alpha, 1.0 / eta, transmit=False) for wi in wis] * mu) * 2.0
    table = transmittance.astype(np.float32)
    table.setflags(write=False)
    return table, float(internal)


def _lerp_table(table: np.ndarray, x: np.ndarray) -> np.ndarray:
    x = np.asarray(x) * (len(table) - 1)
    i = np.minimum(x.astype(np.int64), len(table) - 2)
    w1 = x - i
    return (1.0 - w1) * table[i] + w1 * table[i + 1]


def roughplastic_eval(
    wi: np.ndarray, wo: np.ndarray, albedo: np.ndarray, alpha: float, eta: float = ETA, tables=None
) -> np.ndarray:
    """BRDF x cos(wo) of ``roughplastic`` for local-frame directions wi (to the viewer) and wo (to the
    light), (..., 3) each; ``albedo`` (3,). Returns (..., 3)."""
    transmittance, internal = roughplastic_tables(alpha, eta) if tables is None else tables
    wi, wo = np.asarray(wi, np.float64), np.asarray(wo, np.float64)
    ci, co = wi[..., 2], wo[..., 2]
    active = (ci > 0) & (co > 0)
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    f = fresnel(np.sum(wi * h, axis=-1), eta)[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        spec = f * ggx_d(h, alpha) * smith_g1(wi, h, alpha) * smith_g1(wo, h, alpha) / (4.0 * ci)
    t = _lerp_table(transmittance, np.clip(ci, 0, 1)) * _lerp_table(transmittance, np.clip(co, 0, 1))
    diff = np.asarray(albedo)[None] / (1.0 - internal) * (t * co / (np.pi * eta**2))[..., None]
    value = spec[..., None] + diff.reshape(*spec.shape, 3)
    return np.where(active[..., None], value, 0.0)
