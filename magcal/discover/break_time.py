"""How well the data place a drift's break in time: a confidence interval for it.

A drift with a break (:class:`magcal.discover.effects.Drift` with ``t_break_s``) is a
hinge: zero before the break, rising at the rate change after it, beside a level and a
rate before it. The interval inverts the likelihood ratio of the break time: every time
whose fit of the data falls short of the best by less than a critical value is kept.

* The data are the drift's components of the final residual with the fitted hinge added
  back, averaged over hourly bins (the change-point scans' bins, on true time: a bin
  without data is left out, a break inside a gap is judged by the data on both sides).
* The likelihood is Gaussian under an Ornstein-Uhlenbeck plus white noise fitted per
  component to the hourly means of the residual by restricted maximum likelihood
  (:func:`magcal.alignment.ouwhite.fit_component`, the level, rate and hinge as the
  design). At every candidate time the level, the rate before the break and the rate
  change are refitted by generalised least squares: profiled out, not held at the
  named break's values.
* The critical value is simulated for each record: the likelihood ratio at the named
  time over ``n_sim`` records of the fitted noise with the fitted hinge, each
  component's gains divided by an independent ``chi2(nu) / nu`` (:func:`noise_dof`):
  the record estimates its own noise level, and the ratio scales with it, as Student's
  t takes a variance estimated with ``nu`` degrees of freedom.

Why not the theory's critical value: for a continuous kink the break estimator is
asymptotically normal and the ratio chi-squared(1) (Hansen 2017, J. Bus. Econ. Stat. 35,
228; 3.84 at 95 %), but that is the white-noise limit. Whitening a red noise differences
it, and a differenced hinge is a step: as the noise's correlation time grows, the ratio
tends to the step's ``max_s (2 W(s) - |s|)`` (7.35, :mod:`magcal.discover.step_time`).
On 30-day records of 10-min OU plus white noise (400 seeded records per case, the hinge
at a random time, named by :func:`magcal.discover.scan.change_points` as the loop names
it) the ratio's 95 % quantile at the true time was 3.5-4.1 for correlation times up to
2 h, 4.4-5.0 for 6-12 h, 6.5-6.9 for a day and 8.7 for two days, so 3.84 held the truth
in 83-97 % of the records and 7.35 in 93.5-100 % (wider than needed where the noise is
nearly white: 99-100 %). The simulated value follows the colour. With the noise taken
as known it held the truth in 89-93 % for correlation times of one and two days: the
fitted correlation time comes out short in the very records whose wander misplaced the
break. The degrees-of-freedom term is what brings those to 93-97 %; the numbers per
case are in :func:`break_time_interval` (``benchmarks/bench_break_time.py``).

Rejected, with numbers on the same kind of records: the step interval's recipe (least
squares on hourly means scaled by each component's long-run variance) at 3.84 held the
truth in 66-96 %; re-running the whole procedure in each of 100 simulated records
(re-naming the break and refitting the noise) for a two-day correlation time: 90 % of
52 records, no better than the noise taken as known; whitening with the longest
correlation time within 0.5 of the best restricted log-likelihood: as often as the
delivered interval for two days' correlation (94.5 %, 263 h against 264 h on seeds
0-199 / 0-399) and wider for a day's (130 h against 114 h), at the cost of a search of
the noise likelihood per component; ``nu`` the whole effective count less three
(instead of half of it): 92-98.5 % (92.2 % for a day's correlation time).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from magcal.discover.scan import DAY_S, _hourly_bins

#: Coefficients refitted at each candidate break per component (level, rate, rate change).
N_COEF = 3

#: Most hourly bins the profile is computed on: longer records are binned more coarsely
#: (the candidate times' matrix grows with the square of the bins).
MAX_BINS = 2400


@dataclass(frozen=True)
class BreakLikelihood:
    """The break time's profile likelihood and its simulated distribution.

    Attributes
    ----------
    candidates_s : ndarray
        Break times tried (bin starts away from the ends, then any ``extra_s`` given,
        the named time last), s.
    gain : ndarray
        Twice the log-likelihood gain of a hinge at each candidate (summed over the
        components), the level and rate refitted at each.
    lr_sim : ndarray (n_sim,)
        Likelihood ratios at the named time over the simulated records, the noise level
        estimated with ``nu`` degrees of freedom.
    lr_sim_known_noise : ndarray (n_sim,)
        The same with the noise taken as known (for comparison).
    noise : list of tuple
        Per component ``(ou_std_nT, tau_s, white_std_nT, at_bound)`` of the hourly means
        and its ``nu``: ``(fit, nu)``.
    bin_s : float
        Bin width used (s).
    """

    candidates_s: np.ndarray
    gain: np.ndarray
    lr_sim: np.ndarray
    lr_sim_known_noise: np.ndarray
    noise: list
    bin_s: float

    def ratio(self) -> np.ndarray:
        """Likelihood ratio of each candidate against the best."""
        return self.gain.max() - self.gain

    def critical_value(self, level: float = 0.95, known_noise: bool = False) -> float:
        """The ``level`` quantile of the simulated ratios."""
        sim = self.lr_sim_known_noise if known_noise else self.lr_sim
        return float(np.quantile(sim, level))

    def interval(self, critical: float) -> tuple[float, float]:
        """``(after, by)``: from a bin before the earliest candidate kept at ``critical``
        to a bin after the latest (a candidate is a bin start; the truth between two
        of them), always holding the named time."""
        kept = self.candidates_s[self.ratio() <= critical]
        named = float(self.candidates_s[-1])
        return (min(float(kept.min()), named) - self.bin_s,
                max(float(kept.max()), named) + self.bin_s)


def noise_dof(fit, times_s) -> float:
    """Degrees of freedom of an OU + white noise's level on a record: half its effective
    number of independent samples (total variance over the variance of the mean) less
    :data:`N_COEF`, at least 1.

    The half is calibrated by simulation (see the module's notes): with the whole count,
    30-day records with a correlation time of one or two days held the true break time
    in 93.2 and 92.7 % of 400 (seeds 0-399) and 92.2 and 93.0 % (seeds 1000-1399); with
    half, 94.8 and 94.5 % (seeds 0-399) and 93.5 and 93.2 % held out (seeds 2000-2399).

    Examples
    --------
    White noise on 720 hourly means; a one-day correlation time leaves about 6.

    >>> t = np.arange(720) * 3600.0
    >>> noise_dof((0.0, 3600.0, 1.0, False), t), round(noise_dof((1.0, 86400.0, 0.0, False), t))
    (358.5, 6)
    """
    t = np.asarray(times_s, dtype=float)
    dt = float(np.median(np.diff(t)))
    ou, tau, white = float(fit[0]), float(fit[1]), float(fit[2])
    phi = np.exp(-dt / max(tau, 1e-9))
    var_mean = (ou ** 2 * (1 + phi) / max(1 - phi, 1e-300) + white ** 2) / t.size
    n_eff = min((ou ** 2 + white ** 2) / max(var_mean, 1e-300), t.size)
    return float(max(0.5 * (n_eff - N_COEF), 1.0))


def break_likelihood(times_s, residual, t_break_s: float, rate_change, *,
                     bin_s: float = 3600.0, margin_s: float = 0.25 * DAY_S,
                     n_sim: int = 400, seed: int = 0, extra_s=()) -> BreakLikelihood | None:
    """The profile likelihood of a drift's break time and its simulated distribution
    (see the module's notes; :func:`break_time_interval` takes the interval from it).

    Parameters are those of :func:`break_time_interval`; ``extra_s`` are further
    candidate times (e.g. a simulation's truth). None when the record is too short.
    """
    t = np.asarray(times_s, dtype=float)
    r = np.asarray(residual, dtype=float)
    if r.ndim == 1:
        r = r[:, None]
    if r.shape[0] != t.size:
        raise ValueError(f"residual has {r.shape[0]} rows for {t.size} times")
    d = np.asarray(rate_change, dtype=float).reshape(-1)
    if d.size != r.shape[1]:
        raise ValueError(f"rate_change has {d.size} values for {r.shape[1]} components")
    if not (np.all(np.isfinite(d)) and np.isfinite(t_break_s)):
        raise ValueError("the break time and the rate change must be finite")
    if t.size < 2:
        return None
    span = float(t[-1] - t[0])
    bin_s = float(bin_s) * max(int(np.ceil(span / bin_s / MAX_BINS)), 1)
    valid = np.all(np.isfinite(r), axis=1)
    r = np.where(valid[:, None], r, np.nan)
    y = r + np.outer(np.maximum(t - t_break_s, 0.0) / DAY_S, d)
    starts, means = _hourly_bins(t, y, bin_s)
    _, rmeans = _hourly_bins(t, r, bin_s)
    _, tmean = _hourly_bins(t, np.where(valid, t - t[0], np.nan), bin_s)
    ok = np.all(np.isfinite(means), axis=1)
    nb = starts.size
    margin = max(int(np.ceil(margin_s / bin_s)), 2)
    if ok.sum() < 2 * margin + 2 * N_COEF or nb < 2 * margin + 2:
        return None
    tb = t[0] + tmean[ok, 0]
    cand = np.concatenate([starts[margin:nb - margin + 1],
                           np.asarray(extra_s, dtype=float).reshape(-1), [float(t_break_s)]])
    rng = np.random.default_rng(seed)
    gain = np.zeros(cand.size)
    sim = np.zeros((cand.size, n_sim))
    sim_known = np.zeros((cand.size, n_sim))
    noise = []
    for c, (fit, q, rh, ry) in enumerate(_whitened(tb, means[ok], rmeans[ok], cand,
                                                   float(t_break_s))):
        den = np.maximum(np.sum(rh ** 2, axis=0), 1e-300)
        gain += (rh.T @ ry) ** 2 / den
        # simulated records: the whitened noise is white, freed of level and rate; the
        # named hinge, whitened and freed of them alike, is the last column
        z = rng.standard_normal((rh.shape[0], n_sim))
        z -= q @ (q.T @ z)
        z += (d[c] * rh[:, -1])[:, None]
        g = (rh.T @ z) ** 2 / den[:, None]
        nu = noise_dof(fit, tb)
        sim_known += g
        sim += g * (nu / rng.chisquare(nu, n_sim))[None, :]
        noise.append((fit, nu))
    return BreakLikelihood(cand, gain, sim.max(axis=0) - sim[-1],
                           sim_known.max(axis=0) - sim_known[-1], noise, bin_s)


def _whitened(tb, y, resid, cand, named):
    """Per component: the noise fit, an orthonormal basis of the whitened level and
    rate, and the whitened hinges at ``cand`` and data freed of that basis."""
    from magcal.alignment.ouwhite import fit_component, kalman_gains, whiten

    x0 = np.column_stack([np.ones_like(tb), (tb - tb.mean()) / DAY_S])
    hinges = np.maximum(tb[:, None] - cand[None, :], 0.0) / DAY_S
    design = np.column_stack([x0, hinges[:, -1]])
    for c in range(y.shape[1]):
        fit = fit_component(resid[:, c], tb, design=design)
        var = fit[0] ** 2 + fit[2] ** 2
        w = whiten(np.column_stack([x0, hinges, y[:, c]]),
                   kalman_gains(tb, fit[1], fit[2] ** 2 / var)) / np.sqrt(var)
        q, _ = np.linalg.qr(w[:, :2])
        rest = w[:, 2:] - q @ (q.T @ w[:, 2:])
        yield fit, q, rest[:, :-1], rest[:, -1]


def break_time_interval(times_s, residual, t_break_s: float, rate_change, *,
                        level: float = 0.95, bin_s: float = 3600.0,
                        margin_s: float = 0.25 * DAY_S, n_sim: int = 400,
                        seed: int = 0) -> tuple[float, float] | None:
    """Confidence interval of a drift's break time from the residual left after fitting it.

    Parameters
    ----------
    times_s : array_like, shape (n,)
        Increasing sample times (s).
    residual : array_like, shape (n, m)
        The final residual (nT) in the drift's ``m`` components, NaN where missing: the
        noise once every named effect, the drift and its break included, is taken out.
    t_break_s : float
        The named break time (s).
    rate_change : array_like, shape (m,)
        The fitted change of drift rate per component (nT/day).
    level : float
        Confidence level.
    bin_s : float
        Bin width (s); records of more than :data:`MAX_BINS` bins take a multiple of it.
        The interval is resolved to a bin on each side.
    margin_s : float
        No break closer than this to either end (as the change-point scans).
    n_sim : int
        Simulated records for the critical value.
    seed : int
        Seed of the simulation (the interval is reproducible).

    Returns
    -------
    (lo_s, hi_s) or None
        The rate changed after ``lo_s`` and at or before ``hi_s`` (s): a bin before the
        earliest candidate time kept to a bin after the latest. Always holds
        ``t_break_s``. None when the record is too short to place a break.

    Notes
    -----
    Measured on 30-day records of 10-min OU plus 1 nT white noise, the break at a random
    time in the middle 40 % named by :func:`magcal.discover.scan.change_points` and the
    hinge refitted by least squares; 400 records per case (seeds 2000-2399, held out:
    the method was chosen on seeds 0-399 and 1000-1399). Coverage of the 95 % interval,
    its median width, and the 95th percentile of the named time's error:

    ==================================  ========  =======  ===========
    rate change (nT/day), OU std, tau   coverage  width    error 95 %
    ==================================  ========  =======  ===========
    0.6, 0.3 nT, 10 min (near white)    97.8 %    12 h     5 h
    0.5 x 3 components, 2 nT, 2 h       97.5 %    88 h     102 h
    0.7 x 3, 2 nT, 2 h                  97.0 %    61 h     65 h
    0.8 / -0.4 / 0.2, 1.5 nT, 3 h       97.8 %    69 h     50 h
    1 and 1, 1 nT, 6 h                  95.3 %    39 h     24 h
    0.3, 1 nT, 6 h                      95.5 %    218 h    162 h
    1.5 and 0, 1 nT, 12 h, 3 days gap   95.0 %    63 h     31 h
    1.2, 1.5 nT, 18 h, 5 % rows missing 94.5 %    134 h    57 h
    1, 1 nT, 1 day                      93.5 %    122 h    48 h
    2 and -1, 1 nT, 1 day               97.3 %    52 h     21 h
    0.8, 1 nT, 2 days                   93.2 %    294 h    91 h
    ==================================  ========  =======  ===========

    Where the correlation time is a day or more the record holds few of them, the noise
    level is uncertain and the interval is wide (2.5-3.2 times the error percentile);
    there it still holds the truth less often than stated (93 %).

    Examples
    --------
    A rate change of 1 nT/day in two components over white noise of 1 nT (10-min
    samples, 20 days): placed to within about a day.

    >>> rng = np.random.default_rng(3)
    >>> t = np.arange(0, 20 * 86400, 600.0)
    >>> x = np.column_stack([np.ones_like(t), t / 86400, np.maximum(t - 8.5 * 86400, 0) / 86400])
    >>> y = np.outer(x[:, 2], [1.0, -1.0]) + rng.normal(0, 1, (t.size, 2))
    >>> beta = np.linalg.lstsq(x, y, rcond=None)[0]
    >>> lo, hi = break_time_interval(t, y - x @ beta, 8.5 * 86400, beta[2])
    >>> bool(lo <= 8.5 * 86400 <= hi), bool((hi - lo) / 3600 <= 48)
    (True, True)
    """
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")
    like = break_likelihood(times_s, residual, t_break_s, rate_change, bin_s=bin_s,
                            margin_s=margin_s, n_sim=n_sim, seed=seed)
    if like is None:
        return None
    return like.interval(like.critical_value(level))
