"""Probability laws a config names: the noise families (process and measurement noise,
:mod:`pfx.laws.noise`) and the initial laws of the state (:mod:`pfx.laws.initial`); and the
transition density a model's additive noise gives (:mod:`pfx.laws.transition_density`), which
the filters evaluate.

May import :mod:`pfx.numerics`; nothing above.
"""
