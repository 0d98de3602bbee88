"""Amplitude of each discovered effect with a standard error from the alignment's noise model.

The discovery loop decides *whether* an effect is there (cross-validation and a Wald test
robust to correlated noise). How *large* it is, and how well that is known, is reported
here with the same noise model as the alignment angles
(:mod:`magcal.alignment.ouwhite`): per component an Ornstein-Uhlenbeck process plus
white noise, fitted by exact likelihood to the final residual. The coefficients are the
loop's joint least-squares fit, so their covariance is the sandwich
``(X'X)^-1 X' C X (X'X)^-1`` with ``C`` the fitted noise covariance; ``C X`` is exact
for any sampling (two exponential recursions per column, gaps included).

The amplitude of an effect in a component is the root mean square of its contribution
over the record (a constant offset: its absolute value; a sinusoid of amplitude A:
A / sqrt 2), with the standard error by the delta method.
"""

from __future__ import annotations

import numpy as np

from magcal.alignment.noise import lag_correlation


def ou_times(x, times_s, tau_s: float) -> np.ndarray:
    """``sum_j exp(-|t_i - t_j| / tau) x_j`` for each row ``i`` of ``x`` (n,) or (n, k).

    Exact for irregular times, in O(n): one forward and one backward recursion.

    Examples
    --------
    >>> t = np.array([0.0, 1.0, 3.0])
    >>> k = np.exp(-np.abs(t[:, None] - t[None, :]) / 2.0)
    >>> np.allclose(ou_times(np.eye(3), t, 2.0), k)
    True
    """
    from scipy.signal import lfilter

    v = np.asarray(x, dtype=float)
    one = v.ndim == 1
    v = v[:, None] if one else v
    phi = lag_correlation(np.asarray(times_s, dtype=float), tau_s)

    def forward(y, ph):
        out = np.empty_like(y)
        change = np.flatnonzero(np.diff(ph) != 0) + 1
        bounds = np.concatenate([[0], change, [y.shape[0]]])
        state = np.zeros(y.shape[1])
        for i0, i1 in zip(bounds[:-1], bounds[1:]):
            a = float(ph[i0])
            out[i0:i1] = lfilter([1.0], [1.0, -a], y[i0:i1], axis=0,
                                 zi=(a * state)[None, :])[0]
            state = out[i1 - 1]
        return out

    fwd = forward(v, phi)
    # backward: B_i = x_i + phi_{i+1} B_{i+1}; reversed, the lag of row i is phi_{i+1}
    ph_rev = np.concatenate([[0.0], phi[1:][::-1]])
    bwd = forward(v[::-1], ph_rev)[::-1]
    out = fwd + bwd - v
    return out[:, 0] if one else out


def effect_amplitudes(inputs, measured, effects, noise=None) -> tuple[list[dict], dict]:
    """Amplitude and standard error per effect and component.

    Parameters
    ----------
    inputs : EffectInputs
    measured : ndarray, shape (n, m)
        Measured field (nT), NaN where missing.
    effects : sequence of FittedEffect
        The loop's effects with their joint coefficients ``beta``.
    noise : sequence of (ou_std_nT, tau_s, white_std_nT, at_bound), optional
        Noise model per component; by default fitted to the final residual
        (:func:`magcal.alignment.ouwhite.fit_component`). Given, it states the standard
        errors under a known noise (the tests' truth).

    Returns
    -------
    per_effect : list of dict
        ``{"amplitude_nT": {comp: value}, "amplitude_se_nT": {comp: value}}`` per effect
        (components the effect does not touch are left out).
    noise : dict
        The fitted noise model (:meth:`OUWhiteNoise.to_dict`), or a ``skipped`` reason.
    """
    from magcal.alignment.ouwhite import fit_component, noise_from_components

    comps = tuple(inputs.components)
    y = np.asarray(measured, dtype=float) - inputs.model
    mask = np.isfinite(y)
    if not effects:
        return [], {"skipped": "no effect added"}
    cols = [np.asarray(e.effect.columns(inputs), dtype=float) for e in effects]
    sizes = [c.shape[0] for c in cols]
    x = np.concatenate(cols, axis=0)  # (p, n, m)
    beta = np.concatenate([np.asarray(e.beta, dtype=float) for e in effects])
    t = np.asarray(inputs.times_s, dtype=float)
    resid = y - np.tensordot(beta, x, axes=(0, 0))
    p = x.shape[0]
    xtx = np.zeros((p, p))
    meat = np.zeros((p, p))
    fits = []
    for c in range(len(comps)):
        ok = mask[:, c]
        if ok.sum() < 20:
            fits.append((0.0, 1.0, 0.0, True))
            continue
        tc = t[ok] - t[ok][0]
        fit = (fit_component(resid[ok, c], tc, design=np.ones((int(ok.sum()), 1)))
               if noise is None else tuple(noise[c]))
        fits.append(fit)
        xc = x[:, ok, c].T  # (n_c, p)
        ou_std, tau, white = fit[0], fit[1], fit[2]
        cx = ou_std ** 2 * ou_times(xc, tc, tau) + white ** 2 * xc
        xtx += xc.T @ xc
        meat += xc.T @ cx
    try:
        inv = np.linalg.pinv(xtx)
    except np.linalg.LinAlgError:  # pragma: no cover - pinv does not raise on finite input
        inv = np.full((p, p), np.nan)
    cov = inv @ meat @ inv
    per_effect = []
    k = 0
    for e, q in zip(effects, sizes):
        sl = slice(k, k + q)
        amp, se = {}, {}
        for c, name in enumerate(comps):
            ok = mask[:, c]
            xc = x[sl, ok, c]  # (q, n_c)
            if not np.any(xc):
                continue
            f = beta[sl] @ xc
            a = float(np.sqrt(np.mean(f ** 2)))
            g = xc @ f / (f.size * a) if a > 0 else np.zeros(q)
            amp[name] = a
            se[name] = float(np.sqrt(max(g @ cov[sl, sl] @ g, 0.0)))
        per_effect.append({"amplitude_nT": amp, "amplitude_se_nT": se})
        k += q
    noise = noise_from_components(fits, t - t[0]).to_dict()
    noise["model"] += ", fitted to the final residual"
    return per_effect, noise
