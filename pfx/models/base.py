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
``propagate`` and ``measurement_mean`` (:func:`missing_methods`); everything else has a
default. With ``R`` trials, ``N`` particles, ``d`` states, ``m`` measurement components and
``q`` process noise components, and ``...`` standing for the leading dimensions (``(R,)`` for
the truth, ``(R, N)`` for particles):

=====================================================  =========================================
``propagate(state (..., d), control, noise (..., q))``  the new state, ``(..., d)``, floating point
``measurement_mean(state (..., d))``                    h(x), ``(..., m)``, floating point
``simulate_measurement(state (R, d), random)``          one measurement per trial, ``(R, m)``
``log_likelihood(measurement, state (R, N, d))``        ``(R, N)``; measurement ``(R, 1, m)``
=====================================================  =========================================

**Observation intervals.** ``dt`` is the time between two measurements (two filter steps).
A model integrated with a smaller step declares ``integrates_substeps = True``, lets its
``propagate`` advance one substep of :attr:`Model.substep_duration` = ``dt / substeps``, and the
config sets ``substeps``: the transition from step k-1 to step k is then

.. math::

    x^{(0)} = R\,x_{k-1}, \qquad
    x^{(j)} = f\big(x^{(j-1)}, u_k, w^{(j)}; t_{k-1} + (j-1) h\big) \quad (j = 1..s), \qquad
    x_k = x^{(s)},

with :math:`h` the substep duration, :math:`w^{(j)}` a fresh draw of the process noise for
every substep (``process_noise`` is the law of one ``propagate`` call) and :math:`R` the reset
of the accumulating components (:attr:`Model.accumulating_components`: counts over the
interval, set to 0 before its first substep). A ``propagate`` with a parameter named ``time``
is given the time at the start of its substep. :meth:`Model.mean_transition` is the same
composition with every :math:`w^{(j)} = 0`. With ``substeps: 1`` (the default) this is one
``propagate`` call, as it always was.

A measurement that is not "h(x) + noise" (multiplicative noise, say) overrides both
``simulate_measurement`` (how the truth's measurements are drawn; every draw from ``random``)
and ``log_likelihood`` (log p(z | x), in the log domain). :meth:`Model.check_contract` checks
the shapes and dtypes once, on a tiny batch, before a plugin's model runs.
"""

from __future__ import annotations

import copy
import functools
import inspect
import math
from types import FunctionType
from typing import Any, Callable, ClassVar, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, StrictFloat, StrictInt, model_validator

from pfx.laws.initial import InitialLaw
from pfx.laws.noise import Noise
from pfx.models.contract_checks import check_component_indices
from pfx.numerics.angles import wrap_components
from pfx.numerics.seeding import TrialStreams
from pfx.registry import Registry

# The two noise parameters a model may take as arrays (Model.vectorised_parameters)
NOISE_VARIANCES = ("process_noise.variance", "measurement_noise.variance")


def _as_data(value: Any) -> Any:
    """A field's value as plain data (pydantic models dumped), for comparing."""
    return value.model_dump(mode="json") if isinstance(value, BaseModel) else value


class Model(BaseModel):
    """Base class of all models (see the module docstring)."""

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
        return {name for name, value in self.presets().items() if _as_data(getattr(self, name)) == _as_data(value)}

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

    @property
    def substep_duration(self) -> float:
        """h = dt / substeps: the time one ``propagate`` call advances in a model that
        integrates substeps (``integrates_substeps``)."""
        return self.dt / self.substeps

    @property
    def propagations_per_step(self) -> int:
        """How many times the transition calls ``propagate`` between two measurements:
        ``substeps``, or 1 for a model whose own ``propagate`` integrates the whole interval
        (``substeps_inside_propagate``)."""
        return 1 if self.substeps_inside_propagate else self.substeps

    time_unit: ClassVar[str] = "s"
    # Whether ``propagate`` advances one substep of ``substep_duration`` (so that ``substeps``
    # may exceed 1). A model whose propagate integrates a whole ``dt`` must not declare it:
    # with substeps it would integrate s times too far.
    integrates_substeps: ClassVar[bool] = False
    # Whether the model's own ``substeps`` field counts integration steps inside one
    # ``propagate`` call that spans the whole interval, with the process noise added once per
    # interval (the falling body, whose field is older than the substeps of every model):
    # the transition then calls propagate once per step.
    substeps_inside_propagate: ClassVar[bool] = False
    # Whether the model reads :meth:`step_duration` (the time between steps may vary), so that
    # recorded data with irregular times can be filtered with it; no built-in model does.
    variable_dt: ClassVar[bool] = False
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
        r"""Sample x_k ~ p(x_k | x_{k-1}, u_k) for every leading index; trial axis first.

        The composition of the step's substeps (module docstring): the accumulating components
        reset, then :math:`x \leftarrow f(x, u_k, w^{(j)})` for j = 1..s, each with a fresh
        draw :math:`w^{(j)}` of the process noise from the trials' streams, in order.
        """
        control = self.control(step)
        state = self.reset_accumulators(state)
        for substep in range(self.propagations_per_step):
            noise = self.process_noise.sample(random, state.shape[1:-1])
            state = self.propagate_at(state, control, noise, self.substep_time(step, substep))
        return state

    def mean_transition(self, previous: np.ndarray, step: int) -> np.ndarray:
        r"""The noise-free transition over step k, :math:`\bar f_k(x_{k-1})`: (..., d) from
        ``previous`` (..., d).

        :math:`x^{(0)} = R\,x_{k-1}` (the accumulating components reset),
        :math:`x^{(j)} = f(x^{(j-1)}, u_k, 0; t_{k-1} + (j-1) h)` for j = 1..s, and
        :math:`\bar f_k(x_{k-1}) = x^{(s)}`; with one substep, :math:`f(x_{k-1}, u_k, 0)`. What
        "the prediction of x_k without noise" means for the transition density, the guided
        proposals, the look-ahead and the histogram filter.
        """
        control = self.control(step)
        state = self.reset_accumulators(previous)
        zeros = np.zeros(previous.shape[:-1] + (self.process_noise_dimension,))
        for substep in range(self.propagations_per_step):
            state = self.propagate_at(state, control, zeros, self.substep_time(step, substep))
        return state

    def reset_accumulators(self, state: np.ndarray) -> np.ndarray:
        """``state`` with its accumulating components set to 0 (a copy; ``state`` itself when the
        model has none)."""
        components = list(self.accumulating_components)
        if not components:
            return state
        state = np.array(state, dtype=float)
        state[..., components] = 0.0
        return state

    def substep_time(self, step: int, substep: int) -> float:
        """t_(k-1) + j h: the time at the start of substep j = 0..s-1 of step k (h the substep
        duration), with t_(k-1) the time of step k-1 (:meth:`times`) and, for k = 1,
        t_1 - dt. What a ``propagate`` with a ``time`` parameter is given."""
        if step >= 2:
            start = float(self._recorded_times[step - 2]) if self._recorded_times is not None else self.dt * (step - 1)
        else:
            first = float(self._recorded_times[0]) if self._recorded_times is not None else self.dt
            start = first - self.step_duration(1)
        return start + substep * self.substep_duration if substep else start

    @property
    def propagate_reads_time(self) -> bool:
        """Whether the model's ``propagate`` has a ``time`` parameter (its transition may change
        with time, so nothing about it may be computed once for every step)."""
        return _takes_time(type(self).propagate)

    def propagate_at(self, state: np.ndarray, control: Optional[np.ndarray], noise: np.ndarray,
                     time: float) -> np.ndarray:
        """``propagate(state, control, noise)``, with ``time=time`` if the model's propagate has
        a parameter named ``time`` (looked up once per class)."""
        if self.propagate_reads_time:
            return self.propagate(state, control, noise, time=time)
        return self.propagate(state, control, noise)

    def transition_jacobian_at(self, state: np.ndarray, control: Optional[np.ndarray],
                               time: float) -> Optional[np.ndarray]:
        """``transition_jacobian(state, control)``, with ``time=time`` if it takes a ``time``."""
        if _takes_time(type(self).transition_jacobian):
            return self.transition_jacobian(state, control, time=time)
        return self.transition_jacobian(state, control)

    def process_noise_jacobian_at(self, state: np.ndarray, control: Optional[np.ndarray],
                                  time: float) -> Optional[np.ndarray]:
        """``process_noise_jacobian(state, control)``, with ``time=time`` if it takes a ``time``."""
        if _takes_time(type(self).process_noise_jacobian):
            return self.process_noise_jacobian(state, control, time=time)
        return self.process_noise_jacobian(state, control)

    def truth_event(self, state: np.ndarray, step: int) -> np.ndarray:
        """What happens to the true state at step k beyond the transition (a kidnapping): applied
        by the truth simulation only, after the transition; a filter never calls it. Default: nothing."""
        return state

    def simulate_measurement(self, state: np.ndarray, random: TrialStreams) -> np.ndarray:
        """Sample z_k ~ p(z_k | x_k)."""
        return self.measure(state, self.measurement_noise.sample(random, state.shape[1:-1]))

    def times(self) -> np.ndarray:
        """Time of steps 1..T (recorded data's own times when its file has a ``time`` column)."""
        if self._recorded_times is not None:
            return self._recorded_times.copy()
        return self.dt * np.arange(1, self.steps + 1)

    def step_duration(self, step: int) -> float:
        """The time from step k-1 to step k: ``dt``, or with recorded irregular times (only for
        a model that declares ``variable_dt``) t_k - t_(k-1), and ``dt`` before the first step."""
        if self._recorded_times is None or step <= 1:
            return self.dt
        return float(self._recorded_times[step - 1] - self._recorded_times[step - 2])

    def covariates_at(self, time: float) -> np.ndarray:
        r"""The covariates at ``time``, one per :attr:`covariate_names`, linearly interpolated
        between the two rows of the table around it:
        :math:`c(t) = c_j + (t - t_j) (c_{j+1} - c_j) / (t_{j+1} - t_j)` for
        :math:`t_j \le t \le t_{j+1}`. ValueError outside the table's times (pfx checks before a
        run that the table covers the model's times, :meth:`check_covariate_span`)."""
        if self._covariate_table is None:
            raise ValueError(f"model {self.kind} reads no covariates (its covariate_names is empty)")
        times, values = self._covariate_table
        slack = time_slack(times)
        if not times[0] - slack <= time <= times[-1] + slack:
            raise ValueError(f"model {self.kind}: covariates asked at time {time:.12g}, outside their table "
                             f"({times[0]:.12g} to {times[-1]:.12g})")
        time = min(max(time, times[0]), times[-1])      # an end's row, for a time within the slack of it
        row = min(int(np.searchsorted(times, time, side="right")) - 1, len(times) - 2)
        if row < 0:          # a table of one row: constant covariates
            return values[0].copy()
        share = (time - times[row]) / (times[row + 1] - times[row])
        return values[row] + share * (values[row + 1] - values[row])

    def check_covariate_span(self) -> None:
        """ValueError('@covariates: ...') unless the covariate table covers the times the
        transition reads: from the start of step 1 (its time minus the step's duration) to the
        last step's time."""
        if self._covariate_table is None:
            return
        times = self.times()
        start, end = float(times[0] - self.step_duration(1)), float(times[-1])
        table = self._covariate_table[0]
        slack = time_slack(table)
        if start < table[0] - slack or end > table[-1] + slack:
            raise ValueError(f"@covariates: the table's times run from {table[0]:.12g} to {table[-1]:.12g}; the "
                             f"model reads covariates from {start:.12g} (the start of step 1) to {end:.12g} "
                             f"(step {self.steps}): give rows that cover them")

    def use_recorded_times(self, times: np.ndarray) -> None:
        """Take the times of steps 1..T from recorded data (:mod:`pfx.config.data`)."""
        self._recorded_times = np.asarray(times, dtype=float).copy()

    def check_contract(self, random: TrialStreams) -> None:
        """Call the model's methods once on a tiny batch (2 trials, 3 particles drawn from the
        initial law) and raise ``ValueError("<method> returned ...")`` where a result has the
        wrong shape or is not a floating-point array, or a declared index list is not one
        (:func:`~pfx.models.contract_checks.check_component_indices`): the public contract
        (module docstring), checked before a run rather than deep inside the engine."""
        trials, particles = 2, 3
        self._check_names()
        d, m = self.state_dimension, self.measurement_dimension
        check_component_indices(self)
        for path in type(self).vectorised_parameters:
            value = getattr(self, path, None) if path not in NOISE_VARIANCES else 0.0
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"vectorised_parameters names {path!r}, which is not a number of the model; "
                                 f"expected its scalar fields or {' or '.join(NOISE_VARIANCES)}")
        cloud = np.asarray(self.initial.sample(random, (particles,)), dtype=float).reshape(trials, particles, d)
        truth = cloud[:, 0, :].copy()
        noise = np.zeros((trials, particles, self.process_noise_dimension))
        time = self.substep_time(1, 0)
        if self._covariate_table is not None:   # shapes only: a time the table has (its span is checked
            time = float(np.clip(time, self._covariate_table[0][0], self._covariate_table[0][-1]))   # with the run's times)
        _check_result("propagate", self.propagate_at(cloud, self.control(1), noise, time),
                      (trials, particles, d))
        _check_result("measurement_mean", self.measurement_mean(cloud), (trials, particles, m))
        measurement = _check_result("simulate_measurement", self.simulate_measurement(truth, random), (trials, m))
        _check_result("log_likelihood", self.log_likelihood(measurement[:, None, :], cloud), (trials, particles))

    def _check_names(self) -> None:
        """The model agrees with itself: names and sizes (``state_names``, ``state_units``,
        ``measurement_dimension``, ``measurement_names``, ``process_noise_dimension``)."""
        names = self.state_names
        if not (isinstance(names, (tuple, list)) and names and all(isinstance(n, str) and n for n in names)):
            raise ValueError(f"state_names returned {names!r}; expected a tuple of names, one per state "
                             "component, e.g. ('x', 'v')")
        if len(set(names)) != len(names):
            raise ValueError(f"state_names returned {tuple(names)!r}, which repeats a name; each state "
                             "component needs its own (they become column names)")
        for name in ("measurement_dimension", "process_noise_dimension"):
            size = getattr(self, name)
            if not isinstance(size, (int, np.integer)) or isinstance(size, bool) or size < 1:
                raise ValueError(f"{name} returned {size!r}; expected a whole number of at least 1")
        lists = (("measurement_names", self.measurement_dimension, "measurement_dimension"),
                 ("state_units", len(names), "state_names"))
        for name, size, source in lists:
            value = getattr(self, name)
            if not (isinstance(value, (tuple, list)) and all(isinstance(item, str) for item in value)):
                raise ValueError(f"{name} returned {value!r}; expected a tuple of {size} strings")
            if len(value) != size:
                raise ValueError(f"{name} returned {len(value)} name(s) {tuple(value)!r}, and {source} says "
                                 f"{size}: give one per component")
        measurement_names = tuple(self.measurement_names)
        if len(set(measurement_names)) != len(measurement_names) or "" in measurement_names:
            raise ValueError(f"measurement_names returned {measurement_names!r}; expected distinct, non-empty "
                             "names (they become the column names of a measurements file)")

    # -- validation ----------------------------------------------------------------------------

    @model_validator(mode="after")
    def _resolve(self) -> "Model":
        self._covariate_table = _covariate_table(self)     # first: presets may read the covariates
        for name, value in self.presets().items():
            if getattr(self, name) is None:
                setattr(self, name, value)
        if self.dt is None:     # a model without a time step of its own counts time in steps
            self.dt = 1.0
        missing = [name for name in ("steps", "dt", "process_noise", "measurement_noise", "initial")
                   if getattr(self, name) is None]
        if missing:
            raise ValueError(f"@{missing[0]}: required for model {self.kind}")
        self._check_substeps()
        self.check()
        _bind(self.process_noise, self.process_noise_dimension, "process_noise", need_density=False)
        _bind(self.measurement_noise, self.measurement_dimension, "measurement_noise", need_density=True)
        _bind(self.initial, self.state_dimension, "initial")
        self.setup()
        self._transition_density = None           # derived again from these parameters when asked
        return self

    def _check_substeps(self) -> None:
        """substeps > 1 only for a model whose propagate advances one substep."""
        cls = type(self)
        if self.substeps == 1 or cls.substeps_inside_propagate:
            return
        if not cls.integrates_substeps:
            raise ValueError(f"@substeps: model {self.kind}'s propagate advances a whole dt, so it cannot take "
                             f"{self.substeps} substeps between measurements; a model whose propagate advances "
                             "self.substep_duration (dt / substeps) declares integrates_substeps = True")
        if cls.variable_dt:
            raise ValueError(f"@substeps: model {self.kind} declares variable_dt (irregular measurement times), "
                             "and pfx does not take substeps between irregular times; leave substeps at 1")

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


# Times read from files carry their printing precision (15 significant digits, say): two times
# this close, relative to the largest time's magnitude, are the same time. Recorded data's
# spacings (pfx.config.data) and the ends of a covariate table are compared with it.
RELATIVE_TIME_TOLERANCE = 1e-9


def time_slack(times: np.ndarray) -> float:
    """How far apart two of ``times`` (increasing) may be and still count as equal:
    RELATIVE_TIME_TOLERANCE times the largest magnitude among them, which is at one end (a time
    1 month before a table's first row, computed as t_1 - dt from printed times, may fall 1e-11
    short of it). Two lookups, not a pass over the times: covariates_at asks at every substep."""
    return RELATIVE_TIME_TOLERANCE * max(abs(float(times[0])), abs(float(times[-1])))


def _covariate_table(model: Model) -> Optional[tuple[np.ndarray, np.ndarray]]:
    """The model's ``covariates`` as (times (n,), values (n, c)) in ``covariate_names`` order,
    checked against the names the model reads; None for a model that reads none."""
    names, table = tuple(model.covariate_names), model.covariates
    if not names:
        if table is not None:
            raise ValueError(f"@covariates: model {model.kind} reads no covariates; drop them")
        return None
    if table is None:
        raise ValueError(f"@covariates: model {model.kind} reads the covariates {', '.join(names)} over time: "
                         "give a table of them (data.covariates: a CSV file with `time` and those columns)")
    if "time" not in table:
        raise ValueError("@covariates: the table has no `time`")
    unknown = [name for name in table if name != "time" and name not in names]
    missing = [name for name in names if name not in table]
    if missing or unknown:
        what = f"has no {missing[0]!r}" if missing else f"has {unknown[0]!r}, which the model does not read"
        raise ValueError(f"@covariates: the table {what}; model {model.kind} reads {', '.join(names)}")
    times = np.asarray(table["time"], dtype=float)
    if times.size == 0 or not np.all(np.diff(times) > 0):
        raise ValueError("@covariates.time: the times must increase strictly (and there must be at least one)")
    lengths = {name: len(table[name]) for name in names if len(table[name]) != times.size}
    if lengths:
        name, length = next(iter(lengths.items()))
        raise ValueError(f"@covariates.{name}: {length} values for {times.size} times")
    values = np.column_stack([np.asarray(table[name], dtype=float) for name in names])
    # Interpolation steps from one row to the next by their difference; a difference that
    # overflows (values of opposite signs near the largest float, 1.8e308) would give inf and
    # NaN between the rows, and the model would be blamed for them.
    with np.errstate(over="ignore", invalid="ignore"):
        jumps = np.diff(values, axis=0)
    if not np.isfinite(jumps).all():
        row, column = (int(index) for index in np.argwhere(~np.isfinite(jumps))[0])
        raise ValueError(f"@covariates.{names[column]}[{row + 1}]: {values[row + 1, column]:g} after "
                         f"{values[row, column]:g}: the change between the two rows is too large to be represented "
                         "as a number, so the values between them cannot be interpolated; use smaller values "
                         "(other units)")
    return times, values


def _check_result(method: str, value, shape: tuple) -> np.ndarray:
    """A method's result, if it is a floating-point array of ``shape``; else ValueError."""
    if not isinstance(value, np.ndarray):
        raise ValueError(f"{method} returned {type(value).__name__}, not a numpy array of shape {shape}")
    if value.shape != shape:
        raise ValueError(f"{method} returned shape {value.shape} for a batch of 2 trials x 3 particles; "
                         f"expected {shape}")
    if not np.issubdtype(value.dtype, np.floating):
        raise ValueError(f"{method} returned dtype {value.dtype}; expected floating point (float64)")
    return value


def _bind(component, dimension: int, key: str, **options) -> None:
    try:
        component.bind(dimension, **options)
    except ValueError as error:
        message = str(error)
        if message.startswith("@"):
            raise ValueError(f"@{key}.{message[1:]}") from None
        raise ValueError(f"@{key}: {message}") from None


@functools.lru_cache(maxsize=None)
def _takes_time(method: Callable) -> bool:
    """Whether a model method (the function on the class) has a parameter named ``time``."""
    try:
        return "time" in inspect.signature(method).parameters
    except (TypeError, ValueError):      # a builtin or C function: called without time
        return False


# What every model must define itself: the rest of the interface has defaults.
REQUIRED_METHODS = ("state_names", "measurement_dimension", "propagate", "measurement_mean")


def methods_meant_as_properties(model_class: type) -> list[tuple[str, Optional[int]]]:
    """(name, line of its ``def``) of each member that :class:`Model` declares as a property
    and ``model_class`` defines as a plain method: ``def state_names(self)`` without
    ``@property``, which pfx would read as a bound method, not a tuple."""
    slips = []
    for name, member in vars(Model).items():
        if not isinstance(member, property):
            continue
        defined = inspect.getattr_static(model_class, name)
        if isinstance(defined, FunctionType):
            slips.append((name, defined.__code__.co_firstlineno))
    return slips


def missing_methods(model_class: type) -> list[str]:
    """The required members (:data:`REQUIRED_METHODS`) a model class leaves to :class:`Model`."""
    return [name for name in REQUIRED_METHODS if getattr(model_class, name) is getattr(Model, name)]


def bind_law(law, dimension: int, key: str):
    """Bind an initial law to a dimension, locating errors under ``key``."""
    _bind(law, dimension, key)
    return law


# Every model, under its ``kind``: a model module decorates its class with ``@MODELS.register_kind``.
MODELS: Registry[type[Model]] = Registry("model")
