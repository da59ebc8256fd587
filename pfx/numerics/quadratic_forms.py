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

Both functions are written once in the array namespace (:mod:`pfx.numerics.arrays`): on NumPy
arrays they compute the numbers above, on JAX arrays the same test and square inside the jax
backend's compiled step (in float64, as on NumPy). A compiled program has fixed shapes, so
no covariance is left out by a mask: one that fails the finiteness and variance checks is
replaced by the identity before its correlations are computed (no NaN, infinity or zero
reaches the arithmetic), and the others' correlations are the same numbers either way.
"""

from __future__ import annotations

import numpy as np

from pfx.numerics.arrays import namespace

# The smallest eigenvalue a covariance's correlation matrix may have for its inverse to be
# trusted (module docstring): half the digits of a double.
SMALLEST_CORRELATION_EIGENVALUE = float(np.sqrt(np.finfo(float).eps))


def reliably_invertible(covariances):
    """True where a covariance can be inverted reliably (module docstring): (..., d, d) -> (...)."""
    xp = namespace(covariances)
    covariances = xp.asarray(covariances, dtype=xp.float64)
    variances = xp.diagonal(covariances, axis1=-2, axis2=-1)
    passed = (xp.all(xp.isfinite(covariances), axis=(-2, -1))
              & xp.all(variances >= np.finfo(float).tiny, axis=-1))
    kept = xp.where(passed[..., None, None], covariances, xp.eye(covariances.shape[-1]))
    scale = xp.sqrt(xp.diagonal(kept, axis1=-2, axis2=-1))
    symmetric = 0.5 * (kept + xp.swapaxes(kept, -1, -2))
    correlations = symmetric / (scale[..., :, None] * scale[..., None, :])    # the identity where not passed
    smallest = xp.linalg.eigvalsh(correlations)[..., 0]
    return passed & (smallest > SMALLEST_CORRELATION_EIGENVALUE)


def normalised_squares(vectors, covariances):
    """:math:`v^\\top P^{-1} v` for every leading index: (..., d), (..., d, d) -> (...), NaN where
    :math:`P` cannot be inverted reliably (:func:`reliably_invertible`)."""
    xp = namespace(vectors, covariances)
    vectors = xp.asarray(vectors, dtype=xp.float64)
    covariances = xp.asarray(covariances, dtype=xp.float64)
    reliable = reliably_invertible(covariances)
    # The others are replaced by the identity, so that the solver never meets them.
    usable = xp.where(reliable[..., None, None], covariances, xp.eye(covariances.shape[-1]))
    with np.errstate(over="ignore", invalid="ignore"):
        solved = xp.linalg.solve(usable, vectors[..., None])[..., 0]
        squares = xp.einsum("...d,...d->...", vectors, solved)
    return xp.where(reliable, squares, np.nan)
