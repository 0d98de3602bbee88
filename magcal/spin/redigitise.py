"""Non-equispaced to equispaced samples by frequency folding (Kivelson et al. 1992, App. 1).

Galileo low-rate science returns 3 vectors per 2/3 s frame at 0, 7/30 and 14/30 s.
The record is split into three series ``G_i`` (every third sample), each equispaced at
the frame period ``T`` but shifted by ``tau_i``. The DFT of each is the DFT of the wanted
equispaced series ``G`` (spacing ``T/3``) folded three times, with the phase shift of
its delay:

    G_i(f) = sum_{n=-1,0,1} G(f + 2 n f_N*) exp(2 pi i (f + 2 n f_N*) tau_i) / 3,

``f_N* = 1 / (2 T)``. Per frequency these are 3 complex equations in 3 complex unknowns
(the paper's 6 x 6 real system, Eq. 5); solving them and transforming back gives ``G``
on the grid ``t0 + k T / 3``.
"""

from __future__ import annotations

import numpy as np

from magcal.errors import InputError

#: Galileo frame period (s) and sample delays within a frame (s).
GALILEO_FRAME_S = 2.0 / 3.0
GALILEO_OFFSETS_S = (0.0, 7.0 / 30.0, 14.0 / 30.0)


def redigitise(x, *, frame_s: float = GALILEO_FRAME_S,
               offsets_s=GALILEO_OFFSETS_S) -> np.ndarray:
    """Resample a frame-structured non-equispaced series onto the equispaced grid.

    Parameters
    ----------
    x : array_like, shape (n,) or (n, m)
        Samples in time order, ``n`` a multiple of 3 and starting with the first sample
        of a frame; sample ``3 k + i`` is at ``t0 + k frame_s + offsets_s[i]``.
    frame_s : float
        Frame period ``T``.
    offsets_s : sequence of 3 float
        Delays ``tau_i`` of the samples within a frame.

    Returns
    -------
    ndarray, same shape as ``x``
        Values at ``t0 + j frame_s / 3``.

    Examples
    --------
    >>> import numpy as np
    >>> k = np.arange(300)
    >>> t = (k // 3) * (2 / 3) + np.array([0, 7 / 30, 14 / 30])[k % 3]
    >>> y = redigitise(np.sin(2 * np.pi * 0.3 * t))
    >>> grid = np.arange(300) * (2 / 9)
    >>> bool(np.max(np.abs(y - np.sin(2 * np.pi * 0.3 * grid))[30:-30]) < 0.02)
    True
    """
    x = np.asarray(x, dtype=float)
    if len(offsets_s) != 3:
        raise InputError("redigitisation needs exactly three samples per frame")
    if x.shape[0] % 3 or x.shape[0] < 6:
        raise InputError("redigitisation needs whole frames of 3 samples (length a multiple of 3)")
    if not np.all(np.isfinite(x)):
        raise InputError("redigitisation needs a gap-free record (no missing values)")
    squeeze = x.ndim == 1
    xs = x.reshape(x.shape[0], -1)
    m = xs.shape[0] // 3
    g = np.stack([xs[i::3] for i in range(3)])            # (3, M, cols)
    gf = np.fft.fft(g, axis=1)                            # (3, M, cols)
    n = 3 * m
    tau = np.asarray(offsets_s, dtype=float)
    # Unknown bins of the full series that fold onto sub-series bin q: k = q + l M, taken
    # in the symmetric range (-n/2, n/2] so the delays act as for a band-limited signal.
    q = np.arange(m)
    k = q[:, None] + m * np.arange(3)[None, :]            # (M, 3)
    k_sym = np.where(k > n // 2, k - n, k)
    f = k_sym / (m * frame_s)                              # Hz
    a = np.exp(2j * np.pi * f[:, None, :] * tau[None, :, None]) / 3.0   # (M, 3 eq, 3 unk)
    rhs = np.moveaxis(gf, 0, 1)                            # (M, 3, cols)
    sol = np.linalg.solve(a, rhs)                          # (M, 3, cols)
    full = np.zeros((n, xs.shape[1]), dtype=complex)
    full[k.ravel()] = sol.reshape(-1, xs.shape[1])
    y = np.fft.ifft(full, axis=0).real
    return y[:, 0] if squeeze else y.reshape(x.shape)


def galileo_times(n_frames: int, t0_s: float = 0.0) -> np.ndarray:
    """Sample times of ``n_frames`` Galileo low-rate frames.

    Examples
    --------
    >>> (galileo_times(2) * 30).round(6).tolist()
    [0.0, 7.0, 14.0, 20.0, 27.0, 34.0]
    """
    k = np.arange(3 * n_frames)
    return t0_s + (k // 3) * GALILEO_FRAME_S + np.asarray(GALILEO_OFFSETS_S)[k % 3]
