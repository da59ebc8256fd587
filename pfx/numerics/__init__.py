"""Numerics every layer above may use: the random streams and their seeding scheme, the ziggurat
normal generator, the compiled (numba) loops, angles on the circle, and the canonical hash
that names cells and configs.

Imports nothing of pfx but :mod:`pfx.errors` and :mod:`pfx.registry`.
"""
