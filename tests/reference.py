"""A plain, independent numpy implementation of the paper's objective (DECISIONS.md), for
tests only: python loops and dicts over cells, no code shared with jaxpose."""

import math

import numpy as np


def reference_frame(points):
    g = points.mean(axis=0)
    X = points - g
    C = X.T @ X
    J = np.trace(C) * np.eye(3) - C
    w, U = np.linalg.eigh(J)
    U = U[:, np.argsort(w)[::-1]]
    n1, n2 = U[:, 0], U[:, 1]
    n1 = n1 if n1[np.argmax(np.abs(n1))] > 0 else -n1
    n2 = n2 if n2[np.argmax(np.abs(n2))] > 0 else -n2
    return g, np.stack([n1, n2, np.cross(n1, n2)], axis=1)


def printed_rotation(t, f, s):
    st, ct, sf, cf, ss, cs = math.sin(t), math.cos(t), math.sin(f), math.cos(f), math.sin(s), math.cos(s)
    return np.array(
        [
            [st * sf * ss + ct * cs, st * sf * cs - ct * ss, st * cf],
            [cf * ss, cf * cs, -sf],
            [ct * sf * ss - st * cs, ct * sf * cs + st * ss, ct * cf],
        ]
    )


def _cell(x, lo, d, e):
    return int(math.floor((x - lo) / d + 0.5)) + e


def _direction(cells_a, cells_b, radius):
    """Σ_c k_c r_c max_{c' ∈ b, Q(c)} exp(−δ) / Σ k_c r_c over the filled cells c of a."""
    num = den = 0.0
    for (a, b), k in cells_a.items():
        best = 0.0
        for da in (-1, 0, 1):
            for db in (-1, 0, 1):
                if (a + da, b + db) in cells_b:
                    best = max(best, math.exp(-math.hypot(da, db)))
        w = k * radius(a, b)
        num += best * w
        den += w
    return num / den if den > 0 else 0.0


def reference_objective(prev, curr, p, d=0.026, extension=0.2, slices=1):
    """f(p) of DECISIONS.md for two (N, 3) camera-frame clouds of valid points."""
    g, axes = reference_frame(prev)
    A = (prev - g) @ axes
    q = ((curr - g) @ axes - np.asarray(p[3:])) @ printed_rotation(*p[:3])
    scores = []
    for j in range(3):
        ju, jv = (j + 1) % 3, (j + 2) % 3
        for k in range(slices):
            off = 2 * (k - (slices - 1) / 2) * d
            sel = np.abs(A[:, j] - off) <= d
            if not sel.any():
                lo_u = lo_v = 0.0
                m_u = m_v = 0
            else:
                u, v = A[sel, ju], A[sel, jv]
                lo_u, lo_v = u.min(), v.min()
                m_u = int(math.floor((u.max() - lo_u) / d + 0.5))
                m_v = int(math.floor((v.max() - lo_v) / d + 0.5))
            e_u, e_v = int(math.floor(extension * m_u + 0.5)), int(math.floor(extension * m_v + 0.5))
            n_u, n_v = m_u + 2 * e_u + 1, m_v + 2 * e_v + 1

            def pattern(points, mask):
                cells = {}
                for x, y in zip(points[mask, ju], points[mask, jv], strict=True):
                    a, b = _cell(x, lo_u, d, e_u), _cell(y, lo_v, d, e_v)
                    if 0 <= a < n_u and 0 <= b < n_v:
                        cells[a, b] = cells.get((a, b), 0) + 1
                return cells

            prev_cells = pattern(A, sel)
            curr_cells = pattern(q, np.abs(q[:, j] - off) <= d)

            def radius(a, b):
                return math.hypot(lo_u + (a - e_u) * d, lo_v + (b - e_v) * d)

            fwd = _direction(prev_cells, curr_cells, radius)
            bwd = _direction(curr_cells, prev_cells, radius)
            scores.append((fwd + bwd) / 2)
    return float(np.mean(scores))
