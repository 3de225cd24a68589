"""Background subtraction by exponential averaging (Section 9.2 of the CoLOR chapter)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt


class ExponentialBackgroundSubtractor:
    """Removes static echoes (coupling, walls, furniture) from successive impulse responses.

    The background is an exponential average of past impulse responses, as in the
    background subtraction of Section 9.2 of the CoLOR chapter:

    .. math::

        y_k = h_k - b_{k-1}, \\qquad b_k = b_{k-1} + \\alpha y_k = (1-\\alpha) b_{k-1} + \\alpha h_k

    so that echoes that stay put for many more than ``1/alpha`` impulse responses vanish
    from ``y_k`` while moving people remain. Complex baseband is subtracted coherently.

    Parameters
    ----------
    alpha : float
        Forgetting factor in (0, 1]; time constant ``1/alpha`` impulse responses.
    """

    def __init__(self, alpha: float = 0.05) -> None:
        if not 0.0 < alpha <= 1.0:
            raise ValueError(f"alpha must be in (0, 1], got {alpha}")
        self.alpha = float(alpha)
        self._background: npt.NDArray | None = None

    def reset(self) -> None:
        """Forget the background; the next call re-initialises it."""
        self._background = None

    def state_for(self, h: npt.NDArray) -> npt.NDArray | None:
        """The background :math:`b_{k-1}` that :meth:`step` would subtract from ``h`` (the
        array itself: a caller that subtracts and updates it in place, as
        :meth:`~node_agent.dsp.cfar.GaussianCfarDetector.detect_subtracting` does, takes
        over this step), or None when :meth:`step` would (re)initialise it instead."""
        bg = self._background
        if bg is None or bg.shape != h.shape or bg.dtype != h.dtype:
            return None
        return bg

    def step(self, h: npt.NDArray, out: npt.NDArray | None = None) -> npt.NDArray:
        """Subtract the background, then update it.

        Parameters
        ----------
        h : ndarray, float32 or complex64, shape (n_rx, n)
            Impulse responses.
        out : ndarray, optional
            Array of ``h``'s shape and dtype that receives the result (the caller owns it
            until the next call); a new array when omitted.

        Returns
        -------
        ndarray, same dtype and shape as ``h``
            ``h - background``; all zeros on the first call (or after a shape change),
            which initialises the background to ``h``.
        """
        bg = self._background
        if bg is None or bg.shape != h.shape or bg.dtype != h.dtype:
            self._background = np.array(h, copy=True, order="C")
            self._scaled = np.empty_like(self._background)
            if out is None:
                return np.zeros_like(h)
            out.fill(0)
            return out
        if out is None:
            y = h - bg
        else:
            # row by row: a 2-D ufunc on a strided window of a wider frame goes through
            # numpy's buffered iterator (a copy of the frame), 1-D contiguous rows do not
            for row, b, o in zip(h, bg, out, strict=True):
                np.subtract(row, b, out=o)
            y = out
        # in place: no allocation per call for the (n_rx, n) background
        bg += np.multiply(y, self.alpha, out=self._scaled)
        return y
