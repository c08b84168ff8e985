"""igi's lowest layer (installed as ``igi.common``): scenes and their loaders, sampling (the
scrambled Sobol stream, interleaving), BSDFs, the render parameters, and the wire formats and
protocol that master and workers share. Imports nothing from ``worker``, ``master`` or ``bench``."""
