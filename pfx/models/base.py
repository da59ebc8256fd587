r"""The state-space model interface every pfx model implements.

A model is the triple of laws a particle filter needs, written as vectorised functions over
arrays whose leading dimensions are free (``(trials, d)`` for the truth, ``(trials, N, d)``
for particles):

* the **initial law** :math:`p(x_0)` (``initial``; a filter's prior defaults to
  :meth:`Model.default_prior`),
* the **transition** :math:`x_k = f(x_{k-1}, u_k, w_k)` with control input :math:`u_k`
  (:meth:`Model.control`) and process noise :math:`w_k` (:meth:`Model.propagate`),
* the **measurement** :math:`z_k = h(x_k) + v_k` (:meth:`Model.measurement_mean`,
  :meth:`Model.measure`) and its log-likelihood :math:`\log p(z_k \mid x_k)`
  (:meth:`Model.log_likelihood`).

Optionally, for the extended Kalman filter (:mod:`pfx.filters.kalman`), a model gives the
Jacobians of its transition and measurement (:meth:`Model.transition_jacobian`,
:meth:`Model.process_noise_jacobian`, :meth:`Model.measurement_jacobian`); where it returns
None (the default) the EKF uses central finite differences. Each model's docstring states which.

The same class simulates the truth and runs inside the filter: a filter that assumes a
different model is simply another instance (other noise, other motion) of the same kind.

A model is a pydantic model: its fields are its parameters, declared once with types and
descriptions; the config schema, ``pfx schema`` and the config docs all come from them.
Fields left ``None`` are filled from the model's presets by :meth:`Model.presets`.
Cross-field checks raise ``ValueError("@key.path: reason")`` so errors point at the key.

**The public contract** (``pfx.Model``, for plugins: docs/plugins.md). Its method names and
array shapes are stable. A model must define ``state_names``, ``measurement_dimension``,
``propagate`` and ``measurement_mean`` (:func:`~pfx.models.contract_checks.missing_methods`);
everything else has a default. With ``R`` trials, ``N`` particles, ``d`` states, ``m`` measurement components and
``q`` process noise components, and ``...`` standing for the leading dimensions (``(R,)`` for
the truth, ``(R, N)`` for particles):

=====================================================  =========================================
``propagate(state (..., d), control, noise (..., q))``  the new state, ``(..., d)``, floating point
``measurement_mean(state (..., d))``                    h(x), ``(..., m)``, floating point
``simulate_measurement(state (R, d), random)``          one measurement per trial, ``(R, m)``
``log_likelihood(measurement, state (R, N, d))``        ``(R, N)``; measurement ``(R, 1, m)``
=====================================================  =========================================

**Observation intervals** (``substeps`` between two measurements, accumulators reset at each
step): :mod:`pfx.models.time_axis` states the composition that :meth:`Model.sample_transition`
computes.

A measurement that is not "h(x) + noise" (multiplicative noise, say) overrides both
``simulate_measurement`` (how the truth's measurements are drawn; every draw from ``random``)
and ``log_likelihood`` (log p(z | x), in the log domain).

**Two backends.** The composed operations here (:meth:`Model.transition`,
:meth:`Model.mean_transition`, :meth:`Model.reset_accumulators`, :meth:`Model.propagate_at`, the
default :meth:`Model.log_likelihood`) take NumPy or JAX arrays and return the same kind: they ask
the state for its array namespace (:mod:`pfx.numerics.arrays`) and update functionally. On NumPy
they compute exactly what they always did; a model written the same way runs on both backends.

**This module holds the contract**: the :class:`Model` class (its fields, what a subclass
provides, the composed operations, validation), the ``MODELS`` registry and :func:`bind_law`.
Two jobs live beside it: the time axis (the steps' and substeps' times and the covariates over
time), a mixin of :class:`Model` in :mod:`pfx.models.time_axis`, and the checks of a model
against the contract (:meth:`Model.check_contract`: shapes and dtypes on a tiny batch, before a
plugin's model runs; names and declarations; reproducibility) in :mod:`pfx.models.contract_checks`.
"""

from __future__ import annotations

import copy
import math
from typing import Any, Callable, ClassVar, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, StrictFloat, StrictInt, model_validator

from pfx.laws.initial import InitialLaw
from pfx.laws.noise import Noise
from pfx.models.contract_checks import NOISE_VARIANCES, check_contract
from pfx.models.time_axis import TimeAxis, covariate_table, plain_data
from pfx.numerics.angles import wrap_components
from pfx.numerics.arrays import namespace, with_values
from pfx.numerics.seeding import TrialStreams
from pfx.registry import Registry


class Model(TimeAxis, BaseModel):
    """Base class of all models (see the module docstring); its times and covariates come from
    :class:`~pfx.models.time_axis.TimeAxis`."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    kind: str
    steps: Optional[StrictInt] = Field(None, ge=1, le=1_000_000, description="number of filter steps T")
    dt: Optional[StrictFloat] = Field(None, gt=0, description="time between steps (seconds unless stated)")
    process_noise: Optional[Noise] = Field(None, description="process noise w_k (family, variance)")
    measurement_noise: Optional[Noise] = Field(None, description="measurement noise v_k (family, variance)")
    initial: Optional[InitialLaw] = Field(None, description="initial law of the true state x_0")
    covariates: Optional[dict[str, list[StrictFloat]]] = Field(
        None, description="covariates over time, for a model that reads them (covariate_names): `time` (increasing) "
                          "and one list of values per covariate; filled from the file `data.covariates` names")
    substeps: StrictInt = Field(1, ge=1, le=100_000,
                                description="propagate calls between two measurements, each advancing dt / substeps "
                                            "with its own process noise draw; above 1 only for a model that declares "
                                            "integrates_substeps (docs/plugins.md)")

    # -- what a subclass provides --------------------------------------------------------------

    def presets(self) -> dict[str, Any]:
        """Default values for the fields left None (may depend on other fields)."""
        return {}

    def preset_fields(self) -> set[str]:
        """The fields holding what :meth:`presets` derives (left out, or given equal to it): a
        model rebuilt from the other fields derives them again, so that they follow a changed
        parameter (a filter's model with its own overrides, a PMMH chain's stationary initial law)."""
        return {name for name, value in self.derived_presets().items()
                if plain_data(getattr(self, name)) == plain_data(value)}

    def check(self) -> None:
        """Cross-field checks; raise ValueError('@key: reason')."""

    def setup(self) -> None:
        """Precompute arrays (private attributes) once the parameters are resolved."""

    @property
    def state_names(self) -> tuple[str, ...]:
        raise NotImplementedError

    @property
    def state_units(self) -> tuple[str, ...]:
        return ("",) * self.state_dimension

    @property
    def state_dimension(self) -> int:
        return len(self.state_names)

    @property
    def measurement_dimension(self) -> int:
        raise NotImplementedError

    @property
    def measurement_names(self) -> tuple[str, ...]:
        """Names of the measurement components (default z1..zm): the column headers a recorded
        measurements file may use (``data:``, :mod:`pfx.config.data`; z1..zm always work too)."""
        return tuple(f"z{i + 1}" for i in range(self.measurement_dimension))

    @property
    def process_noise_dimension(self) -> int:
        return self.state_dimension

    @property
    def position_components(self) -> tuple[int, ...]:
        """Indices of the state components that form the 'position' (for error distance)."""
        return tuple(range(self.state_dimension))

    @property
    def position_unit(self) -> str:
        units = {self.state_units[i] for i in self.position_components}
        return units.pop() if len(units) == 1 else ""

    @property
    def angular_components(self) -> tuple[int, ...]:
        """Indices of the state components that are angles, in units of :attr:`full_turn`.

        The estimate averages them on the circle and errors are wrapped (:mod:`pfx.numerics.angles`).
        """
        return ()

    @property
    def full_turn(self) -> float:
        """One full turn in the unit of the angular components (2 pi: radians)."""
        return 2.0 * math.pi

    @property
    def measurement_angular_components(self) -> tuple[int, ...]:
        """Indices of the measurement components that are angles (bearings), in units of
        :attr:`measurement_full_turn`; default none.

        An angle and the same angle plus a full turn are one measurement: the default
        :meth:`log_likelihood`, the Kalman filters and the guided proposals wrap the innovation
        z - h(x) of these components into half a turn either side, and the UKF averages their
        sigma points on the circle (:mod:`pfx.filters.kalman.measurement_form`).
        """
        return ()

    @property
    def measurement_full_turn(self) -> float:
        """One full turn in the unit of the angular measurement components (2 pi: radians)."""
        return 2.0 * math.pi

    @property
    def matrices(self) -> Optional[tuple[np.ndarray, np.ndarray]]:
        """(A, H) for a linear model, the Kalman filter's (``kf``) matrices: ``propagate(x, u_k, w)
        = A x + c_k + L w`` (c_k = propagate(0, u_k, 0), the control's share; L the process noise
        Jacobian) and ``measurement_mean(x) = H x``; A of shape (d, d), H (m, d). None (the
        default): not a linear model. pfx checks a plugin's matrices against its ``propagate``
        and ``measurement_mean`` before the kf runs (:mod:`pfx.filters.kalman.linear_form`)."""
        return None

    @property
    def covariate_names(self) -> tuple[str, ...]:
        """The covariates the model reads (:meth:`covariates_at`), in order; default none."""
        return ()

    @property
    def accumulating_components(self) -> tuple[int, ...]:
        """Indices of the state components reset to 0 at the start of every step's transition,
        before its first substep, so that they accumulate over the substeps between two
        measurements (deaths counted between observations: pomp's accumulator variables)."""
        return ()

    # The parameters (dotted paths under ``model``) whose values the model's methods can take as
    # arrays over the leading axes, (R, 1, 1) for one value per trial row or (R, N, 1) for one
    # per particle, broadcasting against state arrays (R, N, d): parameter estimation then runs
    # many chains in one batch (:meth:`with_parameter_arrays`, docs/estimation.md). A top-level
    # field named here must be read by propagate and log_likelihood in expressions that
    # broadcast so; ``process_noise.variance`` and ``measurement_noise.variance`` (a number)
    # work for a model that uses its noises only through ``sample`` and ``log_density``.
    vectorised_parameters: ClassVar[tuple[str, ...]] = ()
    _recorded_times: Optional[np.ndarray] = PrivateAttr(None)    # set by use_recorded_times
    _transition_density: Any = PrivateAttr(None)                   # derived on first use (transition_density)
    _covariate_table: Optional[tuple[np.ndarray, np.ndarray]] = PrivateAttr(None)   # (times, values (n, c))
    _provisional_times: bool = PrivateAttr(False)   # presets running before recorded times may come (derived_presets)

    def control(self, step: int) -> Optional[np.ndarray]:
        """The control input u_k applied between step k-1 and step k (k = 1..T)."""
        return None

    def propagate(self, state: np.ndarray, control: Optional[np.ndarray], noise: np.ndarray) -> np.ndarray:
        """x_k = f(x_{k-1}, u_k, w_k); ``noise`` has shape state.shape[:-1] + (process noise dim,)."""
        raise NotImplementedError

    def measurement_mean(self, state: np.ndarray) -> np.ndarray:
        """h(x): the noise-free measurement, shape state.shape[:-1] + (m,)."""
        raise NotImplementedError

    def measure(self, state: np.ndarray, noise: np.ndarray) -> np.ndarray:
        """z = h(x) + v."""
        return self.measurement_mean(state) + noise

    def log_likelihood(self, measurement: np.ndarray, state: np.ndarray) -> np.ndarray:
        """log p(z | x) under the measurement noise, of the innovation z - h(x) with its angular
        components (:attr:`measurement_angular_components`) wrapped; ``measurement`` broadcasts
        against ``state``."""
        innovation = measurement - self.measurement_mean(state)
        angles = self.measurement_angular_components
        if angles:
            innovation = wrap_components(innovation, angles, self.measurement_full_turn)
        return self.measurement_noise.log_density(innovation)

    def default_prior(self):
        """The prior a filter starts from unless its config names one (default: ``initial``)."""
        return self.initial

    def scene(self) -> list[dict[str, Any]]:
        """The fixed things of the model's world, for map figures (written to scene.csv).

        One dict per element with keys ``element`` (``beacon``, ``wall``, ``path``, ``region``,
        ...), ``x``, ``y`` and, for segments and boxes, ``x_end``, ``y_end``; ``label`` optional.
        A ``path`` is the polyline through its rows in order. Default: nothing.
        """
        return []

    # -- Jacobians for the extended Kalman filter (optional) ------------------------------------

    def transition_jacobian(self, state: np.ndarray, control: Optional[np.ndarray]) -> Optional[np.ndarray]:
        """F = d f / d x at (state, control, w = 0), shape state.shape[:-1] + (d, d).

        None (the default): not given analytically; the EKF then uses central finite differences.
        """
        return None

    def process_noise_jacobian(self, state: np.ndarray, control: Optional[np.ndarray]) -> Optional[np.ndarray]:
        """L = d f / d w at (state, control, w = 0), shape state.shape[:-1] + (d, process noise dim).

        The identity for noise added to the state. None (the default): finite differences over w.
        """
        return None

    def measurement_jacobian(self, state: np.ndarray) -> Optional[np.ndarray]:
        """H = d h / d x at ``state``, shape state.shape[:-1] + (m, d).

        None (the default): not given analytically; the EKF then uses central finite differences.
        """
        return None

    # -- an optional compiled step (speed only) ------------------------------------------------

    def compiled_step(self) -> Optional[Callable]:
        """The transition and the log-likelihood fused in one compiled pass over the particles.

        None (the default): the engine calls :meth:`propagate` and :meth:`log_likelihood`, as it
        always may. A model that offers one returns a function
        ``step(state (R, N, d), control, noise (R, N, q), measurement (R, m)) -> (new state
        (R, N, d), log-likelihood (R, N))`` that gives what ``propagate(state, control, noise)``
        and ``log_likelihood(measurement[:, None, :], new state)`` give, to rounding (the
        compiled ``exp`` and NumPy's may differ in the last bit). It is a speed-up only: the engine
        uses it for the bootstrap filter with the ``gaussian`` weighting and draws the noise exactly
        as :meth:`transition` does, so the random streams are consumed identically. It may return
        None for settings it does not cover (another noise family, say).
        """
        return None

    # -- the transition density and the look-ahead (for algorithms that evaluate them) ---------

    def transition_density(self):
        """The model's additive transition (:class:`~pfx.laws.transition_density.AdditiveTransition`:
        L, the noise, Q and its Cholesky factor), derived once per model, or
        :class:`~pfx.laws.transition_density.TransitionDensityUnavailable` saying why there is
        none (:mod:`pfx.laws.transition_density`). Guided proposals, the MCMC move, the
        histogram filter and smoothers read it; none probes the model on its own."""
        if self._transition_density is None:
            from pfx.laws.transition_density import derive_transition_density

            self._transition_density = derive_transition_density(self)
        return self._transition_density

    def transition_log_density(self, state: np.ndarray, previous: np.ndarray, step: int) -> np.ndarray:
        r"""log p(x_k | x_{k-1}, u_k): ``state`` x_k (..., d) and ``previous`` x_{k-1} (..., d)
        broadcast against each other; shape (...).

        Default: from the additive noise, :math:`\log p_{Lw}(x_k - f(x_{k-1}, u_k, 0))`
        (:meth:`transition_density`; ValueError if the model has none). A model whose noise does
        not enter additively, but whose transition has a density, may override it.
        """
        density = self.transition_density()
        if isinstance(density, ValueError) or not density.has_density:
            reason = density.reason if isinstance(density, ValueError) else "has a singular process noise covariance"
            raise ValueError(f"model {self.kind} has no transition density pfx can evaluate: it {reason}")
        return density.log_density(state, self.mean_transition(previous, step))

    def look_ahead_log_weight(self, previous: np.ndarray, step: int, measurement: np.ndarray) -> np.ndarray:
        r"""The auxiliary particle filter's first-stage log-weight g(x_{k-1}) of each particle,
        :math:`\log \hat p(z_k \mid x_{k-1})`: (R, N) from ``previous`` (R, N, d) and ``measurement``
        (R, 1, m) (rows whose measurement is missing hold a finite stand-in; their values are
        ignored).

        Default (Pitt & Shephard 1999): the likelihood at the point prediction,
        :math:`\log p(z_k \mid f(x_{k-1}, u_k, 0))` (over every substep: :meth:`mean_transition`). A model may give a better look-ahead (the
        ``logeta`` of the ``particles`` library): the closer to :math:`\log p(z_k \mid x_{k-1})`,
        the flatter the second-stage weights. Any finite function keeps the likelihood estimate
        unbiased: the second stage divides its exponential out again.
        """
        return self.log_likelihood(measurement, self.mean_transition(previous, step))

    # -- composed operations used by the engine and the truth simulator ------------------------

    def transition(self, state: np.ndarray, step: int, random: TrialStreams) -> np.ndarray:
        r"""Sample x_k ~ p(x_k | x_{k-1}, u_k) for every leading index; trial axis first: the
        step's control and substep times read on the host, then :meth:`sample_transition`."""
        times = [self.substep_time(step, substep) for substep in range(self.propagations_per_step)]
        return self.sample_transition(state, self.control(step), times, random)

    def sample_transition(self, state, control, times, random):
        r"""Sample x_k ~ p(x_k | x_{k-1}, u_k) given the control u_k and the start times of the
        step's substeps (one per :meth:`sample_substep`).

        The composition of the step's substeps (module docstring): the accumulating components
        reset, then :math:`x \leftarrow` :meth:`sample_substep` for j = 1..s, in order. A model
        overrides :meth:`sample_substep` to draw its own way at each substep; it overrides this
        method only for a transition that is not a sequence of substeps. Either runs on both
        backends (on jax, ``control`` and ``times`` are arrays of the compiled step, and the
        jax backend scans :meth:`sample_substep` over the substeps itself).
        """
        state = self.reset_accumulators(state)
        for time in times:
            state = self.sample_substep(state, control, time, random)
        return state

    def sample_substep(self, state, control, time, random):
        r"""One substep of the transition from ``state``, starting at ``time``:
        :math:`f(x, u_k, w)` with a fresh draw w of the process noise (``propagate``). A model
        whose substep draws in another way (counts moving between compartments:
        :func:`pfx.euler_multinomial`) overrides it, drawing from ``random``."""
        noise = self.process_noise.sample(random, state.shape[1:-1])
        return self.propagate_at(state, control, noise, time)

    @classmethod
    def transition_method(cls) -> str:
        """The method that makes this model's transition, as messages name it: the outermost of
        :meth:`transition`, :meth:`sample_transition` and :meth:`sample_substep` its class
        defines, else ``propagate`` (the default substep draws the process noise and calls it)."""
        for name in ("transition", "sample_transition", "sample_substep"):
            if getattr(cls, name) is not getattr(Model, name):
                return name
        return "propagate"

    def mean_transition(self, previous: np.ndarray, step: int) -> np.ndarray:
        r"""The noise-free transition over step k, :math:`\bar f_k(x_{k-1})`: (..., d) from
        ``previous`` (..., d).

        :math:`x^{(0)} = R\,x_{k-1}` (the accumulating components reset),
        :math:`x^{(j)} = f(x^{(j-1)}, u_k, 0; t_{k-1} + (j-1) h)` for j = 1..s, and
        :math:`\bar f_k(x_{k-1}) = x^{(s)}`; with one substep, :math:`f(x_{k-1}, u_k, 0)`. What
        "the prediction of x_k without noise" means for the transition density, the guided
        proposals, the look-ahead and the histogram filter. ``previous`` may be a NumPy or a JAX
        array; the result is of the same kind (for a ``propagate`` written generically).
        """
        control = self.control(step)
        state = self.reset_accumulators(previous)
        xp = namespace(previous)
        shape = previous.shape[:-1] + (self.process_noise_dimension,)
        # NumPy's zeros are float64, as always; JAX's take the state's precision (a float32 run stays float32)
        zeros = xp.zeros(shape) if xp is np else xp.zeros(shape, dtype=previous.dtype)
        for substep in range(self.propagations_per_step):
            state = self.propagate_at(state, control, zeros, self.substep_time(step, substep))
        return state

    def reset_accumulators(self, state: np.ndarray) -> np.ndarray:
        """``state`` with its accumulating components set to 0 (a copy, on NumPy in float64; ``state``
        itself when the model has none). NumPy or JAX arrays alike (:mod:`pfx.numerics.arrays`)."""
        components = list(self.accumulating_components)
        if not components:
            return state
        return with_values(state, (..., components), 0.0)     # functional: a JAX array cannot be written

    def truth_event(self, state: np.ndarray, step: int) -> np.ndarray:
        """What happens to the true state at step k beyond the transition (a kidnapping): applied
        by the truth simulation only, after the transition; a filter never calls it. Default: nothing."""
        return state

    def simulate_measurement(self, state: np.ndarray, random: TrialStreams) -> np.ndarray:
        """Sample z_k ~ p(z_k | x_k)."""
        return self.measure(state, self.measurement_noise.sample(random, state.shape[1:-1]))

    def check_contract(self, random: TrialStreams) -> None:
        """Call the model's methods once on a tiny batch (2 trials, 3 particles drawn from the
        initial law) and raise ``ValueError("<method> returned ...")`` where a result has the
        wrong shape or is not a floating-point array, or a declared index list is not one: the
        public contract (module docstring), checked before a run rather than deep inside the
        engine (:func:`pfx.models.contract_checks.check_contract`)."""
        check_contract(self, random)

    # -- validation ----------------------------------------------------------------------------

    @model_validator(mode="after")
    def _resolve(self) -> "Model":
        self._covariate_table = covariate_table(self)     # first: presets may read the covariates
        for name, value in self.derived_presets().items():
            if getattr(self, name) is None:
                setattr(self, name, value)
        if self.dt is None:     # a model without a time step of its own counts time in steps
            self.dt = 1.0
        missing = [name for name in ("steps", "dt", "process_noise", "measurement_noise", "initial")
                   if getattr(self, name) is None]
        if missing:
            raise ValueError(f"@{missing[0]}: required for model {self.kind}")
        self._check_substeps()
        self._bind_and_set_up()
        return self

    def _bind_and_set_up(self) -> None:
        """The checks, the laws bound to their dimensions, ``setup()``: what follows from the fields."""
        self.check()
        _bind(self.process_noise, self.process_noise_dimension, "process_noise", need_density=False)
        _bind(self.measurement_noise, self.measurement_dimension, "measurement_noise", need_density=True)
        _bind(self.initial, self.state_dimension, "initial")
        self.setup()
        self._transition_density = None           # derived again from these parameters when asked

    def with_parameter_arrays(self, values: dict[str, np.ndarray]) -> "Model":
        """A copy of the model whose parameters at the dotted paths of ``values`` (each one of
        :attr:`vectorised_parameters`) are arrays, (R, 1, 1) or (R, N, 1), one value per trial row
        or per particle. No check runs and nothing is derived again from them (presets, the
        initial law): the copy is for the filter's transition and likelihood, not for validation.
        ValueError for a path the model does not declare."""
        copy_ = super().model_copy()
        for path, value in values.items():
            if path not in type(self).vectorised_parameters:
                raise ValueError(f"model {self.kind} does not take {path} as an array (its vectorised_parameters: "
                                 f"{', '.join(type(self).vectorised_parameters) or 'none'})")
            if path in NOISE_VARIANCES:
                name = path.split(".")[0]
                copy_.__dict__[name] = getattr(self, name).with_row_variances(value)
            else:
                copy_.__dict__[path] = value
        copy_._transition_density = None
        return copy_

    def model_copy(self, *, update: Optional[dict[str, Any]] = None, deep: bool = False) -> "Model":
        """A copy of the model; with ``update``, a new model validated from the copy's parameters
        and the updated ones: its checks run and ``setup()`` computes its caches again, so none
        is stale (pydantic's own ``model_copy(update=...)`` would keep the old ones beside the new
        parameters). Fields the presets filled keep their values. Recorded times are kept."""
        if not update:
            return super().model_copy(deep=deep)
        parameters = {name: copy.deepcopy(getattr(self, name)) for name in type(self).model_fields}
        parameters.update(update)
        fresh = type(self).model_validate(parameters)
        fresh._recorded_times = self._recorded_times
        return fresh


def _bind(component, dimension: int, key: str, **options) -> None:
    try:
        component.bind(dimension, **options)
    except ValueError as error:
        message = str(error)
        if message.startswith("@"):
            raise ValueError(f"@{key}.{message[1:]}") from None
        raise ValueError(f"@{key}: {message}") from None


def bind_law(law, dimension: int, key: str):
    """Bind an initial law to a dimension, locating errors under ``key``."""
    _bind(law, dimension, key)
    return law


# Every model, under its ``kind``: a model module decorates its class with ``@MODELS.register_kind``.
MODELS: Registry[type[Model]] = Registry("model")
