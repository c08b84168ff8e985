"""A render node (installed as ``igi.worker``): builds the per-k VPL and caustic-photon sets
from one scrambled Sobol stream, traces a task's eye paths and gathers, and answers the master
over ZeroMQ (:mod:`igi.worker.node`). Imports only ``common``; no worker talks to another."""
