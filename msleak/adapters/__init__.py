"""Beam models and skies that must read files themselves, and the loaders that read an
observation through :mod:`msleak.io` and hand arrays to the computation packages."""
