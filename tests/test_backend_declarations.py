"""What runs on which backend is declared once, at each component, and read everywhere else.

* Every registered resampler, weighting, proposal, move, diffusion and smoother, and the
  adaptive count, injection and the auxiliary filter, carries a
  :class:`~pfx.filters.backends.Backends` declaration.
* The plan refuses a jax filter exactly for the components that do not declare jax, by the
  component's key, with the declared reason.
* docs/backends.md's table has a row for every component, whose jax column says "yes" where the
  component declares jax and "refused: <the declared reason>" where it does not.
* The JAX backend's resamplers are the resamplers that declare jax.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import pfx
from pfx.config.components import registry
from pfx.errors import ConfigError
from pfx.filters.backends import JAX, Backends, declared
from pfx.filters.particle.adaptive import KLDSampling
from pfx.filters.particle.auxiliary import AuxiliaryFirstStage
from pfx.filters.particle.injection import AugmentedMCL

DOCS = Path(__file__).resolve().parents[1] / "docs" / "backends.md"

# registry -> the config key under filter: that names one of its components
KEYED = {"resamplers": "resampler", "weightings": "weighting", "proposals": "proposal", "moves": "move",
         "diffusions": "diffusion", "smoothers": "smoothers"}
# the components that are one setting, not a registry
SINGLE = {"auxiliary": AuxiliaryFirstStage, "kld": KLDSampling, "augmented": AugmentedMCL}


def _components():
    for name, key in KEYED.items():
        for kind, component in registry(name).items():
            yield name, key, kind, component
    for kind, component in SINGLE.items():
        yield "settings", kind, kind, component


def _settings(key: str, kind: str) -> dict:
    """pfx.particle_filter's arguments that ask for one component."""
    if key == "auxiliary":
        return {"auxiliary": True}
    if key == "kld":
        return {"adaptive": {"kind": "kld", "bin_size": [0.5]}}
    if key == "augmented":
        return {"injection": {"kind": "augmented"}}
    if key == "smoothers":
        return {"smoothers": [kind]}
    if key == "resampler":
        return {"resampler": kind}
    if key == "diffusion":
        return {"diffusion": {"kind": kind, **({"std": 0.1} if kind == "gaussian" else {})}}
    return {key: {"kind": kind}}


def _docs_rows() -> dict[str, str]:
    """docs/backends.md's 'What each backend runs' table: each backticked name -> its jax cell."""
    text = DOCS.read_text()
    table = text[text.index("## What each backend runs"):].split("\n\n")[1]
    rows = {}
    for line in table.splitlines()[2:]:
        cells = [cell.strip() for cell in line.strip("|").split("|")]
        for name in re.findall(r"`([^`]+)`", cells[0]):
            rows.setdefault(name, cells[2])
    return rows


@pytest.mark.parametrize("registry_name,key,kind,component",
                         list(_components()), ids=[f"{r}-{k}" for r, _, k, _ in _components()])
def test_every_component_declares_its_backends(registry_name, key, kind, component):
    declaration = getattr(component, "backends", None)
    assert isinstance(declaration, Backends), f"{registry_name} {kind} declares no backends"
    assert "numpy" in declaration.on
    if not declaration.runs_on(JAX):
        assert declaration.why, f"{kind}: a component that does not run on jax says why"


@pytest.mark.parametrize("registry_name,key,kind,component",
                         list(_components()), ids=[f"{r}-{k}" for r, _, k, _ in _components()])
def test_the_docs_table_says_what_the_declarations_say(registry_name, key, kind, component):
    rows = _docs_rows()
    assert kind in rows, f"docs/backends.md's table has no row naming `{kind}`"
    declaration = declared(component)
    if declaration.runs_on(JAX):
        assert rows[kind].startswith("yes"), (kind, rows[kind])
    else:
        assert rows[kind] == f"refused: {declaration.why}", (kind, rows[kind])


@pytest.mark.parametrize("registry_name,key,kind,component",
                         [case for case in _components() if case[0] != "smoothers" or case[2] != "rts"],
                         ids=[f"{r}-{k}" for r, _, k, _ in _components() if r != "smoothers" or k != "rts"])
def test_jax_refuses_exactly_what_does_not_declare_it(registry_name, key, kind, component):
    """pfx.particle_filter on jax, with this one component: built where the component declares
    jax, refused by its key with the declared reason where it does not. (The rts smoother runs
    after the Kalman filters only.)"""
    pytest.importorskip("jax")
    model = pfx.model("linear_gaussian", steps=5, transition_matrix=[[0.9]], measurement_matrix=[[1.0]],
                      process_noise={"variance": 1.0}, measurement_noise={"variance": 1.0},
                      initial={"kind": "gaussian", "mean": [0.0], "covariance": 1.0})
    settings = _settings(key, kind)
    if key == "kld":
        settings["particles"] = 200
    declaration = declared(component)
    try:
        pfx.particle_filter(model, backend="jax", **settings)
    except ConfigError as error:
        message = str(error)
        if declaration.runs_on(JAX):
            # refused for some other reason than the backend (a move's own requirement, say)
            assert "jax backend" not in message, message
        else:
            config_key = {"kld": "adaptive", "augmented": "injection"}.get(key, key)
            assert f"filter.{config_key}" in message and declaration.why in message, message
            assert "backend: numpy" in message
        return
    assert declaration.runs_on(JAX), f"{kind} does not declare jax, yet a jax filter was built with it"


def test_the_jax_resamplers_are_those_that_declare_jax():
    pytest.importorskip("jax")
    from pfx.filters.particle.jax_resampling import JAX_RESAMPLERS

    declaring = {name for name, resampler in registry("resamplers").items() if resampler.backends.runs_on(JAX)}
    assert set(JAX_RESAMPLERS) == declaring


@pytest.mark.parametrize("weighting", [{"kind": "euclidean", "scale": 1.5}, {"kind": "manhattan"},
                                       {"kind": "mahalanobis", "form": "paper"},
                                       {"kind": "mahalanobis", "form": "innovation"}],
                         ids=["euclidean", "manhattan", "mahalanobis-paper", "mahalanobis-innovation"])
def test_a_weighting_gives_the_same_increments_on_both_backends(weighting):
    """The weightings lifted to jax are one function: traced as the compiled step traces it, on the
    same cloud, weights (some zero) and measurement, jax's increments equal numpy's to 1e-12."""
    pytest.importorskip("jax")
    import jax
    import jax.numpy as jnp
    import numpy as np

    from pfx.config.components import registry

    model = pfx.model("linear_gaussian", steps=5, transition_matrix=[[0.9, 0.1], [0.0, 0.9]],
                      measurement_matrix=[[1.0, 0.0], [0.5, 1.0]], process_noise={"variance": 1.0},
                      measurement_noise={"variance": [1.0, 2.0]},
                      initial={"kind": "gaussian", "mean": [0.0, 0.0], "covariance": 1.0})
    generator = np.random.default_rng(3)
    particles = generator.normal(size=(3, 40, 2))
    weights = generator.exponential(size=(3, 40))
    weights[:, :5] = 0.0
    weights /= weights.sum(axis=1, keepdims=True)
    measurement = generator.normal(size=(3, 1, 2))
    component = registry("weightings")[weighting["kind"]](**weighting)
    on_numpy = component.log_weights(model, measurement, particles, weights)
    with jax.enable_x64(True):
        traced = jax.jit(lambda z, x, w: component.log_weights(model, z, x, w))      # as the compiled step calls it
        on_jax = np.asarray(traced(jnp.asarray(measurement), jnp.asarray(particles), jnp.asarray(weights)))
    np.testing.assert_allclose(on_jax, on_numpy, rtol=1e-12, atol=1e-12)


def test_an_isotropic_euclidean_weighting_filters_as_the_likelihood_on_jax():
    """On a model with one measurement of variance R, the euclidean weighting with scale sqrt(R) is
    the log-likelihood less a constant: the normalised weights, hence the estimates and the
    ancestors, are the gaussian weighting's from the same keys, on the jax backend."""
    pytest.importorskip("jax")
    import numpy as np

    model = pfx.model("linear_gaussian", steps=12, transition_matrix=[[0.9]], measurement_matrix=[[1.0]],
                      process_noise={"variance": 1.0}, measurement_noise={"variance": 2.0},
                      initial={"kind": "gaussian", "mean": [0.0], "covariance": 1.0})
    measurements = np.random.default_rng(5).normal(size=(12, 1))
    runs = {kind: pfx.filter(model, measurements, trials=4, particles=64, backend="jax", seed=2, genealogy=True,
                             weighting=settings)
            for kind, settings in (("gaussian", {"kind": "gaussian"}),
                                   ("euclidean", {"kind": "euclidean", "scale": float(np.sqrt(2.0))}))}
    np.testing.assert_allclose(runs["euclidean"].estimates, runs["gaussian"].estimates, rtol=1e-9, atol=1e-9)
    assert np.array_equal(runs["euclidean"].ancestors, runs["gaussian"].ancestors)
