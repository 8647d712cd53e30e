"""Stage 2's output-error pass (core.output_error.Problem's prefix scan) as one loop over the rows."""

from __future__ import annotations

import numpy as np

from .base import _jit


# -- stage 2's output-error fit (core.output_error.Problem) ---------------------
@_jit
def _oe_system(c_f, c_r, i_z, swing, d, cd, v, x0, alpha, phi_dd, l_f, l_r, m):
    """output_error._system at one point: (a11, a12, a21, a22, b1, b2)."""
    e = alpha - c_f * (cd / v)
    y0 = x0 + c_f * (d * cd)
    cr = c_r / v
    c1, c2 = (e - cr) / m, (e * l_f + cr * l_r) / m
    a0 = y0 / m + swing * phi_dd
    return c1, c2 - v, (l_f * e + l_r * cr) / i_z, (l_f * l_f * e - l_r * l_r * cr) / i_z, a0, l_f * y0 / i_z


@_jit
def oe_states(d, cd, v_x, x0, alpha, phi_dd, h, frac, first, theta, swing, bend_f, bend_r, l_f, L, m):
    """Problem._scan(Problem._maps(...)) as one sequential pass: (Phi, G) per row, (6, S, n).

    ``d`` ... ``phi_dd``: the _Pre of the steps (n_steps, 2 sub + 1); ``h`` (n_steps,) the
    sub-step; ``frac`` (2 sub + 1,) the points' place in it; ``first`` (n,) a window's first row
    (identity, zero); ``theta`` (S, 3) C_f, C_r, I_z; ``swing`` (S,); ``bend_f``/``bend_r`` (S, n)
    each axle's secant factor per row, linear between the rows (Problem._at_steps), or empty for
    the linear law.  Row i composes its step's map onto row i-1's, x_i = F x_i-1 + g:
    the prefix scan's products, associated left to right instead of in a tree."""
    S, n = theta.shape[0], first.shape[0]
    sub = (d.shape[1] - 1) // 2
    l_r = L - l_f
    bent = bend_f.shape[0] > 0
    out = np.empty((6, S, n))
    for s in range(S):
        i_z, sw = theta[s, 2], swing[s]
        p11, p12, p21, p22, q1, q2 = 1.0, 0.0, 0.0, 1.0, 0.0, 0.0
        j = -1  # the step reaching this row
        for i in range(n):
            if first[i]:
                p11, p12, p21, p22, q1, q2 = 1.0, 0.0, 0.0, 1.0, 0.0, 0.0
            else:
                j += 1
                hj = h[j]
                hh = 0.5 * hj * hj
                f11, f12, f21, f22, g1, g2 = 1.0, 0.0, 0.0, 1.0, 0.0, 0.0
                for k in range(sub):
                    p, q = 2 * k, 2 * k + 1  # the sub-step's start and midpoint (midpoint rule)
                    cf_p, cr_p, cf_q, cr_q = theta[s, 0], theta[s, 1], theta[s, 0], theta[s, 1]
                    if bent:
                        bf0, bf1, br0, br1 = bend_f[s, i - 1], bend_f[s, i], bend_r[s, i - 1], bend_r[s, i]
                        cf_p *= bf0 + frac[p] * (bf1 - bf0)
                        cr_p *= br0 + frac[p] * (br1 - br0)
                        cf_q *= bf0 + frac[q] * (bf1 - bf0)
                        cr_q *= br0 + frac[q] * (br1 - br0)
                    n11, n12, n21, n22, nb1, nb2 = _oe_system(
                        cf_p, cr_p, i_z, sw, d[j, p], cd[j, p], v_x[j, p], x0[j, p], alpha[j, p], phi_dd[j, p],
                        l_f, l_r, m,
                    )  # fmt: skip
                    m11, m12, m21, m22, mb1, mb2 = _oe_system(
                        cf_q, cr_q, i_z, sw, d[j, q], cd[j, q], v_x[j, q], x0[j, q], alpha[j, q], phi_dd[j, q],
                        l_f, l_r, m,
                    )  # fmt: skip
                    M11 = 1.0 + hj * m11 + hh * (m11 * n11 + m12 * n21)
                    M12 = hj * m12 + hh * (m11 * n12 + m12 * n22)
                    M21 = hj * m21 + hh * (m21 * n11 + m22 * n21)
                    M22 = 1.0 + hj * m22 + hh * (m21 * n12 + m22 * n22)
                    w1 = hj * mb1 + hh * (m11 * nb1 + m12 * nb2)
                    w2 = hj * mb2 + hh * (m21 * nb1 + m22 * nb2)
                    f11, f12, f21, f22 = (
                        M11 * f11 + M12 * f21,
                        M11 * f12 + M12 * f22,
                        M21 * f11 + M22 * f21,
                        M21 * f12 + M22 * f22,
                    )
                    g1, g2 = M11 * g1 + M12 * g2 + w1, M21 * g1 + M22 * g2 + w2
                p11, p12, p21, p22, q1, q2 = (
                    f11 * p11 + f12 * p21,
                    f11 * p12 + f12 * p22,
                    f21 * p11 + f22 * p21,
                    f21 * p12 + f22 * p22,
                    f11 * q1 + f12 * q2 + g1,
                    f21 * q1 + f22 * q2 + g2,
                )
            out[0, s, i], out[1, s, i], out[2, s, i], out[3, s, i] = p11, p12, p21, p22
            out[4, s, i], out[5, s, i] = q1, q2
    return out
