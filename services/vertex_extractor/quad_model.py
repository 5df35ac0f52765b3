"""The whole-marker fits' model (``shadow.py``, ``highlight.py``) in one compiled pass over
the pixels: the chroma score of a blurred quadrilateral under a straight shadow's boundary,

    f(x, y) = b + A · Π_i Φ(d_i / σ) · (k + (1 − k) Φ(s / soft)),

d_i the signed distance (px, positive inward) to edge i (vertex i to i + 1), s the
distance to the boundary's line (angle ``ang``, offset ``rho``), and its Jacobian by the 15
parameters (8 vertex coordinates, blur, A, b, k, ang, rho, soft). σ = |p[8]| + 0.3 and
soft = |p[14]| + 0.3 px. About ten times faster than the same in numpy, whose temporaries
made most of a fit's time; a pixel more than 8.3 blurs outside an edge costs nothing but
its value b.
"""

from __future__ import annotations

import math

import numpy as np

from services.core.jit import njit

N_PARAMS = 15
_SQRT2 = math.sqrt(2.0)
_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)
_FAR = 8.3  # |z| beyond this: Φ(z) is 0 or 1 and φ(z) 0 to 1e-15 (erfc's cost spared)


@njit()
def model(p: np.ndarray, X: np.ndarray, Y: np.ndarray, jac: bool
          ) -> tuple[np.ndarray, np.ndarray]:
    """The score at the pixels X, Y (n,) px, and its Jacobian (n, 15) if ``jac`` (else an
    empty (0, 15) array)."""
    n = X.size
    sig = abs(p[8]) + 0.3
    A, b = p[9], p[10]
    k, ang, rho, soft = p[11], p[12], p[13], abs(p[14]) + 0.3
    ca, sa = math.cos(ang), math.sin(ang)
    cx = (p[0] + p[2] + p[4] + p[6]) / 4.0
    cy = (p[1] + p[3] + p[5] + p[7]) / 4.0
    # each edge: its start a, direction t, length L, the sign that turns its left normal
    # inward, and the inward unit normal and offset
    ax, ay, tx, ty = np.empty(4), np.empty(4), np.empty(4), np.empty(4)
    L, sign, nx, ny, off = np.empty(4), np.empty(4), np.empty(4), np.empty(4), np.empty(4)
    for i in range(4):
        j = (i + 1) % 4
        ax[i], ay[i] = p[2 * i], p[2 * i + 1]
        tx[i], ty[i] = p[2 * j] - ax[i], p[2 * j + 1] - ay[i]
        L[i] = max(math.hypot(tx[i], ty[i]), 1e-9)
        lx, ly = -ty[i] / L[i], tx[i] / L[i]
        sign[i] = 1.0 if (cx - ax[i]) * lx + (cy - ay[i]) * ly >= 0.0 else -1.0
        nx[i], ny[i] = sign[i] * lx, sign[i] * ly
        off[i] = nx[i] * ax[i] + ny[i] * ay[i]
    f = np.empty(n)
    J = np.zeros((n if jac else 0, N_PARAMS))
    d, cdf, pdf = np.empty(4), np.empty(4), np.empty(4)
    for m in range(n):
        x, y = X[m], Y[m]
        cover = 1.0
        outside = False
        for i in range(4):
            d[i] = nx[i] * x + ny[i] * y - off[i]
            z = d[i] / sig
            if z < -_FAR:  # (Φ under 1e-16: the pixel is outside, its value b)
                outside = True
                break
            cdf[i] = 1.0 if z > _FAR else 0.5 * math.erfc(-z / _SQRT2)
            cover *= cdf[i]
        if outside:
            f[m] = b
            if jac:
                J[m, 10] = 1.0
            continue
        s = ca * x + sa * y - rho
        z = s / soft
        lit = 1.0 if z > _FAR else 0.0 if z < -_FAR else 0.5 * math.erfc(-z / _SQRT2)
        G = k + (1.0 - k) * lit
        f[m] = b + A * cover * G
        if not jac:
            continue
        AG = A * G
        dsig = 0.0
        for i in range(4):
            z = d[i] / sig
            pdf[i] = 0.0 if z > _FAR else math.exp(-0.5 * z * z) * _INV_SQRT_2PI
            others = 1.0
            for q in range(4):
                if q != i:
                    others *= cdf[q]
            dcov = others * pdf[i] / sig  # d(cover)/d(d_i)
            dsig += dcov * (-z)
            dx, dy = x - ax[i], y - ay[i]
            cross = -ty[i] * dx + tx[i] * dy  # d_i = sign · cross / L
            w = AG * dcov * sign[i]
            Li, L2 = L[i], L[i] * L[i]
            j = (i + 1) % 4
            # by a = v[i] (x, y) and c = v[i + 1] (x, y)
            J[m, 2 * i] += w * ((ty[i] - dy) / Li - cross * (-tx[i] / Li) / L2)
            J[m, 2 * i + 1] += w * ((dx - tx[i]) / Li - cross * (-ty[i] / Li) / L2)
            J[m, 2 * j] += w * (dy / Li - cross * (tx[i] / Li) / L2)
            J[m, 2 * j + 1] += w * (-dx / Li - cross * (ty[i] / Li) / L2)
        J[m, 8] = AG * dsig * (1.0 if p[8] >= 0 else -1.0)
        J[m, 9] = cover * G
        J[m, 10] = 1.0
        z = s / soft
        ds = 0.0 if abs(z) > _FAR else \
            A * cover * (1.0 - k) * math.exp(-0.5 * z * z) * _INV_SQRT_2PI / soft
        J[m, 11] = A * cover * (1.0 - lit)
        J[m, 12] = ds * (-sa * x + ca * y)
        J[m, 13] = -ds
        J[m, 14] = ds * (-s / soft) * (1.0 if p[14] >= 0 else -1.0)
    return f, J
