r"""Gamma draws by a branch-free inverse CDF: Temme's asymptotic inversion, boosted in shape.

pomp's gamma white noise (``rgammawn``, :func:`pfx.laws.count_transitions.gamma_white_noise`) and
``random.gamma`` draw Gamma(a) variates (scale 1 here; the caller multiplies by the scale). NumPy
and JAX draw them exactly, by rejection (Marsaglia & Tsang): a loop whose length depends on the
values. Here a fixed number of uniforms gives one draw by fixed work, written once against the
array namespace (NumPy or jax.numpy, in the uniforms' dtype), so it traces under ``jax.jit``.

**The inverse CDF at a large shape b** (:func:`gamma_quantile`), N. M. Temme, "Asymptotic
inversion of incomplete gamma functions", Math. Comp. 58 (1992). The regularised incomplete gamma
has the uniform expansion (DLMF 8.12)

.. math::

    Q(b, x) = \tfrac12 \operatorname{erfc}\big(\eta \sqrt{b/2}\big)
        + \frac{e^{-b\eta^2/2}}{\sqrt{2\pi b}} \sum_k C_k(\eta)\, b^{-k},
    \qquad \lambda = x / b, \quad \lambda - 1 - \log\lambda = \eta^2 / 2,

sign(eta) = sign(lambda - 1), with C_0 = 1/(lambda - 1) - 1/eta and
C_k = C'_{k-1}/eta + (-1)^k g_k/(lambda - 1) (g_k Stirling's coefficients 1/12, 1/288,
-139/51840). Its inversion: with w = Phi^-1(u) and eta0 = w / sqrt(b), the x with P(b, x) = u has
eta = eta0 + eps_1(eta0)/b + eps_2(eta0)/b^2 + ..., where eps_1 = log(eta0 / (lambda0 - 1)) / eta0
and each next eps_k follows from the C_k. pfx takes four, as Taylor polynomials in eta0 (16, 16,
12 and 12 terms; their coefficients computed for pfx from the closed forms, the first ones
Temme's: eps_1 = -1/3 + eta0/36 + eta0^2/1620 - ...). The series converge for |eta0| < 2 sqrt(pi);
beyond |eta0| = 2 (|w| > 2 sqrt(b): probability below 1e-5 at b = 5, far less above) the eps_k are
held at their value there, which keeps x monotone in u. Then lambda solves
lambda - 1 - log(lambda) = eta^2/2 (its series for |eta| < 1/2, else 4 Newton steps on
log(lambda)), and x = b + b (lambda - 1): near b, lambda - 1 is the small number computed to the
dtype's relative precision, so x rounds once.

**Any shape, by boosting** (:func:`gamma_variate`): if Y ~ Gamma(b + 1) and U is uniform and
independent of it, Y U^(1/b) ~ Gamma(b). Applied m = 5 times,

.. math::

    X = Q_{a+5}^{-1}(u_0) \prod_{i=0}^{4} u_{i+1}^{1/(a+i)} \sim \mathrm{Gamma}(a),

exactly, for every shape a > 0, from GAMMA_UNIFORMS = 6 uniforms; the asymptotic inversion then
only ever meets shapes of 5 or more, where it is accurate. (pomp's gamma white noise at a day's
step has shapes below 1.)

**Accuracy** (the largest |F(x(u)) - u| over u, F the exact CDF, from scipy): the inverse CDF at
shape b is within 8e-7 at b = 4, 2.9e-7 at b = 5, 3.3e-8 at b = 8, 5e-9 at b = 12, 1e-10 at
b = 30 in float64 (the truncation after eps_4, about b^-4.5). X's CDF is a mixture over the boost
factor of the inverse CDF's at a + 5, so its error is at most that at a + 5: within 2.9e-7 for
every shape in float64. In float32 (measured on NumPy and JAX) within 3.6e-7 at b = 5 and 2e-7 from
b = 6 to 100; above, a draw near a large shape is a float32 whose spacing of about b 2^-24 alone
is a CDF difference of 0.2 sqrt(b) 2^-24, and the error follows it: 2e-6 at 1e4, 1.25e-5 at 1e6.
A float32 draw below the smallest normal float32 (1.2e-38) may be flushed to 0 (XLA flushes
subnormals): a probability of 2.5e-14 at shape 0.36, 1.7e-4 at 0.1. Shape 0 gives 0; u = 0
gives 0; a uniform of 0 among the boosts is read as the smallest float. Shapes are not checked
here (the streams check them).
"""

from __future__ import annotations

from typing import Any

from pfx.numerics.array_namespace import namespace, special_functions

GAMMA_BOOSTS = 5
"""m: gamma_variate draws Gamma(a + m) by the inverse CDF and multiplies it by m powers of uniforms."""

GAMMA_UNIFORMS = 1 + GAMMA_BOOSTS
"""Uniforms per gamma draw: the leading axis of gamma_variate's ``uniforms``."""

# Temme's (1992) coefficients eps_k(eta) of eta = eta0 + eps_1/a + eps_2/a^2 + ..., as Taylor
# polynomials in eta0 (lowest power first), computed for pfx from their closed forms (a Cauchy
# integral at 80 digits); their first terms are Temme's: -1/3 + eta/36 + eta^2/1620 - ...
_EPSILONS = (
    (-0.3333333333333333, 0.027777777777777776, 0.0006172839506172839, -0.0010802469135802468,
     0.0002755731922398589, -2.8741263309164543e-05, -6.185087203605722e-06, 3.776373375138807e-06,
     -9.120511014991658e-07, 7.735470535130866e-08, 3.2400053233896885e-08, -1.685720940069024e-08,
     3.931682661516204e-09, -2.8134289510434744e-10, -1.6988818928842894e-10, 8.292306612656927e-11),
    (-0.01728395061728395, -0.002700617283950617, 0.002611209092690574, -0.0007520766651425087,
     6.229995427526292e-05, 4.055292003251537e-05, -2.1264630522937184e-05, 4.963238978973187e-06,
     -1.762740701047537e-07, -3.458654060048345e-07, 1.524261435838951e-07, -3.203809272306461e-08,
     1.6623076398775507e-10, 2.5777683426580993e-09, -1.0435073378185946e-09, 2.053658457394389e-10),
    (0.004399372917891437, -0.003007782731290962, 0.0007956376423454613, 6.554653913335898e-05,
     -0.00014083659963035565, 5.835799802507499e-05, -1.0458719597698151e-05, -1.767264368629448e-06,
     1.9183236555833138e-06, -6.668385436179321e-07, 9.792656534261617e-08, 2.378280260904135e-08),
    (0.0017364513249286911, -6.36443186258144e-05, -0.00045808052481112146, 0.00029719735544227286,
     -8.702143139501812e-05, -6.062689845768047e-07, 1.3182157101661426e-05, -6.632500497635966e-06,
     1.5800065030126537e-06, 5.595475256604004e-08, -2.1646379636438505e-07, 9.592365281492863e-08),
)
_EPSILON_REACH = 2.0     # |eta0| beyond which the eps_k are held at their value there
# lambda(eta) - 1 = eta + eta^2/3 + eta^3/36 - ... (lowest power first; computed for pfx, the
# first ones Temme's), where lambda - 1 - log(lambda) = eta^2/2: to 1e-17 for |eta| < 1/2
_EXCESS_SERIES = (1.0, 1.0 / 3.0, 1.0 / 36.0, -1.0 / 270.0, 1.0 / 4320.0, 1.0 / 17010.0, -139.0 / 5443200.0,
                  1.0 / 204120.0, -2.428276122977769e-07, -1.85406221071516e-07, 7.542464855411896e-08,
                  -1.47216272806884e-08, 5.159887341078076e-10, 7.32986413160022e-10, -2.921357345635569e-10,
                  5.717312238897994e-11)
_SERIES_REACH = 0.5
_NEWTON_STEPS = 4
_ETA_BOUND = 1e3         # |eta| is at most 38 / sqrt(a) for a shape a; beyond, only shapes far
                         # below the asymptotic range (their quantile is not claimed) reach


def gamma_quantile(uniform: Any, shape: Any) -> Any:
    """The x with P(shape, x) = u by Temme's asymptotic inversion (module docstring): accurate for
    shapes of 5 or more (the module docstring's table; below it degrades, 4e-4 at 1, and is
    meaningless near 0: :func:`gamma_variate` draws those). ``uniform`` a float array in [0, 1)
    whose dtype the result takes (1 is read as the largest float below it); ``shape`` broadcasts
    against it. 0 where u = 0 or shape <= 0."""
    xp = namespace(uniform, shape)
    uniform = xp.asarray(uniform)
    information = xp.finfo(uniform.dtype)
    shape = xp.asarray(shape, dtype=uniform.dtype)
    usable = shape > 0.0
    a = xp.where(usable, shape, 1.0)
    level = xp.clip(uniform, float(information.tiny), 1.0 - float(information.eps) / 2.0)
    first = special_functions(xp).ndtri(level) / xp.sqrt(a)
    held = xp.clip(first, -_EPSILON_REACH, _EPSILON_REACH)
    inverse = 1.0 / xp.maximum(a, 0.01)      # no overflow at shapes far below the claimed range
    correction = 0.0
    for epsilon in reversed(_EPSILONS):
        correction = (correction + _series(epsilon, held)) * inverse
    excess, log_lambda = _lambda(xp, first + correction)
    # a + a (lambda - 1) rounds once, near a, where a lambda would round lambda first; far below
    # a, a lambda keeps the small values that a + a (lambda - 1) would cancel away
    quantile = xp.where(excess > -0.5, a + a * excess, a * xp.exp(log_lambda))
    return xp.where(usable & (uniform > 0.0), quantile, 0.0)


def gamma_variate(uniforms: Any, shape: Any) -> Any:
    """A Gamma(``shape``) draw (scale 1) from ``uniforms``, an array whose leading axis holds
    GAMMA_UNIFORMS uniforms in [0, 1) per draw: the inverse CDF at shape + 5 of the first, times the
    boosts of the other five (module docstring). The draws take the uniforms' dtype and the
    shape of ``uniforms[0]`` broadcast against ``shape`` (>= 0; 0 gives 0)."""
    xp = namespace(uniforms, shape)
    uniforms = xp.asarray(uniforms)
    shape = xp.asarray(shape, dtype=uniforms.dtype)
    usable = shape > 0.0
    a = xp.where(usable, shape, 1.0)
    tiny = float(xp.finfo(uniforms.dtype).tiny)      # u = 0 read as the smallest float: log finite
    log_product = 0.0
    for boost in range(GAMMA_BOOSTS):
        log_product = log_product + xp.log(xp.maximum(uniforms[1 + boost], tiny)) / (a + float(boost))
    draw = gamma_quantile(uniforms[0], a + float(GAMMA_BOOSTS)) * xp.exp(log_product)
    return xp.where(usable, draw, 0.0)


def _series(coefficients: tuple, x: Any) -> Any:
    """Horner's rule, coefficients from the lowest power up."""
    value = coefficients[-1]
    for coefficient in reversed(coefficients[:-1]):
        value = value * x + coefficient
    return value


def _lambda(xp, eta: Any) -> tuple:
    """lambda - 1 and log(lambda), where lambda - 1 - log(lambda) = eta^2/2 and sign(lambda - 1) =
    sign(eta): for |eta| < 1/2, lambda - 1 by its series (log(lambda) is then not needed: 0);
    else a fixed 4 Newton steps on z = log(lambda), z <- z - (e^z - 1 - z - eta^2/2) / (e^z - 1),
    from the series (|eta| <= 1.5), z = -1 - eta^2/2 (below: lambda is tiny) or
    log(1 + eta^2/2 + log(1 + eta^2/2)) (above); relative error of lambda below 4e-15 after the
    4 steps (measured for |eta| from 1e-3 to 40)."""
    near = xp.abs(eta) < _SERIES_REACH
    close = xp.where(near, eta, 0.0)
    far = xp.clip(xp.where(near, 1.0, eta), -_ETA_BOUND, _ETA_BOUND)
    half_square = 0.5 * far * far
    upper = 1.0 + half_square
    middle = 1.0 + _series(_EXCESS_SERIES[:4], xp.clip(far, -1.5, 1.5)) * xp.clip(far, -1.5, 1.5)
    log_lambda = xp.where(far < -1.5, -1.0 - half_square,
                          xp.where(far > 1.5, xp.log(upper + xp.log(upper)), xp.log(xp.maximum(middle, 1e-3))))
    for _ in range(_NEWTON_STEPS):
        excess = xp.expm1(log_lambda)
        log_lambda = log_lambda - (excess - log_lambda - half_square) / excess
    excess = xp.where(near, close * _series(_EXCESS_SERIES, close), xp.expm1(log_lambda))
    return excess, xp.where(near, 0.0, log_lambda)
