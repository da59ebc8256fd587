r"""Poisson and binomial counts by branch-free inverse CDFs: one uniform in, one count out.

A count X with CDF F is drawn from one uniform u in [0, 1) as its quantile

.. math::

    X = Q(u) = \min\{k : F(k) > u\} = \#\{j \ge 0 : F(j) \le u\},

so P(X <= k) = P(u < F(k)) = F(k) exactly, and X is monotone in u. NumPy's and JAX's own
samplers (:mod:`pfx.numerics.seeding`, :mod:`pfx.numerics.key_streams`) draw exactly, by
rejection: a loop whose length depends on the values, which a vectorised or compiled program
runs until its slowest lane accepts. Here every lane does the same fixed work, written once
against the array namespace (:func:`pfx.numerics.arrays.namespace`: NumPy or jax.numpy, the
computation in the uniforms' dtype), so it traces under ``jax.jit`` and runs on a GPU as on a
CPU. The regimes are computed side by side and one is picked per lane with ``where``; each is
given inputs that are safe for it on the lanes that do not use it, so no NaN (value or gradient)
comes from an unused branch. Exactness is given up only above the first K counts:

**Counts below K = 24: exact, by a bottom-up sum.** F(j) = P(0) + ... + P(j) for j < K, with
P(j) = P(j-1) rate / j (Poisson, P(0) = e^(-rate)) or P(j) = P(j-1) (n - j + 1) p / (j (1 - p))
(binomial, P(0) = (1 - p)^n); the number of F(j) <= u among them is X whenever X < K. The
same K terms for every lane: no loop whose length depends on the values.

**Counts of K or more: asymptotic inverse CDFs.** With w = Phi^-1(u):

* Poisson, Giles' approximation (M. B. Giles, "Algorithm 955: approximation of the inverse
  Poisson cumulative distribution function", ACM TOMS 42(1), 2016; the one CUDA's ``poissinvf``
  uses). The quantile is floor(x) for the continuous x that solves Q(x, rate) = u (Q the
  regularised upper incomplete gamma, Q(k + 1, rate) = F(k)). With s = w / sqrt(rate), Temme's
  uniform expansion gives x = rate r + c0(r) + c1(r) / rate + ..., where r solves
  sign(r - 1) sqrt(2 (1 - r + r log r)) = s and c0(r) = log(sqrt(2 r (1 - r + r log r)) / |r - 1|)
  / log r. In the central region -0.683 < s < 1.778, Giles' polynomials in s give r - 1, c0 and
  c1 (his coefficients); outside it, r is found by the series r = 1 + s + s^2/6 - s^3/72 + s^4/270
  and 3 Newton steps, and Giles' term -0.0218 / (x + 0.065 rate) stands for c1 / rate. It holds
  for rates above 4; below, only counts >= K use it (evaluated at a rate of 4 and raised to K),
  an event of probability below 1e-11 there.
* Binomial, p > 1/2 reflected (X = n - X' with X' ~ Bin(n, 1 - p)) so that the exact sum serves
  a small mean n min(p, 1 - p). Above K: the Poisson quantile of the same mean plus the
  difference of the two laws' Cornish-Fisher expansions, both to fifth order. A lattice law's
  CDF at k is the Edgeworth expansion at k + 1/2 of a smooth law whose cumulants are the lattice
  law's corrected by Sheppard's (variance - 1/12, fourth cumulant + 1/120, sixth - 1/252); its
  inverse is x = mean - 1/2 + sd (w + a1/sd + ... + a5/sd^5) and X = ceil(x), with a_j the
  Cornish-Fisher polynomials in w and the standardised cumulants (derived for pfx; to second
  order they are Giles & Beentjes' normal asymptotic expansion, "Approximation of an inverse of
  the incomplete beta function", ICMS 2024). The binomial's cumulants are n p q, n p q (q - p),
  n p q (1 - 6 p q), ...; the Poisson's are all the rate. The difference is small where p is small
  (the binomial is nearly Poisson) and the expansions' loss of accuracy in the tails largely
  cancels in it, so the sum keeps Giles' uniform accuracy.

**Accuracy** (largest |F_approx(k) - F(k)| over k, where F_approx(k) is the u at which the
sampler's count passes k, found by bisection over the floats; the table over rates 1e-3 to 1e6
and n up to 1e7 is in docs/plugins.md, "Count draws: exact or inverse-CDF", from
examples/benchmarks/count_sampler_accuracy.py):

* float64: exact to rounding (below 1e-12) for counts below K; the asymptotic regimes are within
  about 1e-7, largest at means of 10 to 60 (Giles' approximation: up to 1e-7 near a rate of 30;
  the binomial near p = 1/2 and a mean of 20: up to 2e-7), and far smaller at large means
  (below 1e-10 from a mean of 1e4, to rates and n of 1e9). Float64 inputs are thus drawn to about
  float32's resolution, not float64's: the exact samplers stay available for that.
* float32: within about 1e-6 everywhere (measured up to 8e-7): the rounding of u itself
  (6e-8 near 1), of the K-term recurrences (a product rounded once per term), and of n log(1 - p)
  (the sum starts from P(0) = e^(-n p) e^(-n (-log(1 - p) - p)), n p taken exactly as a whole part
  and a fraction, so that only the small second exponent rounds). 1 - u rounds in the reflection
  (an error below 3e-8). Counts are exact integers up to 2^24 (1.7e7); above, float32 cannot hold
  every count: a rate or mean above 2^24 gives counts rounded to float32's spacing (8 at 1e8),
  a CDF error of about 0.4 spacing / sqrt(mean) (3e-4 at 1e8), and is not claimed.

u = 1 is read as the largest float below 1; u = 0 gives the smallest count of the support (0, or
n when p = 1). Parameters are not checked here (the streams check them: a negative rate or a p
outside [0, 1] gives meaningless counts). The cost is fixed per draw: K terms, both asymptotic
regions and (binomial) two Cornish-Fisher expansions, for every lane; docs/plugins.md has the
nanoseconds per draw beside NumPy's and JAX's exact samplers.
"""

from __future__ import annotations

from typing import Any, Callable

from pfx.numerics.array_namespace import namespace, special_functions

SUMMED_TERMS = 24
"""K: the exact bottom-up sum gives every count below K; the asymptotic formulas give the rest."""

POISSON_ASYMPTOTIC_FLOOR = 4.0
"""Giles' approximation holds for means above 4; below, only counts >= K (probability below 1e-11
at a mean of 4) come from it, evaluated at a mean of 4 and raised to K."""

# Giles (2016), Algorithm 955: the central region of s = w / sqrt(rate) and its polynomials
# (highest power first) for r - 1, the O(1) term and the O(1/rate) term of the quantile.
_CENTRAL_LOW, _CENTRAL_HIGH = -0.6833501, 1.777993
_RATIO_MINUS_ONE = (2.82298751e-07, -2.58136133e-06, 1.02118025e-05, -2.37996199e-05, 4.05347462e-05,
                    -6.63730967e-05, 1.24762566e-04, -2.56970731e-04, 5.58953132e-04, -1.33129194e-03,
                    3.70367937e-03, -1.38888706e-02, 1.66666667e-01)
_CONSTANT_TERM = (1.86386867e-05, -2.07319499e-04, 9.68945100e-04, -2.47340054e-03, 3.79952985e-03,
                  -3.86717047e-03, 3.46960934e-03, -4.14125511e-03, 5.86752093e-03, -8.38583787e-03,
                  1.32793933e-02, -2.77755360e-02, 3.33333333e-01)
_INVERSE_RATE_TERM = (-1.45852240e-04, 1.46121529e-03, -6.10328845e-03, 1.38117964e-02, -1.86988746e-02,
                      1.68155118e-02, -1.33947970e-02, 1.35698573e-02, -1.55377333e-02, 1.74065334e-02,
                      -1.98011178e-02)
_NEWTON_STEPS = 3
_NEWTON_LOWEST_S = -1.4     # below, r -> 0: such counts are below K wherever they can occur


def poisson_quantile(uniform: Any, rate: Any) -> Any:
    """The Poisson(``rate``) count for ``uniform``: the smallest k with F(k; rate) > u, exact for
    counts below K and within Giles' approximation above (module docstring). ``uniform`` is a
    float array in [0, 1) (1 is read as the largest float below it) whose dtype the computation
    and the result take; ``rate`` >= 0 broadcasts against it. No checks: the streams check."""
    xp, uniform, (rate,) = _as_arrays(uniform, rate)
    summed = _summed_count(xp, uniform, xp.exp(-rate), lambda term: rate * (1.0 / term))
    large = xp.maximum(rate, POISSON_ASYMPTOTIC_FLOOR)
    whole = xp.floor(large)
    offset = _poisson_offset(xp, _normal_quantile(xp, uniform), large)
    asymptotic = whole + xp.floor((large - whole) + offset)
    count = xp.where(summed < SUMMED_TERMS, summed, xp.maximum(asymptotic, SUMMED_TERMS))
    return xp.where(uniform <= 0.0, 0.0, count)


def binomial_quantile(uniform: Any, count: Any, probability: Any) -> Any:
    """The Binomial(``count``, ``probability``) count for ``uniform``: the smallest k with
    F(k; n, p) > u, exact for counts below K (after the reflection p > 1/2 -> n - X with 1 - p)
    and within the Cornish-Fisher-corrected Poisson approximation above (module docstring).
    ``uniform`` as for :func:`poisson_quantile`; ``count`` a whole number >= 0 and
    ``probability`` in [0, 1] broadcast against it. No checks: the streams check."""
    xp, uniform, (trials, probability) = _as_arrays(uniform, count, probability)
    reflect = probability > 0.5
    small_p = xp.where(reflect, 1.0 - probability, probability)
    # X = n - #{j: F'(j) < 1 - u} for X' = n - X ~ Bin(n, 1 - p); "< v" is "<= the float below v"
    level = xp.where(reflect, xp.nextafter(1.0 - uniform, 0.0), uniform)
    odds = small_p / (1.0 - small_p)
    whole, fraction = _exact_mean(xp, trials, small_p)
    first = xp.exp(-whole) * xp.exp(-(fraction + trials * _log_excess(xp, small_p)))
    summed = _summed_count(xp, level, first,
                           lambda term: xp.maximum(trials - (term - 1), 0.0) * (odds * (1.0 / term)))
    # the asymptotic branch sees parameters it is accurate for; a small mean's lanes read it only
    # for counts >= K, raised to K (their probability is below 1e-11: module docstring)
    usable = trials * small_p >= POISSON_ASYMPTOTIC_FLOOR
    n = xp.where(usable, trials, 2.0 * POISSON_ASYMPTOTIC_FLOOR)
    p = xp.where(usable, small_p, 0.5)
    normal = _normal_quantile(xp, level)
    continuous = _poisson_offset(xp, normal, n * p) - 1.0 + _cornish_fisher_gap(xp, normal, n, p)
    asymptotic = (xp.where(usable, whole, POISSON_ASYMPTOTIC_FLOOR)
                  + xp.ceil(xp.where(usable, fraction, 0.0) + continuous))
    result = xp.where(summed < SUMMED_TERMS, summed, xp.minimum(xp.maximum(asymptotic, SUMMED_TERMS), trials))
    result = xp.where(reflect, trials - result, result)
    return xp.where(uniform <= 0.0, xp.where(probability >= 1.0, trials, 0.0), result)


# -- the pieces --------------------------------------------------------------------------------------



def inverse_cdf_law(law: str) -> tuple[int, Callable]:
    """How the random streams draw ``law`` (binomial, poisson or gamma) under ``count_draws:
    inverse_cdf``: (the uniforms a draw takes, ``variate(uniforms, *parameters)``), the uniforms
    on the leading axis, the parameters as the streams lay them out (a gamma's scale last)."""
    from pfx.numerics.gamma_quantiles import GAMMA_UNIFORMS, gamma_variate

    return {"binomial": (1, lambda uniforms, count, probability: binomial_quantile(uniforms[0], count, probability)),
            "poisson": (1, lambda uniforms, rate: poisson_quantile(uniforms[0], rate)),
            "gamma": (GAMMA_UNIFORMS, lambda uniforms, shape, scale: scale * gamma_variate(uniforms, shape))}[law]


def _as_arrays(uniform: Any, *parameters: Any) -> tuple:
    """The namespace, the uniforms capped below 1, and the parameters in the uniforms' dtype."""
    xp = namespace(uniform, *parameters)
    uniform = xp.asarray(uniform)
    dtype = uniform.dtype
    below_one = 1.0 - float(xp.finfo(dtype).eps) / 2.0
    uniform = xp.minimum(uniform, below_one)
    return xp, uniform, tuple(xp.asarray(parameter, dtype=dtype) for parameter in parameters)


def _summed_count(xp, level: Any, first: Any, ratio) -> Any:
    """How many of F(0), ..., F(K-1) are <= ``level``: F summed bottom up from the first term
    ``first`` = P(0), each next term P(j) = P(j-1) ratio(j). A fixed K terms for every lane: K
    means "K or more"."""
    term = first
    cumulative = first
    count = xp.where(cumulative <= level, 1.0, 0.0).astype(level.dtype)
    for index in range(1, SUMMED_TERMS):
        term = term * ratio(float(index))
        cumulative = cumulative + term
        count = count + (cumulative <= level)
    return count


def _normal_quantile(xp, uniform: Any) -> Any:
    """Phi^-1(u), u kept between the smallest normal float and the largest float below 1 (0 and 1
    are read there: finite)."""
    information = xp.finfo(uniform.dtype)
    below_one = 1.0 - float(information.eps) / 2.0
    return special_functions(xp).ndtri(xp.clip(uniform, float(information.tiny), below_one))


def _polynomial(coefficients: tuple, x: Any) -> Any:
    """Horner's rule, coefficients from the highest power down (Python floats: x's dtype stays)."""
    value = coefficients[0]
    for coefficient in coefficients[1:]:
        value = value * x + coefficient
    return value


def _poisson_offset(xp, normal: Any, rate: Any) -> Any:
    """x - rate for Giles' continuous quantile x (count = floor(x)): the central region's
    polynomials in s = w / sqrt(rate), or elsewhere the Newton solution r of h(r) = s and Temme's
    terms; both computed, one kept, each on inputs that are safe for it."""
    s = normal / xp.sqrt(rate)
    central = (s > _CENTRAL_LOW) & (s < _CENTRAL_HIGH)
    s_central = xp.where(central, s, 0.0)
    ratio_minus_one = s_central + s_central * s_central * _polynomial(_RATIO_MINUS_ONE, s_central)
    central_offset = (rate * ratio_minus_one + _polynomial(_CONSTANT_TERM, ratio_minus_one)
                      + _polynomial(_INVERSE_RATE_TERM, ratio_minus_one) / rate)
    ratio = _temme_ratio(xp, xp.where(central, 2.0, xp.maximum(s, _NEWTON_LOWEST_S)))
    log_ratio = xp.log(ratio)
    constant = xp.log(xp.sqrt(2.0 * ratio * ((1.0 - ratio) + ratio * log_ratio)) / xp.abs(ratio - 1.0)) / log_ratio
    below_last = rate * (ratio - 1.0) + constant
    tail_offset = below_last - 0.0218 / (rate + below_last + 0.065 * rate)
    return xp.where(central, central_offset, tail_offset)


def _temme_ratio(xp, s: Any) -> Any:
    """r with sign(r - 1) sqrt(2 (1 - r + r log r)) = s, for s >= 1.77 or -1.4 <= s <= -0.68:
    the series r = 1 + s + s^2/6 - s^3/72 + s^4/270 (its Taylor series, derived for pfx), then a
    fixed 3 Newton steps: relative error below 1e-13 above, 2e-10 for s >= -1.3 (measured); 1e-4
    near s = -1.4 (r near 0.02), which counts of K or more reach only for u below 1e-90."""
    ratio = xp.maximum(1.0 + s * (1.0 + s * (1.0 / 6.0 + s * (-1.0 / 72.0 + s / 270.0))), 0.05)
    for _ in range(_NEWTON_STEPS):
        log_ratio = xp.log(ratio)
        signed_root = xp.sign(ratio - 1.0) * xp.sqrt(2.0 * xp.maximum((1.0 - ratio) + ratio * log_ratio, 0.0))
        ratio = xp.maximum(ratio - (signed_root - s) * signed_root / log_ratio, 0.1 * ratio)
    return ratio


def _exact_mean(xp, count: Any, probability: Any) -> tuple:
    """n p as a whole part and a fraction in [0, 4), exact to the fraction's rounding: n and p
    are cut into halves of at most half the mantissa's bits (n below 2^24 in float32, 2^52 in
    float64), so each of the four products is exact in the dtype (float32's n p near 1e6 would
    otherwise be off by up to 0.03)."""
    half = (int(xp.finfo(count.dtype).nmant) + 1) // 2
    scale = float(2 ** half)
    count_high = xp.floor(count / scale) * scale
    count_low = count - count_high
    mantissa, exponent = xp.frexp(probability)
    probability_high = xp.ldexp(xp.floor(mantissa * scale), exponent - half)
    probability_low = probability - probability_high
    whole, fraction = 0.0, 0.0
    for product in (count_high * probability_high, count_high * probability_low,
                    count_low * probability_high, count_low * probability_low):
        floor = xp.floor(product)
        whole, fraction = whole + floor, fraction + (product - floor)
    return whole, fraction


def _log_excess(xp, probability: Any) -> Any:
    """-log(1 - p) - p = p^2/2 + p^3/3 + ..., for 0 <= p <= 1/2, to a few ulps of itself: by its
    series below 0.05 (the direct difference loses the digits n p would amplify), directly above."""
    series_p = xp.minimum(probability, 0.05)
    series = series_p * series_p * (0.5 + series_p * (1.0 / 3.0 + series_p * (0.25 + series_p * (0.2 + series_p / 6.0))))
    direct = -xp.log1p(-probability) - probability
    return xp.where(probability < 0.05, series, direct)


def _cornish_fisher_gap(xp, normal: Any, n: Any, p: Any) -> Any:
    """The binomial's continuous quantile minus the Poisson's of the same mean, each from the
    Cornish-Fisher expansion to fifth order with Sheppard-corrected cumulants (module docstring)."""
    q = 1.0 - p
    pq = p * q
    mean = n * p
    spread = mean * q
    skew = q - p
    binomial_variance = spread - 1.0 / 12.0
    poisson_variance = mean - 1.0 / 12.0
    binomial_sd, poisson_sd = xp.sqrt(binomial_variance), xp.sqrt(poisson_variance)
    binomial = _cornish_fisher_terms(
        normal, 1.0 / binomial_sd,
        spread * skew / binomial_variance,
        (spread * (1.0 - 6.0 * pq) + 1.0 / 120.0) / binomial_variance,
        spread * skew * (1.0 - 12.0 * pq) / binomial_variance,
        (spread * (1.0 - 30.0 * pq * (1.0 - 4.0 * pq)) - 1.0 / 252.0) / binomial_variance,
        spread * skew * (1.0 - 60.0 * pq * (1.0 - 6.0 * pq)) / binomial_variance)
    odd = mean / poisson_variance
    poisson = _cornish_fisher_terms(normal, 1.0 / poisson_sd, odd, (mean + 1.0 / 120.0) / poisson_variance,
                                    odd, (mean - 1.0 / 252.0) / poisson_variance, odd)
    sd_gap = -mean * p / (binomial_sd + poisson_sd)      # sd_b - sd_p without the cancellation
    return normal * sd_gap + binomial - poisson


def _cornish_fisher_terms(w: Any, epsilon: Any, c3: Any, c4: Any, c5: Any, c6: Any, c7: Any) -> Any:
    """sd (y - w) of the Cornish-Fisher expansion y = w + a1 e + ... + a5 e^5, e = 1/sd, with
    standardised cumulants k_r = c_r e^(r-2) (the a_j derived for pfx: module docstring)."""
    w2 = w * w
    c3c3 = c3 * c3
    a1 = c3 * (w2 - 1.0) / 6.0
    a2 = w * ((10.0 * c3c3 - 9.0 * c4) + w2 * (3.0 * c4 - 4.0 * c3c3)) / 72.0
    c333, c34 = c3c3 * c3, c3 * c4
    a3 = ((170.0 * c333 - 270.0 * c34 + 81.0 * c5)
          + w2 * ((-530.0 * c333 + 675.0 * c34 - 162.0 * c5)
                  + w2 * 3.0 * (40.0 * c333 - 45.0 * c34 + 9.0 * c5))) / 3240.0
    c3333, c334, c35, c44 = c333 * c3, c3c3 * c4, c3 * c5, c4 * c4
    a4 = w * ((-30220.0 * c3333 + 57780.0 * c334 - 18144.0 * c35 - 11745.0 * c44 + 3240.0 * c6)
              + w2 * (4.0 * (8440.0 * c3333 - 13905.0 * c334 + 3672.0 * c35 + 2430.0 * c44 - 540.0 * c6)
                      + w2 * 9.0 * (-560.0 * c3333 + 840.0 * c334 - 192.0 * c35 - 135.0 * c44 + 24.0 * c6))) / 155520.0
    c5th, c3334, c335, c344, c36, c45 = c3333 * c3, c333 * c4, c3c3 * c5, c3 * c44, c3 * c6, c4 * c5
    a5 = ((-148456.0 * c5th + 383040.0 * c3334 - 136080.0 * c335 - 181440.0 * c344 + 34020.0 * c36
           + 54432.0 * c45 - 4860.0 * c7)
          + w2 * ((843472.0 * c5th - 1906380.0 * c3334 + 594216.0 * c335 + 768285.0 * c344 - 124740.0 * c36
                   - 197316.0 * c45 + 14580.0 * c7)
                  + w2 * (9.0 * (-55608.0 * c5th + 112420.0 * c3334 - 30408.0 * c335 - 40635.0 * c344
                                 + 5460.0 * c36 + 9072.0 * c45 - 540.0 * c7)
                          + w2 * 12.0 * (4480.0 * c5th - 8400.0 * c3334 + 2016.0 * c335 + 2835.0 * c344
                                         - 315.0 * c36 - 567.0 * c45 + 27.0 * c7)))) / 1632960.0
    return a1 + epsilon * (a2 + epsilon * (a3 + epsilon * (a4 + epsilon * a5)))
