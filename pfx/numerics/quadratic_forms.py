r"""Normalised squares :math:`v^\top P^{-1} v` (NEES, NIS) that are never a wrong number.

A normalised square is never negative: :math:`P` is a covariance, positive semidefinite, and
where it is positive definite so is its inverse. In floating point a covariance can be
positive definite on paper and not in the computer: a particle cloud whose weight has
collapsed onto one or a few particles has a weighted covariance of rank below the state
dimension (two distinct particles span a line), and rounding makes its smallest eigenvalues
tiny numbers of either sign. Solving with such a matrix returns whatever the rounding
dictates: NEES of :math:`-6.5\times10^{23}` and :math:`-2.6\times10^{39}` were seen from a
500-particle cloud collapsed to about one particle. Such a step has no NEES; this module
returns NaN for it (an empty field in the tables), and the metrics count the steps left out.

**The test.** The normalised square does not depend on the units of the components: with
:math:`D = \operatorname{diag}(P)^{1/2}` and the correlation matrix :math:`C = D^{-1} P D^{-1}`,

.. math:: v^\top P^{-1} v = (D^{-1} v)^\top C^{-1} (D^{-1} v),

so a heading in radians beside a position in kilometres makes :math:`P` badly scaled without
making the square hard to compute. How hard it is depends on :math:`C`, whose eigenvalues lie
in :math:`[0, d]` and sum to :math:`d` (van der Sluis 1969: this diagonal scaling is within a
factor :math:`d` of the best one). A covariance is **reliably invertible** when its entries are
finite, its variances are positive normal numbers, and the smallest eigenvalue of :math:`C`
exceeds :math:`\sqrt{\varepsilon} \approx 1.5\times10^{-8}` (:data:`SMALLEST_CORRELATION_EIGENVALUE`,
:math:`\varepsilon` the double-precision machine epsilon). Why that bound: a covariance
summed from :math:`N` weighted particles carries a rounding error of about
:math:`N\varepsilon` relative to :math:`\sqrt{P_{ii} P_{jj}}` in each entry, which moves the
eigenvalues of :math:`C` by up to about :math:`d N \varepsilon` (Weyl's inequality); the
relative error of the normalised square is then at most about
:math:`d N \varepsilon / \lambda_{\min}(C) \le d N \sqrt{\varepsilon}`, under 1% for
:math:`d N` up to :math:`6.7\times10^5` (a 4-D state with 100 000 particles). Below the bound
the smallest eigenvalue is within a few orders of magnitude of its own rounding error: its
sign, and the square's, are not known. The bound is a property of :math:`C` alone, so a
filter that is merely very sure (a tiny covariance, a huge NEES) keeps its value: a NEES of
:math:`10^{20}` from a well-conditioned :math:`P` is the right number for an overconfident
filter, and is kept.

Where the covariance passes, the square is computed exactly as before this test existed
(``numpy.linalg.solve`` with :math:`P` itself), so that the values of every covariance that
was never in doubt stay the same to the last bit.
"""

from __future__ import annotations

import numpy as np

# The smallest eigenvalue a covariance's correlation matrix may have for its inverse to be
# trusted (module docstring): half the digits of a double.
SMALLEST_CORRELATION_EIGENVALUE = float(np.sqrt(np.finfo(float).eps))


def reliably_invertible(covariances: np.ndarray) -> np.ndarray:
    """True where a covariance can be inverted reliably (module docstring): (..., d, d) -> (...)."""
    covariances = np.asarray(covariances, dtype=float)
    variances = np.diagonal(covariances, axis1=-2, axis2=-1)
    passed = (np.isfinite(covariances).all(axis=(-2, -1))
              & (variances >= np.finfo(float).tiny).all(axis=-1))
    correlations = np.broadcast_to(np.eye(covariances.shape[-1]), covariances.shape).copy()
    if passed.any():
        scale = np.sqrt(variances[passed])
        kept = covariances[passed]
        symmetric = 0.5 * (kept + np.swapaxes(kept, -1, -2))
        correlations[passed] = symmetric / (scale[..., :, None] * scale[..., None, :])
    smallest = np.linalg.eigvalsh(correlations)[..., 0]
    return passed & (smallest > SMALLEST_CORRELATION_EIGENVALUE)


def normalised_squares(vectors: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """:math:`v^\\top P^{-1} v` for every leading index: (..., d), (..., d, d) -> (...), NaN where
    :math:`P` cannot be inverted reliably (:func:`reliably_invertible`)."""
    vectors = np.asarray(vectors, dtype=float)
    covariances = np.asarray(covariances, dtype=float)
    reliable = reliably_invertible(covariances)
    # The others are replaced by the identity, so that the solver never meets them.
    usable = np.where(reliable[..., None, None], covariances, np.eye(covariances.shape[-1]))
    with np.errstate(over="ignore", invalid="ignore"):
        solved = np.linalg.solve(usable, vectors[..., None])[..., 0]
        squares = np.einsum("...d,...d->...", vectors, solved)
    return np.where(reliable, squares, np.nan)
