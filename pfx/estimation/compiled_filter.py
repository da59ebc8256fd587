r"""The particle filter of parameter estimation as a function of the parameters, on the jax backend.

PMMH and IF2 run the cell's bootstrap filter at many parameter vectors. On the NumPy backend
each batch is a new model object (:mod:`pfx.estimation.target`). On the jax backend the
parameters are *arguments* of one compiled program:

.. math::

    (\theta_{1:R},\ \text{keys}_{1:R},\ m_{1:R},\ L_{1:R}) \;\mapsto\;
    \bigl(\log \hat p_{\theta_r}(z_{1:T})\bigr)_{r=1..R},

one row per chain (or per evaluation). The model is the cell's, with the estimated paths set to
traced arrays of shape (R, 1, 1) (:meth:`pfx.models.base.Model.with_parameter_arrays`, what the
model's ``vectorised_parameters`` promise to broadcast); the filter is the jax engine's own
scan (:class:`~pfx.filters.particle.jax_engine.JaxParticleFilter`), vectorised over rows x
particles. Row r's initial particles are drawn from row r's initial law: when the model derives
its initial law from the estimated parameters (a stationary law, say), the law at
:math:`\theta_r` is a Gaussian (or a point) passed as its mean :math:`m_r` and a square root
:math:`L_r` of its covariance (:class:`RowGaussians`); otherwise it is the one law of the cell.

What needs the model's own Python code (its validation: does it accept :math:`\theta`? its
presets: which initial law follows?) stays on the host (:meth:`CompiledFilter.host_laws`); the
compiled chains call it through ``jax.pure_callback`` once per iteration, for all rows at once.
A row whose filter fails (every particle lost, a NaN likelihood) gets :math:`-\infty`, as a row
run alone on the NumPy backend does.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import replace

import numpy as np

from pfx.filters.particle.bound import bind_particle_filter


class RowGaussians:
    r"""Initial laws that differ by row, as arrays: row r's particles are
    :math:`m_r + L_r \varepsilon`, :math:`\varepsilon \sim N(0, I)`, from row r's keys."""

    def __init__(self, means, factors):
        self.means, self.factors = means, factors        # (R, d), (R, d, d)

    def sample(self, random, shape=()):
        import jax.numpy as jnp

        standard = random.standard_normal(tuple(shape) + (self.means.shape[-1],))     # (R, *shape, d)
        flat = standard.reshape(standard.shape[0], -1, standard.shape[-1])
        moved = jnp.einsum("rij,rnj->rni", self.factors.astype(standard.dtype), flat)
        return (self.means.astype(standard.dtype)[:, None, :] + moved).reshape(standard.shape)


def law_arrays(law, dimension: int) -> tuple[np.ndarray, np.ndarray]:
    """A Gaussian or point law's mean (d,) and a square root L of its covariance (d, d),
    L L^T = P (Cholesky, or the symmetric root where P is singular)."""
    mean = np.asarray(law.mean_vector(), dtype=float).reshape(dimension)
    covariance = np.asarray(law.covariance_matrix(), dtype=float).reshape(dimension, dimension)
    try:
        factor = np.linalg.cholesky(covariance)
    except np.linalg.LinAlgError:
        values, vectors = np.linalg.eigh(covariance)
        factor = vectors * np.sqrt(np.clip(values, 0.0, None))
    return mean, factor


def initial_law_follows_parameters(model, settings) -> bool:
    """Whether the filter's initial law is derived from the model's parameters (its presets),
    and so changes with the estimated values; not when the config names one."""
    return settings.initial is None and "initial" in model.preset_fields()


class CompiledFilter:
    """One estimation target's filter as a compiled function of the parameters (module docstring)."""

    def __init__(self, target):
        from pfx.filters.particle.jax_engine import Flags

        self.target = target
        settings = target.cell.filter
        self.template = target.cell.filter_model
        self.follows = initial_law_follows_parameters(self.template, settings)
        self.bound = bind_particle_filter(settings.kind, self.template, settings, target.prior_of(self.template))
        self.state_dimension = self.template.state_dimension
        self.flags = Flags(spread=False, radius=None, deviations=False, genealogy=False, history=False)
        self._program = None

    # -- on the host ------------------------------------------------------------------------------

    def inputs(self, rows: int):
        """The step inputs (measurements, controls, substep times) of ``rows`` rows."""
        measurements = np.broadcast_to(self.target.measurements, (rows,) + self.target.measurements.shape)
        return self.bound.compiled.step_inputs(np.ascontiguousarray(measurements))

    def host_laws(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For parameter rows (R, p) on the natural scale: whether the model accepts each row, and
        each accepted row's initial law as arrays (means (R, d), factors (R, d, d)); identity laws
        where the law does not follow the parameters or the row is refused."""
        rows, dimension = len(values), self.state_dimension
        valid = np.zeros(rows, dtype=bool)
        means, factors = np.zeros((rows, dimension)), np.broadcast_to(np.eye(dimension), (rows, dimension, dimension)).copy()
        for r, row in enumerate(values):
            if not np.all(np.isfinite(row)):
                continue
            model = self.target.model_at(row)
            if model is None:
                continue
            valid[r] = True
            if self.follows:
                means[r], factors[r] = law_arrays(self.target.prior_of(model), dimension)
        return valid, means, factors

    def log_likelihoods(self, values: np.ndarray, seeds: list[int]) -> np.ndarray:
        """log p_hat(z_1:T | theta_r) for each row of ``values`` (R, p), filter seed ``seeds[r]``
        (the row's threefry key); -inf where the model refuses the row or its filter fails."""
        import jax

        from pfx.numerics.key_streams import threefry_keys

        valid, means, factors = self.host_laws(values)
        if not valid.any():
            return np.full(len(values), -np.inf)
        safe = np.where(valid[:, None], values, values[np.argmax(valid)])
        with jax.enable_x64(True):
            if self._program is None:
                self._program = jax.jit(self.log_likelihood)
            result = np.asarray(self._program(safe, threefry_keys(seeds), means, factors, self.inputs(len(values))))
        return np.where(valid, result, -np.inf)

    # -- traced -----------------------------------------------------------------------------------

    def engine(self, values):
        """The jax engine over the model at parameter rows ``values`` (R, p), traced or not."""
        from pfx.filters.particle.jax_engine import JaxParticleFilter

        model = self.template.with_parameter_arrays(self.target.parameter_arrays(values))
        return JaxParticleFilter(replace(self.bound, model=model))

    def log_likelihood(self, values, keys, means, factors, inputs):
        """The traced function: log-likelihood estimates (R,), -inf where a row's filter failed."""
        import jax.numpy as jnp

        engine = self.engine(values)
        if self.follows:
            engine.bound = replace(engine.bound, prior=RowGaussians(means, factors))
        cloud, outputs = engine.traced_run(keys, inputs, self.flags)
        failed = jnp.any(outputs.failures != 0, axis=0)
        return jnp.where(failed, -jnp.inf, cloud.log_likelihood)


@contextmanager
def double_precision_everywhere():
    """64-bit JAX types on every thread while a compiled estimation runs: its host callbacks run
    on a thread of XLA's, where the calling thread's ``jax.enable_x64`` does not reach, and JAX
    would otherwise narrow their float64 results to float32."""
    import jax

    before = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    try:
        yield
    finally:
        jax.config.update("jax_enable_x64", before)
