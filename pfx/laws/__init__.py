"""Probability laws a config names: the noise families (process and measurement noise,
:mod:`pfx.laws.noise`) and the initial laws of the state (:mod:`pfx.laws.initial`).

May import :mod:`pfx.numerics`; nothing above.
"""
