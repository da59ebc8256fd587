r"""The time axis of a model: when its steps happen, and the covariates it reads over time.

A model's steps k = 1..T are measurement times :math:`t_1 < \dots < t_T`. By default they are
evenly spaced, :math:`t_k = k\,\Delta t` (``dt``); recorded data with a ``time`` column replaces
them with its own times (:meth:`TimeAxis.use_recorded_times`, :mod:`pfx.config.data`). The
transition from step k-1 to step k starts at :math:`t_{k-1}`, with :math:`t_0 = t_1 - \Delta t`
before the first step, and is cut into ``substeps`` pieces of :math:`h = \Delta t / s`
(``substep_duration``): substep j = 0..s-1 starts at :math:`t_{k-1} + j\,h`
(:meth:`TimeAxis.substep_time`), the ``time`` a ``propagate`` with a parameter of that name
is given.

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

**Covariates.** A model that reads quantities known over time (a census, seasonal splines)
names them (``covariate_names``) and is given a table of them, ``covariates``: rows at times
:math:`\tau_0 < \dots < \tau_{n-1}`, read by :meth:`TimeAxis.covariates_at` with linear
interpolation between the two rows around a time,

.. math::

    c(t) = c_j + \frac{t - \tau_j}{\tau_{j+1} - \tau_j}\,(c_{j+1} - c_j)
    \qquad (\tau_j \le t \le \tau_{j+1}).

The table must cover every time the transition reads, the start of every substep, from
:math:`t_0` to :math:`t_T - h` (nothing else reads covariates by time);
:meth:`TimeAxis.check_covariate_span` checks that once, before a run, so that a compiled
filter (the ``jax`` backend, whose substep times are traced values that cannot be compared
with Python's ``<``) can interpolate without checking again.

**Equal times.** Times read from files carry their printing precision: two times closer than
:data:`RELATIVE_TIME_TOLERANCE` times their magnitude are the same time (:func:`time_slack`).

:class:`TimeAxis` is a mixin of :class:`pfx.models.base.Model`: it declares what a model says
about its time (``time_unit``, ``integrates_substeps``, ``substeps_inside_propagate``,
``variable_dt``) and reads the fields and private attributes that :class:`~pfx.models.base.Model`
declares (pydantic keeps them there): ``dt``, ``steps``, ``substeps``, ``kind``,
``covariate_names``, ``_recorded_times`` and ``_covariate_table`` (what :func:`covariate_table`
makes of the ``covariates`` field when the model is validated). It also calls the methods that
may take the time (``propagate``, the Jacobians) with it where their signature has a ``time``
parameter (:meth:`TimeAxis.propagate_at`).
"""

from __future__ import annotations

import functools
import inspect
from types import ModuleType
from typing import Any, Callable, ClassVar, Optional

import numpy as np

from pfx.numerics.arrays import namespace

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


class TimeAxis:
    """The times of a model's steps and substeps, and its covariates over time (module docstring)."""

    # The unit of dt and of the times, for tables and figures (s: seconds).
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

    def times(self) -> np.ndarray:
        """Time of steps 1..T (recorded data's own times when its file has a ``time`` column)."""
        if self._recorded_times is not None:
            return self._recorded_times.copy()
        return self.dt * np.arange(1, self.steps + 1)

    def use_recorded_times(self, times: np.ndarray) -> None:
        """Take the times of steps 1..T from recorded data (:mod:`pfx.config.data`); the fields
        the model's presets filled are derived again, so that presets that read the time of the
        initial state (:attr:`start_time`) see the data's (:meth:`Model.derive_presets_again`)."""
        derived = self.preset_fields()
        self._recorded_times = np.asarray(times, dtype=float).copy()
        self.derive_presets_again(derived)

    def derive_presets_again(self, fields: set[str]) -> None:
        """Set ``fields`` (some of the model's ``preset_fields()``, found before a change of what
        its presets read, such as the recorded times) to what ``presets()`` derives now, and redo
        what follows from them (checks, the laws' binding, ``setup()``); nothing when none changes."""
        values = self.derived_presets() if fields else {}
        changed = {name: values[name] for name in fields
                   if name in values and plain_data(values[name]) != plain_data(getattr(self, name))}
        if not changed:
            return
        for name, value in changed.items():
            object.__setattr__(self, name, value)
        self._bind_and_set_up()

    def derived_presets(self) -> dict:
        """``presets()``, as pfx calls it. Until recorded data's times are attached, the times
        are provisional (t_0 = 0), and presets that read a covariate at :attr:`start_time` may
        ask outside a table that starts later (a record of 1950's): such a lookup gives the
        table's nearest end rather than failing the model. The values are never used by a run:
        the presets are derived again from the data's times (:meth:`use_recorded_times`), and
        without recorded data t_0 really is 0 and :meth:`check_covariate_span` refuses the run."""
        self._provisional_times = self._recorded_times is None
        try:
            return self.presets()
        finally:
            self._provisional_times = False

    @property
    def start_time(self) -> float:
        """t_0, the time of the initial state x_0: one step before the first measurement, t_1 -
        dt (with recorded times, the data's first time less dt; else 0). A model's ``presets``
        may read it, an initial law at the start of the record (a population, say) from it; with
        recorded data the presets are derived again once the data's times are known."""
        if self._recorded_times is None:       # t_k = k dt: t_0 = 0, even before presets give dt
            return 0.0
        return self.substep_time(1, 0)

    def step_duration(self, step: int) -> float:
        """The time from step k-1 to step k: ``dt``, or with recorded irregular times (only for
        a model that declares ``variable_dt``) t_k - t_(k-1), and ``dt`` before the first step."""
        if self._recorded_times is None or step <= 1:
            return self.dt
        return float(self._recorded_times[step - 1] - self._recorded_times[step - 2])

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

    def covariates_at(self, time: Any) -> Any:
        r"""The covariates at ``time``, one per :attr:`covariate_names`, linearly interpolated
        between the two rows of the table around it:
        :math:`c(t) = c_j + (t - t_j) (c_{j+1} - c_j) / (t_{j+1} - t_j)` for
        :math:`t_j \le t \le t_{j+1}`. ValueError outside the table's times (pfx checks before a
        run that the table covers the model's times, :meth:`check_covariate_span`).

        ``time`` is a number, or on the ``jax`` backend a JAX scalar, traced inside a compiled
        scan: its value is not known when the code runs, so it is not checked against the table
        (the span was checked before the run) but clamped to the table's ends, and the columns are
        interpolated by ``jax.numpy.interp``, the same formula, giving a JAX array."""
        if self._covariate_table is None:
            raise ValueError(f"model {self.kind} reads no covariates (its covariate_names is empty)")
        xp = namespace(time)
        if xp is not np:
            return _interpolate_traced(self._covariate_table, time, xp)
        times, values = self._covariate_table
        slack = time_slack(times)
        if not times[0] - slack <= time <= times[-1] + slack and not self._provisional_times:
            raise ValueError(f"model {self.kind}: covariates asked at time {time:.12g}, outside their table "
                             f"({times[0]:.12g} to {times[-1]:.12g})")
        time = min(max(time, times[0]), times[-1])      # an end's row, for a time within the slack of it
        row = min(int(np.searchsorted(times, time, side="right")) - 1, len(times) - 2)
        if row < 0:          # a table of one row: constant covariates
            return values[0].copy()
        share = (time - times[row]) / (times[row + 1] - times[row])
        return values[row] + share * (values[row + 1] - values[row])

    def within_covariate_table(self, time: float) -> float:
        """``time`` moved to the nearest time the covariate table covers (``time`` itself for a
        model without covariates): where the plan-time probes of a model's methods call
        ``propagate``, whose shapes they check, whatever the run's times (whose span
        :meth:`check_covariate_span` checks)."""
        if self._covariate_table is None:
            return time
        table = self._covariate_table[0]
        return float(np.clip(time, table[0], table[-1]))

    def check_covariate_span(self) -> None:
        """ValueError('@covariates: ...') unless the covariate table covers the times the
        transition reads: the start of every substep, from the start of step 1 (its time minus
        the step's duration) to the start of the last step's last substep (its time minus one
        substep). Nothing else reads covariates by time (the measurement's methods take no time),
        so the table need not reach the last step's own time."""
        if self._covariate_table is None:
            return
        times = self.times()
        start = float(times[0] - self.step_duration(1))
        end = float(self.substep_time(self.steps, self.propagations_per_step - 1))
        table = self._covariate_table[0]
        slack = time_slack(table)
        if start < table[0] - slack or end > table[-1] + slack:
            raise ValueError(f"@covariates: the table's times run from {table[0]:.12g} to {table[-1]:.12g}; the "
                             f"model reads covariates from {start:.12g} (the start of step 1) to {end:.12g} "
                             f"(the start of the last substep of step {self.steps}): give rows that cover them")

    # -- the methods called with the time, where they take one ------------------------------

    @property
    def propagate_reads_time(self) -> bool:
        """Whether the model's ``propagate`` has a ``time`` parameter (its transition may change
        with time, so nothing about it may be computed once for every step)."""
        return _takes_time(type(self).propagate)

    def propagate_at(self, state: Any, control: Optional[Any], noise: Any,
                     time: float) -> Any:
        """``propagate(state, control, noise)``, with ``time=time`` if the model's propagate has
        a parameter named ``time`` (looked up once per class)."""
        if self.propagate_reads_time:
            return self.propagate(state, control, noise, time=time)
        return self.propagate(state, control, noise)

    def transition_jacobian_at(self, state: Any, control: Optional[Any],
                               time: float) -> Optional[Any]:
        """``transition_jacobian(state, control)``, with ``time=time`` if it takes a ``time``."""
        if _takes_time(type(self).transition_jacobian):
            return self.transition_jacobian(state, control, time=time)
        return self.transition_jacobian(state, control)

    def process_noise_jacobian_at(self, state: Any, control: Optional[Any],
                                  time: float) -> Optional[Any]:
        """``process_noise_jacobian(state, control)``, with ``time=time`` if it takes a ``time``."""
        if _takes_time(type(self).process_noise_jacobian):
            return self.process_noise_jacobian(state, control, time=time)
        return self.process_noise_jacobian(state, control)


@functools.lru_cache(maxsize=None)
def _takes_time(method: Callable) -> bool:
    """Whether a model method (the function on the class) has a parameter named ``time``."""
    try:
        return "time" in inspect.signature(method).parameters
    except (TypeError, ValueError):      # a builtin or C function: called without time
        return False


def _interpolate_traced(table: tuple[np.ndarray, np.ndarray], time: Any, xp: ModuleType) -> Any:
    """:meth:`TimeAxis.covariates_at` for a JAX ``time``: (c,) interpolated column by column,
    clamped to the table's ends (``jax.numpy.interp`` holds the end rows' values beyond them).
    Its formula is the NumPy path's: the row j with t_j <= t < t_(j+1) (the last two rows at the
    table's end), then c_j + (t - t_j) / (t_(j+1) - t_j) (c_(j+1) - c_j)."""
    times, values = table
    if len(times) == 1:      # a table of one row: constant covariates
        return xp.asarray(values[0])
    return xp.stack([xp.interp(time, times, values[:, column]) for column in range(values.shape[1])])


def covariate_table(model) -> Optional[tuple[np.ndarray, np.ndarray]]:
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


def plain_data(value: Any) -> Any:
    """A field's value as plain data (a pydantic model dumped), for comparing."""
    return value.model_dump(mode="json") if hasattr(value, "model_dump") else value
